"""The metacontroller-style reasoner: choices for the MROS pilot, NFR fallback, validation, and
reconfiguring a real manager over simulated nodes."""

from __future__ import annotations

import dataclasses

import pytest
from model_files import bundled

from sm_bt.model.types import SystemPart
from sm_bt.reasoner import Decision, FunctionDesign, Objective, Reasoner
from sm_bt.sim import SimulatedSystem
from sm_bt.trees.pilot.designs import PILOT_DESIGNS, PILOT_OBJECTIVE, pilot_reasoner


def design(mode: str, performance: float, *, energy: float = 0.1, safety: float = 0.9,
           requires: frozenset[str] = frozenset({"battery"})) -> FunctionDesign:
    return FunctionDesign(mode, requires, {"energy": energy, "performance": performance, "safety": safety})


# -- the pilot's choices ---------------------------------------------------------------------------


@pytest.mark.parametrize(("failed", "expected"), [
    ((), "f_normal_mode"),
    (("battery",), "f_energy_saving_mode"),
    (("laser_resender",), "f_degraded_mode"),
    (("battery", "laser_resender"), None),
])
def test_pilot_choice_for_each_failure_combination(failed: tuple[str, ...], expected: str | None) -> None:
    reasoner = pilot_reasoner()
    for name in failed:
        reasoner.component_failed(name)
    decision = reasoner.decide()
    assert decision.mode == expected
    assert decision.failed == failed
    assert "\n" not in decision.explanation


def test_nothing_failed_excludes_the_performance_mode_for_energy() -> None:
    decision = pilot_reasoner().decide()
    assert decision.design == PILOT_DESIGNS[0]
    assert decision.realisable == ("f_performance_mode", "f_normal_mode", "f_slow_mode", "f_energy_saving_mode",
                                   "f_degraded_mode")
    assert decision.meeting_nfrs == ("f_normal_mode", "f_slow_mode", "f_energy_saving_mode", "f_degraded_mode")
    assert decision.explanation.startswith("all components OK: f_normal_mode has the best performance (0.7)")
    assert "f_performance_mode: energy 0.7 > 0.5" in decision.explanation


def test_battery_failure_leaves_only_energy_saving() -> None:
    reasoner = pilot_reasoner()
    reasoner.component_failed("battery")
    decision = reasoner.decide()
    assert decision.realisable == ("f_energy_saving_mode",)
    assert decision.explanation == "battery failed: f_energy_saving_mode is the only realisable design"


def test_both_failed_explains_that_nothing_is_realisable() -> None:
    reasoner = pilot_reasoner()
    reasoner.component_failed("battery")
    reasoner.component_failed("laser_resender")
    decision = reasoner.decide()
    assert decision == Decision(None, (), (), "battery, laser_resender failed: no design of pilot is realisable",
                                ("battery", "laser_resender"))
    assert reasoner.failed_components() == ("battery", "laser_resender")


def test_recovery_goes_back_to_normal() -> None:
    reasoner = pilot_reasoner()
    reasoner.component_failed("laser_resender")
    assert reasoner.decide().mode == "f_degraded_mode"
    reasoner.component_recovered("laser_resender")
    assert reasoner.failed_components() == ()
    assert reasoner.decide().mode == "f_normal_mode"


def test_mros_status_words() -> None:
    reasoner = pilot_reasoner()
    assert reasoner.report("battery", "FALSE")
    assert not reasoner.is_ok("battery")
    assert not reasoner.report("battery", "false")  # no change
    assert reasoner.report("battery", "RECOVERED")
    assert reasoner.is_ok("battery")
    with pytest.raises(ValueError, match=r"unknown status 'BROKEN'.*RECOVERED"):
        reasoner.report("battery", "BROKEN")


def test_revision_and_changed_track_status_changes_only() -> None:
    reasoner = pilot_reasoner()
    assert reasoner.changed and reasoner.revision == 0  # nothing decided yet
    reasoner.decide()
    assert not reasoner.changed
    assert not reasoner.component_recovered("battery")  # already OK: no change
    assert not reasoner.changed and reasoner.revision == 0
    assert reasoner.component_failed("battery")
    assert reasoner.changed and reasoner.revision == 1
    assert reasoner.last_decision is not None and reasoner.last_decision.mode == "f_normal_mode"
    reasoner.decide()
    assert not reasoner.changed
    assert reasoner.last_decision is not None and reasoner.last_decision.mode == "f_energy_saving_mode"
    reasoner.set_component("battery", True)
    assert reasoner.changed and reasoner.revision == 2


