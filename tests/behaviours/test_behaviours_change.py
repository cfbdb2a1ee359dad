"""ChangeMode and ChangeState in real py_trees trees, against simulated nodes on virtual time."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import py_trees
import pytest
from harness import settle
from model_files import bundled
from py_trees.common import Status
from tree_helpers import Flag, backend_requests, fresh_blackboard

from sm_bt.behaviours import CanChangeMode, ChangeMode, ChangeState, FeedbackSnapshotVisitor
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State, StateMode
from sm_bt.sim import SimulatedSystem

FAST = {"FollowPath.max_vel_x": 0.5, "FollowPath.max_speed_xy": 0.5, "FollowPath.max_vel_theta": 1.5,
        "FollowPath.transform_tolerance": 0.2}


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def pilot_rig(**options: object) -> SimulatedSystem:
    return SimulatedSystem(bundled("pilot"), recovery=False, **options)


# -- ChangeMode: progress and success ---------------------------------------------------------------


def test_change_mode_on_a_system_reports_each_step_then_succeeds() -> None:
    rig = pilot_rig()
    change = ChangeMode("Performance", "pilot", "f_performance_mode")
    trace = rig.tick_until_done(rig.tree(change))

    running = [t.feedback for t in trace if t.status is Status.RUNNING]
    # The step in progress, and the plan previewed before the request: 8 calls, as were made.
    assert running == [
        "amcl: configure (1 of 2 steps to active); controller_server: set parameters of mode FAST; "
        "pointcloud_to_laser: configure; laser_resender: configure (1 of 2 steps to active) (plan: 8 calls)",
        "amcl: activate; controller_server: configure (1 of 2 steps to active); laser_resender: activate "
        "(plan: 8 calls)",
        "controller_server: activate (plan: 8 calls)",
    ]
    assert change.plan is not None and change.plan.calls == 8
    assert trace[-1].status is Status.SUCCESS
    assert trace[-1].time == pytest.approx(0.15)
    assert change.feedback_message == "pilot is active.f_performance_mode (0.11 s)"
    assert str(rig.manager.actual("pilot")) == "active.f_performance_mode"
    assert str(rig.manager.actual("controller_server")) == "active.FAST"
    assert rig.backend.node("controller_server").parameters == FAST
    assert rig.backend.node("pointcloud_to_laser").state is State.INACTIVE
    assert rig.backend.node("laser_resender").state is State.ACTIVE
    assert change.request is not None and change.request.succeeded
    assert rig.manager.requests() == []


def test_change_mode_on_a_node() -> None:
    rig = pilot_rig()
    change = ChangeMode("Fast", "controller_server", "FAST")
    trace = rig.tick_until_done(rig.tree(change))

    assert [t.status for t in trace] == [Status.RUNNING, Status.RUNNING, Status.RUNNING, Status.SUCCESS]
    assert len({t.feedback for t in trace[:-1]}) > 1, "the feedback follows the steps"
    assert change.feedback_message.startswith("controller_server is active.FAST (")
    assert str(rig.manager.actual("controller_server")) == "active.FAST"
    assert rig.backend.node("controller_server").parameters == FAST
    # Only the node itself was touched.
    assert {line.split(":")[0] for line in backend_requests(rig)} == {"controller_server"}


def test_change_mode_accepts_the_default_mode_marker() -> None:
    rig = pilot_rig()
    settle(rig, rig.manager.change_mode("controller_server", "FAST"))
    change = ChangeMode("Default", "controller_server", "__DEFAULT__")
    rig.tick_until_done(rig.tree(change))
    assert change.status is Status.SUCCESS
    assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
    assert rig.backend.node("controller_server").parameters["FollowPath.max_vel_x"] == 0.3


def test_a_part_already_in_the_mode_succeeds_in_one_tick() -> None:
    rig = pilot_rig()
    settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
    before = len(backend_requests(rig))
    change = ChangeMode("Normal", "pilot", "f_normal_mode")
    trace = rig.tick_until_done(rig.tree(change))
    assert [t.status for t in trace] == [Status.SUCCESS]
    assert len(backend_requests(rig)) == before


# -- ChangeMode: failures carry the manager's reason --------------------------------------------------


Fault = Callable[[SimulatedSystem], None]


def _reject(rig: SimulatedSystem) -> None:
    rig.backend.reject_parameters("controller_server", "read-only")


def _refuse_configure(rig: SimulatedSystem) -> None:
    rig.backend.fail_next("controller_server", Transition.CONFIGURE)


def _hang_activate(rig: SimulatedSystem) -> None:
    rig.backend.hang_next("controller_server", Transition.ACTIVATE)


@pytest.mark.parametrize("part", ["pilot", "controller_server"])
@pytest.mark.parametrize(("mode", "fault", "timeout", "reason", "failed_at"), [
    pytest.param({"pilot": "f_performance_mode", "controller_server": "FAST"}, _reject, None,
                 "controller_server: set parameters of mode FAST failed: read-only", 0.05, id="rejected-parameters"),
    pytest.param({"pilot": "f_performance_mode", "controller_server": "FAST"}, _refuse_configure, None,
                 "controller_server: configure failed: configure of controller_server failed: "
                 "on_configure returned FAILURE", 0.1, id="refused-transition"),
    pytest.param({"pilot": "f_performance_mode", "controller_server": "FAST"}, _hang_activate, 0.5,
                 "timed out after 0.5 s (controller_server hung in activating for 0.44 s)", 0.5, id="timeout"),
])
def test_change_mode_fails_with_the_managers_reason(part: str, mode: dict[str, str], fault: Fault,
                                                    timeout: float | None, reason: str, failed_at: float) -> None:
    rig = pilot_rig()
    fault(rig)
    change = ChangeMode("Change", part, mode[part], timeout=timeout)
    trace = rig.tick_until_done(rig.tree(change))

    assert trace[-1].status is Status.FAILURE
    assert {t.status for t in trace[:-1]} <= {Status.RUNNING}
    assert change.feedback_message == reason
    assert change.request is not None and change.request.reason == reason
    # The failure is seen at the first tick after the manager gave up (virtual time).
    assert trace[-1].time == pytest.approx(failed_at, abs=0.051)
    assert rig.manager.requests() == []
    assert str(rig.manager.actual("controller_server")) != "active.FAST"


def test_timeout_must_be_positive() -> None:
    with pytest.raises(ValueError, match="timeout must be positive, not 0"):
        ChangeMode("Change", "pilot", "f_normal_mode", timeout=0)


# -- interruption withdraws the request ---------------------------------------------------------------


@pytest.mark.parametrize(("part", "mode"), [("pilot", "f_performance_mode"), ("controller_server", "FAST")])
def test_a_higher_priority_branch_taking_over_withdraws_the_change(part: str, mode: str) -> None:
    rig = pilot_rig()
    emergency = Flag("Emergency?")
    change = ChangeMode("Change", part, mode)
    root = py_trees.composites.Selector("Root", memory=False, children=[emergency, change])
    tree = rig.tree(root)
    tree.tick()
    rig.clock.advance(0.02)  # configuring: no activation asked for yet
    tree.tick()
    assert change.status is Status.RUNNING
    request = change.request
    assert request is not None and rig.manager.requests() == [request]

    emergency.on = True
    tree.tick()
    sent = backend_requests(rig)
    assert change.status is Status.INVALID
    assert request.done and not request.succeeded
    assert request.reason == "cancelled"
    assert change.feedback_message == f"cancelled: change_mode {part} {mode}"
    assert rig.manager.requests() == []
    assert rig.manager.target(part) is None, "the previous target (none) is back"

    rig.tick_for(tree, 5.0)
    assert backend_requests(rig) == sent, "no step is sent after the interruption"
    assert not any("activate" in line for line in sent)


def test_stopping_the_behaviour_directly_withdraws_the_change() -> None:
    rig = pilot_rig()
    change = ChangeMode("Change", "pilot", "f_normal_mode")
    tree = rig.tree(change)
    tree.tick()
    request = change.request
    assert request is not None and not request.done

    change.stop(Status.INVALID)
    assert request.reason == "cancelled"
    assert rig.manager.requests() == []
    sent = backend_requests(rig)
    rig.run(5.0)
    assert backend_requests(rig) == sent


def test_a_finished_change_is_not_cancelled_when_the_tree_moves_on() -> None:
    rig = pilot_rig()
    change = ChangeMode("Change", "pilot", "f_normal_mode")
    tree = rig.tree(change)
    rig.tick_until_done(tree)
    request = change.request
    change.stop(Status.INVALID)
    assert request is not None and request.succeeded and request.reason == ""
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_normal_mode")


# -- ChangeState --------------------------------------------------------------------------------------


@pytest.mark.parametrize(("model", "part"), [("actuation", "actuation"), ("actuation", "drive_base"),
                                             ("pilot", "amcl")])
def test_change_state_walks_the_lifecycle(model: str, part: str) -> None:
    rig = SimulatedSystem(bundled(model), recovery=False)
    expected = [("configure", "inactive"), ("activate", "active.__DEFAULT__"), ("deactivate", "inactive"),
                ("cleanup", "unconfigured"), ("shutdown", "finalized")]
    for transition, state in expected:
        change = ChangeState(transition.title(), part, transition)
        trace = rig.tick_until_done(rig.tree(change))
        assert trace[0].status is Status.RUNNING, f"{transition} takes time"
        assert trace[-1].status is Status.SUCCESS, change.feedback_message
        assert change.feedback_message.startswith(f"{part} is {state} (")
        assert str(rig.manager.actual(part)) == state
    assert rig.manager.requests() == []


def test_change_state_accepts_a_transition_enum() -> None:
    assert ChangeState("Configure", "amcl", Transition.CONFIGURE).transition == "configure"


@pytest.mark.parametrize("transition", ["explode", "Configure", "destroy", Transition.ON_CONFIGURE_SUCCESS])
def test_change_state_rejects_an_unknown_transition_at_construction(transition: str | Transition) -> None:
    with pytest.raises(ValueError, match=r"cannot request transition .* \(one of: configure, activate, "
                                         r"deactivate, cleanup, shutdown\)"):
        ChangeState("Bad", "amcl", transition)


@pytest.mark.parametrize("part", ["amcl", "pilot"])
def test_a_transition_invalid_from_the_current_state_fails_with_the_reason(part: str) -> None:
    rig = pilot_rig()
    change = ChangeState("Activate", part, "activate")
    trace = rig.tick_until_done(rig.tree(change))
    assert [t.status for t in trace] == [Status.FAILURE]
    assert change.feedback_message == (f"{part}: transition activate is not valid in state unconfigured "
                                       "(valid: configure, shutdown)")
    assert backend_requests(rig) == []
    assert rig.manager.requests() == []


def test_activate_keeps_the_last_mode() -> None:
    rig = pilot_rig()
    settle(rig, rig.manager.change_mode("pilot", "f_performance_mode"))
    for transition in ("deactivate", "activate"):
        change = ChangeState(transition.title(), "pilot", transition)
        rig.tick_until_done(rig.tree(change))
        assert change.status is Status.SUCCESS, change.feedback_message
    assert change.feedback_message.startswith("pilot is active.f_performance_mode (")
    assert str(rig.manager.actual("pilot")) == "active.f_performance_mode"
    assert rig.backend.node("controller_server").parameters == FAST


def test_interrupting_change_state_withdraws_it() -> None:
    rig = pilot_rig()
    rig.backend.set_delay("amcl", 1.0)
    change = ChangeState("Configure", "amcl", "configure")
    root = py_trees.composites.Sequence("Task", memory=True, children=[change])
    tree = rig.tree(root)
    rig.tick_until(tree, lambda: rig.clock.now() >= 0.5)
    assert change.status is Status.RUNNING
    assert change.feedback_message == "amcl: configure"
    request = change.request
    root.stop(Status.INVALID)  # the parent is stopped (as a selector or parallel would)
    assert change.status is Status.INVALID
    assert request is not None and request.reason == "cancelled"
    assert rig.manager.requests() == []


def test_each_new_step_of_a_mode_change_flags_a_snapshot_as_changed() -> None:
    rig = pilot_rig()
    change = ChangeMode("Normal", "pilot", "f_normal_mode")
    tree = py_trees.trees.BehaviourTree(change)
    visitor = FeedbackSnapshotVisitor()
    plain = py_trees.visitors.SnapshotVisitor()
    tree.visitors += [visitor, plain]
    tree.setup(manager=rig.manager)
    flagged: list[tuple[bool, bool, str]] = []
    while change.status is not Status.SUCCESS:
        tree.tick()
        flagged.append((visitor.changed, plain.changed, change.feedback_message))
        assert visitor.status_changed == plain.changed  # what py_trees flags, apart
        rig.clock.advance(0.05)
    running = [f for f in flagged if f[2] and " s)" not in f[2]]  # the RUNNING ticks
    steps = {message for _, _, message in running}
    assert len(steps) >= 2, steps  # configure, then activate: feedback moved while RUNNING
    for (mine, plain_changed, message), (_, _, before) in zip(flagged[1:], flagged, strict=False):
        assert mine == (plain_changed or message != before)
    assert any(mine and not plain_changed for mine, plain_changed, _ in flagged[1:])


def test_requests_say_who_asked_the_tree_or_the_caller() -> None:
    rig = pilot_rig()
    refused = rig.manager.change_state("pilot", "activate", requester="operator")  # not from unconfigured
    assert refused.refused and not refused.succeeded and refused.requester == "operator"
    change = ChangeState("Configure", "pilot", "configure")
    tree = rig.tree(change)
    tree.tick()
    (by_tree,) = rig.manager.requests()
    assert by_tree.requester == "tree"
    rig.tick_until_done(tree)
    assert rig.manager.change_mode("pilot", "f_normal_mode").requester == "user"
    assert rig.manager.change_mode("pilot", "f_slow_mode", requester="operator").requester == "operator"


def test_can_change_mode_says_whether_a_change_could_be_made_now_without_asking_for_it() -> None:
    rig = pilot_rig()
    can = CanChangeMode("Degraded possible?", "pilot", "f_degraded_mode")
    tree = rig.tree(can)
    tree.tick()
    assert can.status is Status.SUCCESS and can.feedback_message == (
        "8 calls: pointcloud_to_laser configure+activate, amcl set DEGRADED+configure+activate, "
        "controller_server set DEGRADED+configure+activate")  # laser_resender stays unconfigured
    assert rig.manager.requests() == [] and str(rig.manager.actual("pilot")) == "unconfigured"  # nothing asked
    rig.crash("laser_resender")
    rig.clock.advance(2.0)
    tree.tick()
    assert can.status is Status.FAILURE
    assert can.feedback_message == ("cannot be made now: laser_resender is not reachable (no answer for 1.0 s "
                                    "(crashed?))")


# -- priority and queue against the manager's holds --------------------------------------------------


def test_a_change_at_a_priority_overrides_a_lower_hold_and_one_queued_waits_for_a_higher_one(
        tmp_path: Path) -> None:
    from sm_bt.trees.mission_xml import load_tree

    rig = pilot_rig()
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    hold = rig.manager.hold("pilot", "f_degraded_mode", requester="operator", lease=4.0)
    rig.finish(hold.request)
    # The tree's own priority (40) is refused at once, naming the holder.
    refused = ChangeMode("Slow", "pilot", "f_slow_mode")
    trace = rig.tick_until_done(rig.tree(refused))
    assert trace[-1].status is Status.FAILURE and "held in active.f_degraded_mode by operator" in trace[-1].feedback
    # Queued, it is RUNNING while held (saying so), and goes ahead once the lease runs out.
    queued = ChangeMode("Slow", "pilot", "f_slow_mode", timeout=10.0, queue=True)
    tree = rig.tree(queued)
    tree.tick()
    assert queued.status is Status.RUNNING and queued.feedback_message.startswith("queued: pilot is held in ")
    trace = rig.tick_until_done(tree, timeout=10.0)
    assert trace[-1].status is Status.SUCCESS and not hold.active
    # From XML: the attributes are text.
    file = tmp_path / "mission.xml"
    file.write_text('<root><BehaviorTree ID="M"><ChangeMode part="pilot" mode="f_normal_mode" priority="90" '
                    'queue="false"/></BehaviorTree></root>')
    rig.finish(rig.manager.hold("pilot", "f_slow_mode", requester="operator").request)
    trace = rig.tick_until_done(rig.tree(load_tree(file, model=rig.manager.model)))
    assert trace[-1].status is Status.SUCCESS and str(rig.manager.actual("pilot")) == "active.f_normal_mode"
    with pytest.raises(ValueError, match="priority must be a whole number, 0 or more, not 'high'"):
        ChangeMode("Bad", "pilot", "f_normal_mode", priority="high")
    with pytest.raises(ValueError, match="queue must be true or false, not 'maybe'"):
        ChangeMode("Bad", "pilot", "f_normal_mode", queue="maybe")
