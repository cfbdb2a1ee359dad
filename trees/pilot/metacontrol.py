"""The MROS pilot mission with a metacontroller choosing the modes (the pilot's second
generation): the tree only patrols and recharges, a :class:`~sm_bt.reasoner.Reasoner` picks the
best realisable function design whenever a component fails or recovers, and
:class:`~sm_bt.behaviours.Reconfigure` requests it.

Component statuses come from the tree's sensors: the battery monitor (failed below 0.5,
recovered above 0.8) and the mode manager (laser_resender failed when it leaves its target by
itself; recovered once the laser's scans are healthy again).
"""

from __future__ import annotations

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Access, Status

from sm_bt.behaviours import ChangeState, ManagerBehaviour, Reconfigure
from sm_bt.model.types import Model
from sm_bt.reasoner import Reasoner
from sm_bt.trees import pilot
from sm_bt.trees.pilot import SYSTEM, go_and_recharge, patrol
from sm_bt.trees.pilot.actions import BATTERY_OK, LASER_SCANS_OK
from sm_bt.trees.pilot.designs import pilot_reasoner


class ComponentsToReasoner(ManagerBehaviour):
    """Tell the reasoner what failed and what recovered. Always SUCCESS.

    * ``battery``: the battery monitor's status on the blackboard
    * ``laser``: failed when the manager reports it diverging from its target as an error (it
      fell to unconfigured by itself and recovery could not bring it back); recovered when the
      scans are healthy again
    """

    def __init__(self, name: str, reasoner: Reasoner, laser: str = "laser_resender",
                 battery: str = "battery") -> None:
        super().__init__(name)
        self.reasoner = reasoner
        self.laser = laser
        self.battery = battery
        self.blackboard = self.attach_blackboard_client(name)
        self.blackboard.register_key(BATTERY_OK, access=Access.READ)
        self.blackboard.register_key(LASER_SCANS_OK, access=Access.READ)

    def check_model(self, model: Model) -> None:
        self._check_part(model, self.laser)

    def update(self) -> Status:
        if self.blackboard.exists(BATTERY_OK):
            self.reasoner.set_component(self.battery, bool(self.blackboard.get(BATTERY_OK)))
        divergence = self.manager.divergence(self.laser)
        if divergence is not None and divergence.is_error:
            self.reasoner.component_failed(self.laser)
        elif not self.reasoner.is_ok(self.laser) and self.blackboard.exists(LASER_SCANS_OK) \
                and self.blackboard.get(LASER_SCANS_OK):
            self.reasoner.component_recovered(self.laser)
        failed = self.reasoner.failed_components()
        self.feedback_message = f"failed: {', '.join(failed)}" if failed else "all components OK"
        return Status.SUCCESS


class NeedsDecision(py_trees.behaviour.Behaviour):
    """SUCCESS when the reasoner has not decided yet or a component status changed since it
    last did; FAILURE otherwise (a check: never RUNNING)."""

    def __init__(self, name: str, reasoner: Reasoner) -> None:
        super().__init__(name)
        self.reasoner = reasoner

    def update(self) -> Status:
        if self.reasoner.last_decision is None or self.reasoner.changed:
            self.feedback_message = "statuses changed"
            return Status.SUCCESS
        self.feedback_message = f"grounded: {self.reasoner.last_decision}"
        return Status.FAILURE


def adapt(reasoner: Reasoner, suffix: str = "") -> Behaviour:
    """When the statuses changed, let the reasoner reconfigure."""
    return py_trees.composites.Sequence(f"Adapt{suffix}", memory=True, children=[
        NeedsDecision(f"Statuses changed?{suffix}", reasoner),
        Reconfigure(f"Reconfigure{suffix}", reasoner),
    ])


def create_root(cycles: int = 2, reasoner: Reasoner | None = None) -> Behaviour:
    """The pilot mission driven by ``reasoner`` (default: the pilot ontology's designs)."""
    reasoner = reasoner or pilot_reasoner()
    gather = pilot.gather().add_children([ComponentsToReasoner("Components to Reasoner", reasoner)])
    metacontroller = py_trees.composites.Selector("Metacontroller", memory=False, children=[
        adapt(reasoner),
        py_trees.behaviours.Running("Grounded"),
    ])
    # The last action (a recharge) changes statuses the sensors only see at the next tick:
    # gather once more, then let the reasoner settle the final mode.
    wrap_up = py_trees.composites.Sequence("Wrap-up", memory=True, children=[
        py_trees.behaviours.TickCounter("Sense once more", duration=1, completion_status=Status.SUCCESS),
        py_trees.composites.Selector("Final adaptation", memory=False, children=[
            adapt(reasoner, " (final)"),
            py_trees.behaviours.Success("Grounded (final)"),
        ]),
    ])
    # The reasoner picks the recharge's mode (the battery failed): the tree only goes and recharges.
    patrolling = patrol(cycles, recharging=go_and_recharge())
    mission = py_trees.composites.Sequence("Mission", memory=True, children=[
        ChangeState("Configure", SYSTEM, "configure"),
        py_trees.composites.Parallel(
            "Patrol under metacontrol",
            policy=py_trees.common.ParallelPolicy.SuccessOnSelected([patrolling], synchronise=False),
            children=[metacontroller, patrolling],
        ),
        wrap_up,
    ])
    return py_trees.composites.Sequence("Pilot (metacontrol)", memory=False, children=[gather, mission])