# -- ranking ---------------------------------------------------------------------------------------


def test_fallback_to_best_utility_when_no_design_meets_the_nfrs() -> None:
    designs = [design("GREEDY", 0.9, energy=0.9), design("HUNGRY", 0.5, energy=0.8), design("UNSAFE", 0.95, safety=0.1,
                                                                                            requires=frozenset())]
    reasoner = Reasoner("robot", designs, PILOT_OBJECTIVE)
    decision = reasoner.decide()
    assert decision.mode == "UNSAFE"
    assert decision.meeting_nfrs == ()
    assert "no realisable design meets the NFRs (energy <= 0.5, safety >= 0.5)" in decision.explanation
    assert "falling back to UNSAFE" in decision.explanation and "safety 0.1 < 0.5" in decision.explanation
    reasoner.component_failed("battery")  # UNSAFE requires nothing: still realisable
    assert reasoner.decide().mode == "UNSAFE"


def test_designs_meeting_the_nfrs_win_over_a_better_violating_one() -> None:
    designs = [design("FAST", 0.9, energy=0.9), design("OK", 0.3)]
    assert Reasoner("robot", designs, PILOT_OBJECTIVE).decide().mode == "OK"


def test_ties_are_broken_by_name() -> None:
    designs = [design("MIKE_B", 0.5), design("ZULU_A", 0.5), design("ALPHA_C", 0.5), design("YANKEE", 0.6)]
    decision = Reasoner("robot", designs, PILOT_OBJECTIVE).decide()
    assert decision.mode == "YANKEE"
    assert decision.meeting_nfrs == ("YANKEE", "ALPHA_C", "MIKE_B", "ZULU_A")


def test_another_utility_and_bounds() -> None:
    objective = Objective(maximum={"energy": 0.4}, utility="safety")
    decision = Reasoner("pilot", PILOT_DESIGNS, objective).decide()
    # energy <= 0.4: slow (safety 0.7) and energy saving (0.6); safety ranks.
    assert decision.meeting_nfrs == ("f_slow_mode", "f_energy_saving_mode")
    assert decision.mode == "f_slow_mode"


# -- validation --------------------------------------------------------------------------------------


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"mode": ""}, "mode must be a non-empty string"),
    ({"mode": "active.FAST"}, "may not contain '.'"),
    ({"requires": "battery"}, "must be a set of component names"),
    ({"requires": frozenset({""})}, "component required by design M"),
    ({"qualities": {"energy": "high"}}, r"qualities of design M\['energy'\] must be a finite number"),
    ({"qualities": {"energy": float("nan")}}, "must be a finite number"),
    ({"qualities": {"energy": True}}, "must be a finite number"),
    ({"qualities": [0.5]}, "must be a mapping"),
])
def test_function_design_validation(kwargs: dict[str, object], message: str) -> None:
    values: dict[str, object] = {"mode": "M", "requires": frozenset({"battery"}), "qualities": {"energy": 0.5}}
    values.update(kwargs)
    with pytest.raises(ValueError, match=message):
        FunctionDesign(**values)  # type: ignore[arg-type]


def test_designs_are_frozen_and_hashable() -> None:
    qualities = {"energy": 0.5, "performance": 0.5, "safety": 0.5}
    made = FunctionDesign("M", frozenset({"battery"}), qualities)
    qualities["energy"] = 1.0  # the design keeps its own copy
    assert made.qualities["energy"] == 0.5
    with pytest.raises(TypeError):
        made.qualities["energy"] = 2.0  # type: ignore[index]
    assert len({made, FunctionDesign("M", frozenset({"battery"}), {"energy": 0.5, "performance": 0.5,
                                                                    "safety": 0.5})}) == 1
    assert made.quality("safety") == 0.5
    with pytest.raises(ValueError, match=r"no quality 'cost'.*energy, performance, safety"):
        made.quality("cost")


def test_objective_validation() -> None:
    with pytest.raises(ValueError, match="objective maximum"):
        Objective(maximum={"energy": "low"})  # type: ignore[dict-item]
    with pytest.raises(ValueError, match="objective utility"):
        Objective(utility="")
    assert Objective().describe() == "no NFRs"
    assert PILOT_OBJECTIVE.describe() == "energy <= 0.5, safety >= 0.5"


