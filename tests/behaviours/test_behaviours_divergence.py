"""OnDivergence and ModesToBlackboard: what the tree learns about parts straying from their targets.

The fault is laser_resender's (the MROS pilot): with the pilot in f_normal_mode the node fails
by itself (deactivating -> errorprocessing -> unconfigured); recovery is off, so the divergence
stays until somebody acts."""

from __future__ import annotations

import copy
import operator
import pickle
import time
from collections.abc import Iterator
from dataclasses import replace

import py_trees
import pytest
from harness import settle
from model_files import MODELS, bundled
from py_trees.blackboard import Blackboard
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.behaviours import ModesToBlackboard, OnDivergence, PartStatus
from sm_bt.engine.events import Cause, Divergence
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.model.loader import load_model
from sm_bt.model.states import State, StateMode
from sm_bt.sim import SimulatedSystem

GRACE = 2.0
PILOT_PARTS = ("pilot", "amcl", "controller_server", "pointcloud_to_laser", "laser_resender")


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.fixture
def rig() -> SimulatedSystem:
    """The pilot in f_normal_mode, recovery off."""
    rig = SimulatedSystem(bundled("pilot"), recovery=False, grace_period=GRACE)
    settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
    return rig


def fail_laser(rig: SimulatedSystem) -> float:
    """laser_resender fails by itself; returns when."""
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE, outcome=Outcome.ERROR)
    return rig.clock.now()


# -- OnDivergence -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("part", "feedback"), [(None, "every part on target"),
                                                ("laser_resender", "laser_resender on target")])
def test_on_target_is_failure(rig: SimulatedSystem, part: str | None, feedback: str) -> None:
    check = OnDivergence("Diverges?", part)
    tree = rig.tree(check)
    trace = rig.tick_for(tree, 3.0)
    assert {t.status for t in trace} == {Status.FAILURE}
    assert check.feedback_message == feedback
    assert not Blackboard.exists("/divergence")


def test_a_node_failing_by_itself_is_reported_after_the_grace_period(rig: SimulatedSystem) -> None:
    check = OnDivergence("Diverges?")
    tree = rig.tree(check)
    failed_at = fail_laser(rig)
    trace = rig.tick_until(tree, lambda: check.status is Status.SUCCESS)

    during_grace = [t for t in trace if t.time < failed_at + GRACE - 1e-6]
    assert len(during_grace) == 40
    assert {t.status for t in during_grace} == {Status.FAILURE}
    assert trace[-1].time == pytest.approx(failed_at + GRACE, abs=0.051)
    assert trace[-1].time >= failed_at + GRACE - 1e-6

    divergence = Blackboard.get("/divergence")
    assert isinstance(divergence, Divergence)
    assert divergence.part == "laser_resender", "with part=None the node comes first: the likely cause"
    assert divergence.target == StateMode(State.ACTIVE, "__DEFAULT__")
    assert divergence.actual.state is State.UNCONFIGURED
    assert divergence.since == pytest.approx(failed_at)
    assert divergence.cause is Cause.FAULT
    assert check.feedback_message == (
        "laser_resender: target active.__DEFAULT__, actual unconfigured (fault) for 2.0 s (+1 more)")


def test_watching_the_system_reports_the_system(rig: SimulatedSystem) -> None:
    check = OnDivergence("Pilot diverges?", "pilot")
    tree = rig.tree(check)
    failed_at = fail_laser(rig)
    rig.tick_until(tree, lambda: check.status is Status.SUCCESS)
    divergence = Blackboard.get("/divergence")
    assert divergence.part == "pilot"
    assert divergence.target == StateMode(State.ACTIVE, "f_normal_mode")
    assert divergence.since == pytest.approx(failed_at)
    assert "laser_resender is unconfigured" in divergence.actual.reason
    assert check.feedback_message.startswith("pilot: target active.f_normal_mode, actual ")
    assert "(+" not in check.feedback_message


def test_watching_another_part_ignores_the_laser(rig: SimulatedSystem) -> None:
    check = OnDivergence("Amcl diverges?", "amcl")
    tree = rig.tree(check)
    fail_laser(rig)
    trace = rig.tick_for(tree, 5.0)
    assert {t.status for t in trace} == {Status.FAILURE}
    assert check.feedback_message == "amcl on target"


def test_transient_divergences_only_count_with_errors_only_false(rig: SimulatedSystem) -> None:
    strict = OnDivergence("Error?", "laser_resender", variable_name="error")
    loose = OnDivergence("Any?", "laser_resender", variable_name="any", errors_only=False)
    tree = rig.tree(py_trees.composites.Parallel("Both", policy=py_trees.common.ParallelPolicy.SuccessOnAll(),
                                              children=[strict, loose]))
    fail_laser(rig)
    tree.tick()
    assert strict.status is Status.FAILURE
    assert loose.status is Status.SUCCESS
    assert Blackboard.get("/any").cause is Cause.GRACE
    assert not Blackboard.exists("/error")


