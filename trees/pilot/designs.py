"""The MROS pilot's function designs and objective (ontology ``URJCpilot.owl``), for the
:class:`~sm_bt.reasoner.Reasoner` of the pilot's metacontrol tree."""

from __future__ import annotations

from sm_bt.reasoner import FunctionDesign, Objective, Reasoner

#: The function designs of the MROS pilot ontology (URJCpilot.owl), one per system mode of ``pilot``.
PILOT_DESIGNS: tuple[FunctionDesign, ...] = (
    FunctionDesign("f_normal_mode", frozenset({"battery", "laser_resender"}),
                   {"energy": 0.5, "performance": 0.7, "safety": 0.8}),
    FunctionDesign("f_degraded_mode", frozenset({"battery"}),
                   {"energy": 0.45, "performance": 0.2, "safety": 0.55}),
    FunctionDesign("f_energy_saving_mode", frozenset({"laser_resender"}),
                   {"energy": 0.34, "performance": 0.3, "safety": 0.6}),
    FunctionDesign("f_performance_mode", frozenset({"battery", "laser_resender"}),
                   {"energy": 0.7, "performance": 0.9, "safety": 0.55}),
    FunctionDesign("f_slow_mode", frozenset({"battery", "laser_resender"}),
                   {"energy": 0.3, "performance": 0.4, "safety": 0.7}),
)

#: The pilot's objective: energy at most 0.5, safety at least 0.5, ranked by performance.
PILOT_OBJECTIVE = Objective(maximum={"energy": 0.5}, minimum={"safety": 0.5}, utility="performance")


def pilot_reasoner() -> Reasoner:
    """A reasoner for the bundled ``pilot`` model's system ``pilot``."""
    return Reasoner("pilot", PILOT_DESIGNS, PILOT_OBJECTIVE)
