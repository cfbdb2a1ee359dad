"""hold_mode, switch_on_divergence and Reconfigure in real trees, on the MROS pilot."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import py_trees
import pytest
from harness import settle
from model_files import bundled
from py_trees.common import Status
from tree_helpers import Flag, Probe, backend_requests, fresh_blackboard

from sm_bt.behaviours import (
    ChangeMode,
    HoldMode,
    ModeIs,
    OnDivergence,
    Reconfigure,
    WaitForMode,
    hold_mode,
    switch_on_divergence,
)
from sm_bt.engine.events import Event, EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.model.states import State, StateMode
from sm_bt.reasoner import FunctionDesign, Reasoner
from sm_bt.sim import SimulatedSystem
from sm_bt.trees.pilot.designs import PILOT_OBJECTIVE, pilot_reasoner

NORMAL = StateMode(State.ACTIVE, "f_normal_mode")
PERFORMANCE = StateMode(State.ACTIVE, "f_performance_mode")
DEFAULT_CONTROLLER = {"FollowPath.max_vel_x": 0.3, "FollowPath.max_speed_xy": 0.3, "FollowPath.max_vel_theta": 1.25,
                      "FollowPath.transform_tolerance": 0.2}
DEGRADED_CONTROLLER = {"FollowPath.max_vel_x": 0.1, "FollowPath.max_speed_xy": 0.1, "FollowPath.max_vel_theta": 0.5,
                       "FollowPath.transform_tolerance": 2.5}
DEGRADED_AMCL = {"transform_tolerance": 2.5, "alpha1": 0.05, "alpha2": 0.05, "alpha3": 0.05, "alpha4": 0.05,
                 "alpha5": 0.05}


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.fixture
def rig() -> SimulatedSystem:
    """The pilot in f_normal_mode, recovery off (the tree handles the contingencies)."""
    rig = SimulatedSystem(bundled("pilot"), recovery=False)
    settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
    return rig


def pilot_mode(rig: SimulatedSystem) -> str:
    return str(rig.manager.actual("pilot"))


def held(subtree: py_trees.behaviour.Behaviour) -> HoldMode:
    hold = subtree.children[0]
    assert isinstance(hold, HoldMode)
    return hold


# -- hold_mode ----------------------------------------------------------------------------------------


def test_the_work_starts_once_the_mode_is_confirmed_and_the_mode_is_restored_after(rig: SimulatedSystem) -> None:
    work = Probe("Sprint", [Status.RUNNING, Status.RUNNING, Status.SUCCESS], look=lambda: pilot_mode(rig))
    subtree = hold_mode("Fast", "pilot", "f_performance_mode", work)
    tree = rig.tree(subtree)
    trace = rig.tick_until_done(tree)

    assert subtree.status is Status.SUCCESS
    assert work.seen == ["active.f_performance_mode"] * 3, "the work only ever saw the held mode"
    assert [t.status for t in trace] == [Status.RUNNING] * 3 + [Status.SUCCESS]
    assert len(work.seen) == len(trace) - 1, "the first tick only requested the mode"

    hold = held(subtree)
    restore = hold.restore_request
    assert restore is not None
    assert rig.manager.target("pilot") == NORMAL
    settle(rig, restore)
    assert pilot_mode(rig) == "active.f_normal_mode"
    assert rig.backend.node("controller_server").parameters == DEFAULT_CONTROLLER


def test_the_mode_is_restored_when_the_work_fails(rig: SimulatedSystem) -> None:
    work = Probe("Sprint", [Status.RUNNING, Status.FAILURE], look=lambda: pilot_mode(rig))
    subtree = hold_mode("Fast", "pilot", "f_performance_mode", work)
    rig.tick_until_done(rig.tree(subtree))

    assert subtree.status is Status.FAILURE
    assert work.seen == ["active.f_performance_mode"] * 2
    restore = held(subtree).restore_request
    assert restore is not None and restore.description == "change_to pilot active.f_normal_mode"
    settle(rig, restore)
    assert pilot_mode(rig) == "active.f_normal_mode"


def test_the_mode_is_restored_when_the_parent_interrupts_the_work(rig: SimulatedSystem) -> None:
    stop = Flag("Stop?")
    work = Probe("Sprint", [Status.RUNNING], look=lambda: pilot_mode(rig))
    subtree = hold_mode("Fast", "pilot", "f_performance_mode", work)
    root = py_trees.composites.Selector("Root", memory=False, children=[stop, subtree])
    tree = rig.tree(root)
    rig.tick_for(tree, 0.5)
    hold = held(subtree)
    assert hold.status is Status.RUNNING
    assert hold.feedback_message == "holding pilot in active.f_performance_mode"
    assert work.seen and work.terminated == []

    stop.on = True
    tree.tick()
    assert subtree.status is Status.INVALID
    assert work.terminated == [Status.INVALID]
    assert hold.feedback_message == "restoring pilot to active.f_normal_mode"
    assert hold.restore_request is not None
    settle(rig, hold.restore_request)
    assert pilot_mode(rig) == "active.f_normal_mode"


def test_interrupted_before_the_mode_is_reached_the_change_is_withdrawn(rig: SimulatedSystem) -> None:
    rig.backend.hang_next("pointcloud_to_laser", Transition.ACTIVATE)
    stop = Flag("Stop?")
    work = Probe("Careful", [Status.RUNNING])
    subtree = hold_mode("Degraded", "pilot", "f_degraded_mode", work)
    root = py_trees.composites.Selector("Root", memory=False, children=[stop, subtree])
    tree = rig.tree(root)
    rig.tick_for(tree, 0.5)
    hold = held(subtree)
    change = hold.restore_request
    assert change is None
    assert rig.manager.requests()[0].description == "change_mode pilot f_degraded_mode"

    stop.on = True
    tree.tick()
    assert work.seen == [], "the work never ran"
    requests = rig.manager.requests()
    assert [r.description for r in requests] == ["change_to pilot active.f_normal_mode"]
    assert rig.manager.target("pilot") == NORMAL


def test_nothing_is_restored_when_someone_else_retargeted_the_part(rig: SimulatedSystem) -> None:
    work = Probe("Sprint", [Status.RUNNING] * 10 + [Status.SUCCESS])
    subtree = hold_mode("Fast", "pilot", "f_performance_mode", work)
    tree = rig.tree(subtree)
    rig.tick_until(tree, lambda: len(work.seen) == 2)
    slow = rig.manager.change_mode("pilot", "f_slow_mode")
    tree.tick()
    assert held(subtree).feedback_message == ("pilot was re-targeted to active.f_slow_mode: "
                                              "it will not be restored")

    rig.tick_until_done(tree)
    assert subtree.status is Status.SUCCESS
    assert held(subtree).restore_request is None
    assert slow.succeeded and slow.reason == ""
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_slow_mode")
    assert rig.manager.requests() == []
    assert pilot_mode(rig) == "active.f_slow_mode"


def test_failure_when_the_held_mode_cannot_be_reached(rig: SimulatedSystem) -> None:
    rig.backend.reject_parameters("controller_server", "read-only")
    work = Probe("Sprint", [Status.SUCCESS])
    subtree = hold_mode("Fast", "pilot", "f_performance_mode", work)
    rig.tick_until_done(rig.tree(subtree))

    assert subtree.status is Status.FAILURE
    assert work.seen == [], "the work never ran"
    hold = held(subtree)
    assert hold.status is Status.FAILURE
    # Why it failed, and that the previous target is being restored.
    assert hold.feedback_message == ("controller_server: set parameters of mode FAST failed: read-only; "
                                     "restoring pilot to active.f_normal_mode")
    restore = hold.restore_request
    assert restore is not None
    settle(rig, restore)
    assert rig.manager.target("pilot") == NORMAL
    assert pilot_mode(rig) == "active.f_normal_mode"


def test_the_mode_lost_before_the_work_starts_fails_the_subtree_instead_of_waiting_for_ever(
        rig: SimulatedSystem) -> None:
    # The change succeeds between two ticks, and the laser fails before the next tick: the work
    # must not wait (without a bound) for a mode that nothing brings back (recovery is off).
    def fail_laser_once_held(event: Event) -> None:
        request = event.request
        if request is not None and request.done and request.succeeded and "f_energy_saving_mode" in request.description:
            rig.backend.trigger("laser_resender", Transition.DEACTIVATE, Outcome.ERROR)

    rig.manager.subscribe(fail_laser_once_held, kinds=[EventKind.REQUEST])
    work = Probe("Work", [Status.SUCCESS])
    subtree = hold_mode("Save energy", "pilot", "f_energy_saving_mode", work)
    trace = rig.tick_until_done(rig.tree(subtree), timeout=5.0)
    assert trace[-1].status is Status.FAILURE
    assert work.seen == [], "the work never ran"
    gate = subtree.children[1].children[0]
    assert gate.feedback_message.startswith("pilot lost active.f_energy_saving_mode before the work started")
    assert held(subtree).restore_request is not None  # the previous target is asked back


@pytest.mark.parametrize("make", [
    lambda: ChangeMode("Change", "pilot", ""),
    lambda: HoldMode("Hold", "pilot", ""),
    lambda: hold_mode("Hold", "pilot", "", Probe("Work", [Status.SUCCESS])),
    lambda: ModeIs("Is", "pilot", ""),
    lambda: WaitForMode("Wait", "pilot", ""),
])
def test_an_empty_mode_name_is_refused_when_the_behaviour_is_made(make: Callable[[], object]) -> None:
    with pytest.raises(ValueError, match=r"mode name of pilot is empty .*__DEFAULT__"):
        make()


def test_holding_the_mode_the_part_is_in_restores_nothing(rig: SimulatedSystem) -> None:
    work = Probe("Cruise", [Status.SUCCESS])
    subtree = hold_mode("Normal", "pilot", "f_normal_mode", work)
    rig.tick_until_done(rig.tree(subtree))
    assert subtree.status is Status.SUCCESS
    assert work.seen == [None]
    assert held(subtree).restore_request is None
    assert rig.manager.requests() == []


# -- switch_on_divergence -----------------------------------------------------------------------------


def test_laser_failure_switches_the_pilot_to_degraded(rig: SimulatedSystem) -> None:
    navigate = Probe("Navigate", [Status.RUNNING])
    switch = switch_on_divergence("Laser lost", "laser_resender", "pilot", "f_degraded_mode")
    root = py_trees.composites.Selector("Contingencies", memory=False, children=[switch, navigate])
    tree = rig.tree(root)
    detector, change = switch.children
    assert isinstance(detector, OnDivergence) and isinstance(change, ChangeMode)

    # While the change is in progress, record whether the laser still diverges.
    during_switch: list[bool] = []

    def watch(_tree: py_trees.trees.BehaviourTree) -> None:
        if change.status is Status.RUNNING:
            during_switch.append(rig.manager.divergence("laser_resender") is not None)

    tree.add_post_tick_handler(watch)
    rig.tick_for(tree, 0.5)
    ticks_before = len(navigate.seen)
    failed_at = rig.clock.now()
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE, outcome=Outcome.ERROR)
    rig.tick_until(tree, lambda: switch.status is Status.SUCCESS, watch=switch)

    request = change.request
    assert request is not None and request.succeeded and request.reason == ""
    assert 2.0 - 1e-6 <= request.created - failed_at <= 2.05 + 1e-6, "requested at the first tick after the grace"
    # 2 s of grace at one tick per 0.05 s (give or take the clock's rounding)
    assert len(navigate.seen) - ticks_before in (40, 41), "the fallback ran during the grace period"
    assert navigate.terminated[-1] is Status.INVALID, "the contingency took over"
    assert during_switch and not all(during_switch), "the divergence disappeared mid-switch"

    assert pilot_mode(rig) == "active.f_degraded_mode"
    assert rig.backend.node("laser_resender").state is State.UNCONFIGURED
    assert rig.backend.node("pointcloud_to_laser").state is State.ACTIVE
    assert rig.backend.node("amcl").parameters == DEGRADED_AMCL
    assert rig.backend.node("controller_server").parameters == DEGRADED_CONTROLLER
    assert str(rig.manager.actual("amcl")) == "active.DEGRADED"
    assert str(rig.manager.actual("controller_server")) == "active.DEGRADED"

    # The next tick finds everything on target: back to the fallback.
    tree.tick()
    assert detector.status is Status.FAILURE
    assert navigate.status is Status.RUNNING


def test_switch_on_divergence_fails_when_nothing_diverges(rig: SimulatedSystem) -> None:
    switch = switch_on_divergence("Any failure", None, "pilot", "f_degraded_mode")
    tree = rig.tree(switch)
    trace = rig.tick_for(tree, 3.0)
    assert {t.status for t in trace} == {Status.FAILURE}
    assert pilot_mode(rig) == "active.f_normal_mode"
    assert rig.manager.requests() == []


# -- Reconfigure --------------------------------------------------------------------------------------


def test_reconfigure_picks_normal_mode_at_start() -> None:
    rig = SimulatedSystem(bundled("pilot"), recovery=False)
    reconfigure = Reconfigure("Reconfigure", pilot_reasoner())
    trace = rig.tick_until_done(rig.tree(reconfigure))
    assert trace[0].status is Status.RUNNING
    assert trace[-1].status is Status.SUCCESS
    assert reconfigure.decision_text == ("all components OK: f_normal_mode has the best performance (0.7) of the "
                                         "4 designs meeting the NFRs (excluded f_performance_mode: energy 0.7 > 0.5)")
    assert reconfigure.feedback_message == f"{reconfigure.decision_text} -> pilot is active.f_normal_mode (0.10 s)"
    assert pilot_mode(rig) == "active.f_normal_mode"


def test_reconfigure_degrades_when_the_laser_failed(rig: SimulatedSystem) -> None:
    reasoner = pilot_reasoner()
    reconfigure = Reconfigure("Reconfigure", reasoner)
    tree = rig.tree(reconfigure)
    reasoner.component_failed("laser_resender")
    trace = rig.tick_until_done(tree)
    assert trace[0].status is Status.RUNNING
    assert trace[-1].status is Status.SUCCESS
    assert reconfigure.decision_text == "laser_resender failed: f_degraded_mode is the only realisable design"
    assert pilot_mode(rig) == "active.f_degraded_mode"
    assert rig.backend.node("laser_resender").state is State.UNCONFIGURED


def test_reconfigure_fails_with_the_explanation_when_nothing_is_realisable(rig: SimulatedSystem) -> None:
    reasoner = pilot_reasoner()
    reasoner.component_failed("battery")
    reasoner.component_failed("laser_resender")
    reconfigure = Reconfigure("Reconfigure", reasoner)
    before = backend_requests(rig)
    trace = rig.tick_until_done(rig.tree(reconfigure))
    assert [t.status for t in trace] == [Status.FAILURE]
    assert reconfigure.feedback_message == "battery, laser_resender failed: no design of pilot is realisable"
    assert reconfigure.request is None
    assert rig.manager.requests() == []
    assert backend_requests(rig) == before
    assert rig.manager.target("pilot") == NORMAL


def test_reconfigure_with_nothing_to_do_succeeds_at_once(rig: SimulatedSystem) -> None:
    reasoner = pilot_reasoner()
    reconfigure = Reconfigure("Reconfigure", reasoner)
    before = backend_requests(rig)
    trace = rig.tick_until_done(rig.tree(reconfigure))
    assert [t.status for t in trace] == [Status.SUCCESS]
    assert reconfigure.request is None
    assert reconfigure.feedback_message == reasoner.last_decision.explanation
    assert rig.manager.requests() == []
    assert backend_requests(rig) == before
    assert not reasoner.changed


def test_interrupting_reconfigure_withdraws_the_change(rig: SimulatedSystem) -> None:
    rig.backend.hang_next("pointcloud_to_laser", Transition.ACTIVATE)
    reasoner = pilot_reasoner()
    reasoner.component_failed("laser_resender")
    reconfigure = Reconfigure("Reconfigure", reasoner)
    tree = rig.tree(reconfigure)
    rig.tick_for(tree, 0.5)
    request = reconfigure.request
    assert request is not None and not request.done
    reconfigure.stop(Status.INVALID)
    assert request.reason == "cancelled"
    assert rig.manager.requests() == []
    assert rig.manager.target("pilot") == NORMAL


def test_reconfigure_checks_the_reasoner_against_the_model_at_setup(rig: SimulatedSystem) -> None:
    design = FunctionDesign("f_turbo_mode", frozenset({"battery"}),
                            {"energy": 0.1, "performance": 1.0, "safety": 0.9})
    reconfigure = Reconfigure("Reconfigure", Reasoner("pilot", [design], PILOT_OBJECTIVE))
    with pytest.raises(ValueError, match=r"^Reconfigure/Reconfigure: designs of pilot name modes the model lacks: "
                                         r"f_turbo_mode \(modes of pilot: "):
        rig.tree(reconfigure)

    other = SimulatedSystem(bundled("actuation"))
    with pytest.raises(ValueError, match=r"unknown part 'pilot' \(parts: actuation, manipulator, drive_base\)"):
        other.tree(Reconfigure("Reconfigure", pilot_reasoner()))