def test_no_success_while_a_request_is_in_flight(rig: SimulatedSystem) -> None:
    check = OnDivergence("Error?")
    loose = OnDivergence("Any?", variable_name="any", errors_only=False)
    tree = rig.tree(py_trees.composites.Parallel("Both", policy=py_trees.common.ParallelPolicy.SuccessOnAll(),
                                              children=[check, loose]))
    rig.backend.hang_next("pointcloud_to_laser", Transition.ACTIVATE)
    request = rig.manager.change_mode("pilot", "f_degraded_mode", timeout=3.0)

    trace = rig.tick_for(tree, 2.9, watch=check)
    assert {t.status for t in trace} == {Status.FAILURE}, "the request explains the divergence"
    assert loose.status is Status.SUCCESS
    assert Blackboard.get("/any").cause is Cause.IN_FLIGHT

    # Once the request gave up, the divergence is an error after a new grace period.
    trace = rig.tick_until(tree, lambda: check.status is Status.SUCCESS, watch=check)
    assert request.done and request.reason.startswith("timed out after 3 s")
    assert trace[-1].time == pytest.approx(request.finished + GRACE, abs=0.051)


def test_the_variable_is_removed_once_the_divergence_clears(rig: SimulatedSystem) -> None:
    check = OnDivergence("Diverges?")
    tree = rig.tree(check)
    fail_laser(rig)
    rig.tick_until(tree, lambda: check.status is Status.SUCCESS)
    assert Blackboard.exists("/divergence")

    settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
    tree.tick()
    assert check.status is Status.FAILURE
    assert not Blackboard.exists("/divergence")
    assert check.feedback_message == "every part on target"


def test_the_variable_is_written_and_unset_only_when_it_changes(rig: SimulatedSystem) -> None:
    """Activity views (py-trees-blackboard-watcher -a, the tree watcher) show changes, not ticks."""
    Blackboard.enable_activity_stream()
    try:
        check = OnDivergence("Diverges?")
        tree = rig.tree(check)
        rig.tick_for(tree, 1.0)  # on target: nothing to unset, so nothing is written
        fail_laser(rig)
        rig.tick_until(tree, lambda: check.status is Status.SUCCESS)
        rig.tick_for(tree, 1.0)  # the same divergence, ticked on
        settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
        rig.tick_for(tree, 1.0)  # cleared once, then on target
        assert Blackboard.activity_stream is not None
        kinds = [(item.key, item.activity_type) for item in Blackboard.activity_stream.data
                 if item.activity_type in ("WRITE", "UNSET", "INITIALISED")]
        assert kinds == [("/divergence", "INITIALISED"), ("/divergence", "UNSET")]
    finally:
        Blackboard.disable_activity_stream()


def test_a_custom_variable_name(rig: SimulatedSystem) -> None:
    check = OnDivergence("Laser lost?", "laser_resender", variable_name="laser/lost")
    tree = rig.tree(check)
    fail_laser(rig)
    rig.tick_until(tree, lambda: check.status is Status.SUCCESS)
    assert Blackboard.get("/laser/lost").part == "laser_resender"
    assert not Blackboard.exists("/divergence")


def test_the_blackboard_access_is_on_an_attached_client(rig: SimulatedSystem) -> None:
    check = OnDivergence("Diverges?", variable_name="problem")
    assert check.blackboards == [check.blackboard]
    assert check.blackboard.write == {"/problem"}
    tree = rig.tree(check)
    snapshot = py_trees.visitors.SnapshotVisitor()
    tree.add_visitor(snapshot)
    tree.tick()
    assert "/problem" in snapshot.visited_blackboard_keys
    assert check.blackboard.id() in snapshot.visited_blackboard_client_ids


# -- ModesToBlackboard --------------------------------------------------------------------------------


def test_every_part_is_written_under_system_modes() -> None:
    rig = SimulatedSystem(bundled("pilot"), recovery=False)
    writer = ModesToBlackboard()
    tree = rig.tree(writer)
    tree.tick()
    assert writer.status is Status.SUCCESS
    assert writer.feedback_message == "5 part(s) changed"
    for part in PILOT_PARTS:
        assert Blackboard.get(f"/system_modes/{part}") == PartStatus(part, "unconfigured", None, None, None, None)
        assert str(Blackboard.get(f"/system_modes/{part}")) == "unconfigured (no target)"
    assert sorted(Blackboard.keys()) == sorted(f"/system_modes/{part}" for part in PILOT_PARTS)