def test_reasoner_validation() -> None:
    with pytest.raises(ValueError, match="no function designs"):
        Reasoner("robot", [], PILOT_OBJECTIVE)
    with pytest.raises(ValueError, match="two designs for mode A"):
        Reasoner("robot", [design("A", 0.1), design("A", 0.2)], PILOT_OBJECTIVE)
    with pytest.raises(ValueError, match="design A lacks the qualities cost"):
        Reasoner("robot", [design("A", 0.1)], Objective(maximum={"cost": 1.0}))
    with pytest.raises(ValueError, match="part must be a non-empty string"):
        Reasoner("", [design("A", 0.1)], PILOT_OBJECTIVE)


def test_unknown_component_lists_the_known_ones() -> None:
    reasoner = pilot_reasoner()
    for call in (reasoner.component_failed, reasoner.component_recovered, reasoner.is_ok):
        with pytest.raises(ValueError, match=r"unknown component 'laser' for pilot \(components: battery, "
                                             r"laser_resender\)"):
            call("laser")
    with pytest.raises(ValueError, match="unknown component 'camera'"):
        reasoner.set_component("camera", False)
    assert reasoner.revision == 0


# -- the model ---------------------------------------------------------------------------------------


def test_check_passes_against_the_bundled_pilot_model() -> None:
    pilot_reasoner().check(bundled("pilot"))


def test_check_names_a_mode_the_model_lacks() -> None:
    model = bundled("pilot")
    pilot = model.part("pilot")
    assert isinstance(pilot, SystemPart)
    modes = {name: mode for name, mode in pilot.modes.items() if name != "f_slow_mode"}
    lacking = dataclasses.replace(model, parts={**model.parts, "pilot": dataclasses.replace(pilot, modes=modes)})
    with pytest.raises(ValueError, match=r"designs of pilot name modes the model lacks: f_slow_mode \(modes of pilot: "
                                         r"__DEFAULT__, f_normal_mode"):
        pilot_reasoner().check(lacking)


def test_check_names_a_missing_part() -> None:
    reasoner = Reasoner("navigation", PILOT_DESIGNS, PILOT_OBJECTIVE)
    with pytest.raises(ValueError, match=r"reasoner part 'navigation' is not in the model.*parts: pilot"):
        reasoner.check(bundled("pilot"))


# -- reconfiguring a manager ---------------------------------------------------------------------------


def test_reconfigure_drives_the_manager_through_failures_and_recovery() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    reasoner = pilot_reasoner()
    rig.finish(rig.manager.change_state("pilot", "configure"))
    assert str(rig.manager.actual("pilot")) == "inactive"

    request = reasoner.reconfigure(rig.manager)
    assert request is not None
    rig.finish(request)
    assert request.succeeded, request.reason
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"

    # Already there: nothing to ask for.
    assert reasoner.reconfigure(rig.manager) is None

    reasoner.component_failed("laser_resender")
    request = reasoner.reconfigure(rig.manager)
    assert request is not None and "f_degraded_mode" in request.description
    rig.finish(request)
    assert request.succeeded, request.reason
    assert str(rig.manager.actual("pilot")) == "active.f_degraded_mode"
    assert str(rig.manager.actual("laser_resender")) == "unconfigured"
    assert reasoner.reconfigure(rig.manager) is None

    # Nothing realisable: the reasoner leaves the manager alone.
    reasoner.component_failed("battery")
    sent = len(rig.backend.events)
    assert reasoner.reconfigure(rig.manager) is None
    assert len(rig.backend.events) == sent
    assert rig.manager.target("pilot") is not None
    assert str(rig.manager.target("pilot")) == "active.f_degraded_mode"

    reasoner.component_recovered("battery")
    reasoner.component_recovered("laser_resender")
    rig.finish(reasoner.reconfigure(rig.manager))  # type: ignore[arg-type]
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"


def test_reconfigure_asks_again_when_the_part_was_deactivated() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    reasoner = pilot_reasoner()
    request = reasoner.reconfigure(rig.manager)  # no target yet: ask
    assert request is not None
    rig.finish(request)
    rig.finish(rig.manager.change_state("pilot", "deactivate"))
    assert str(rig.manager.actual("pilot")) == "inactive"
    request = reasoner.reconfigure(rig.manager)  # same mode name, but not active: ask again
    assert request is not None
    rig.finish(request)
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"