def test_the_blackboard_follows_changes(rig: SimulatedSystem) -> None:
    writer = ModesToBlackboard()
    tree = rig.tree(writer)
    tree.tick()
    pilot = Blackboard.get("/system_modes/pilot")
    assert pilot == PartStatus("pilot", "active", "f_normal_mode", "active", "f_normal_mode", None)
    assert pilot.state_mode == "active.f_normal_mode"
    assert str(pilot) == "active.f_normal_mode (target active.f_normal_mode)"
    assert str(Blackboard.get("/system_modes/pointcloud_to_laser")) == "inactive (target inactive)"
    tree.tick()
    assert writer.feedback_message == "0 part(s) changed"

    fail_laser(rig)
    rig.clock.advance(0.2)
    tree.tick()
    laser = Blackboard.get("/system_modes/laser_resender")
    assert laser == PartStatus("laser_resender", "unconfigured", None, "active", "__DEFAULT__", "grace")
    assert Blackboard.get("/system_modes/pilot").divergence == "grace"
    assert writer.feedback_message == "2 part(s) changed"
    # plain data (py_trees_ros pickles it to tell watchers of changes); str() says since when
    assert pickle.loads(pickle.dumps(laser)) == laser and copy.deepcopy(laser) == laser
    assert laser.since is not None and 0.0 < laser.since < 0.2
    assert str(laser) == f"unconfigured (target active.__DEFAULT__: grace since t={laser.since:.1f} s)"
    assert str(replace(laser, since=1_700_000_000.0)).endswith(
        f"grace since {time.strftime('%H:%M:%S', time.localtime(1_700_000_000.0))})")  # a wall clock's

    rig.clock.advance(GRACE)
    tree.tick()
    assert Blackboard.get("/system_modes/laser_resender").divergence == "fault"

    settle(rig, rig.manager.change_mode("pilot", "f_performance_mode"))
    tree.tick()
    assert Blackboard.get("/system_modes/pilot") == PartStatus("pilot", "active", "f_performance_mode", "active",
                                                               "f_performance_mode", None)
    assert Blackboard.get("/system_modes/controller_server").mode == "FAST"
    assert Blackboard.get("/system_modes/laser_resender").divergence is None


def test_the_keys_are_registered_on_the_attached_client(rig: SimulatedSystem) -> None:
    writer = ModesToBlackboard()
    assert writer.blackboards == [writer.blackboard]
    tree = rig.tree(writer)
    assert writer.blackboard.write == {f"/system_modes/{part}" for part in PILOT_PARTS}
    snapshot = py_trees.visitors.SnapshotVisitor()
    tree.add_visitor(snapshot)
    tree.tick()
    assert snapshot.visited_blackboard_keys == {f"/system_modes/{part}" for part in PILOT_PARTS}


def test_a_namespace_and_a_subset_of_parts(rig: SimulatedSystem) -> None:
    writer = ModesToBlackboard("Modes", namespace="/robot/modes/", parts=["pilot", "amcl"])
    tree = rig.tree(writer)
    tree.tick()
    assert writer.blackboard.write == {"/robot/modes/pilot", "/robot/modes/amcl"}
    assert sorted(Blackboard.keys()) == ["/robot/modes/amcl", "/robot/modes/pilot"]
    assert str(Blackboard.get("/robot/modes/amcl")) == "active.__DEFAULT__ (target active.__DEFAULT__)"


def test_namespaced_part_names_nest_under_the_namespace() -> None:
    rig = SimulatedSystem(load_model(MODELS / "loader_namespaced.yaml"))
    writer = ModesToBlackboard()
    rig.tree(writer).tick()
    expected = ["/system_modes/arms", "/system_modes/left/gripper", "/system_modes/right/gripper",
                "/system_modes/wrist"]
    assert sorted(writer.blackboard.write) == expected
    assert sorted(Blackboard.keys()) == expected
    assert Blackboard.get("/system_modes/left/gripper").part == "left/gripper"


def test_other_behaviours_can_read_it(rig: SimulatedSystem) -> None:
    check = py_trees.behaviours.CheckBlackboardVariableValue(
        "Normal?", py_trees.common.ComparisonExpression("/system_modes/pilot.mode", "f_normal_mode", operator.eq))
    root = py_trees.composites.Sequence("Root", memory=False, children=[ModesToBlackboard(), check])
    tree = rig.tree(root)
    tree.tick()
    assert root.status is Status.SUCCESS
    settle(rig, rig.manager.change_mode("pilot", "f_slow_mode"))
    tree.tick()
    assert check.status is Status.FAILURE
