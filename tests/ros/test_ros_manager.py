"""The ROS 2 backend and the mode manager node against real rclpy lifecycle nodes in other processes.

Node processes run ``sm-bt sim-nodes`` (several nodes per process); the manager runs
embedded in the test process (``RosRuntime``) or as ``sm-bt manager`` in its own process; plain
rclpy clients play the part of existing system_modes users.
"""

from __future__ import annotations

import gc
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from harness import settle
from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableStates, GetState
from model_files import bundled
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_harness import BACKEND_OPTIONS, RosHarness
from ros_processes import NodeProcess, RosContext, Starter, call, line_within, wait_until
from sm_bt_msgs.srv import HoldMode, RequestChange
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetAvailableModes, GetMode

from sm_bt.cli import main
from sm_bt.engine.backend import CallResult, NodeReport
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State, StateMode
from sm_bt.ros.discovery import GRAPH_CATCH_UP
from sm_bt.ros.peers import NodeCall
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")


def harness(process: NodeProcess, model: str = "pilot", **options: Any) -> RosHarness:
    return RosHarness(bundled(model), process, **options)


@pytest.fixture
def pilot(node_processes: Starter) -> Iterator[RosHarness]:
    rig = harness(node_processes("pilot"))
    yield rig
    rig.close()


# -- the backend: live state, transitions, parameters ----------------------------------------------


def test_a_manager_started_after_the_nodes_picks_up_their_live_state(node_processes: Starter) -> None:
    process = node_processes("pilot", "--state", "active")
    rig = harness(process)
    try:
        for node in NODES:
            observed = rig.manager.observation(node)
            assert observed.state is State.ACTIVE, node
            assert observed.lifecycle
        assert rig.manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.3
        assert str(rig.manager.actual("controller_server")) == "active.__DEFAULT__"
        # Every pilot node active (pointcloud_to_laser too): no mode of the pilot has exactly that.
        assert rig.manager.actual("pilot").state is not State.UNKNOWN
    finally:
        rig.close()


def test_configure_activate_and_mode_changes_of_a_system_are_confirmed(pilot: RosHarness) -> None:
    manager = pilot.manager
    settle(pilot, manager.change_state("pilot", "configure"))
    assert manager.actual("pilot").state is State.INACTIVE
    assert {manager.observation(n).state for n in NODES} == {State.INACTIVE}
    settle(pilot, manager.change_mode("pilot", "f_performance_mode"))
    assert str(manager.actual("pilot")) == "active.f_performance_mode"
    assert manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.5
    settle(pilot, manager.change_mode("pilot", "f_energy_saving_mode"))
    assert str(manager.actual("controller_server")) == "active.SLOW"
    settle(pilot, manager.change_state("pilot", "deactivate"))
    assert manager.actual("pilot").state is State.INACTIVE


def test_the_calls_of_a_finished_change_leave_nothing_for_the_garbage_collector(pilot: RosHarness) -> None:
    """A call's timer, future and callbacks refer back to it: kept after it finished, every call
    of a change would be a cycle of closures for the collector (hundreds of objects a request)."""
    manager = pilot.manager
    gc.collect()
    gc.disable()
    try:
        settle(pilot, manager.change_state("pilot", "configure"))
        settle(pilot, manager.change_mode("pilot", "f_performance_mode"))
        time.sleep(0.2)  # late answers and events of the change, dropped or matched
        left = [o for o in gc.get_objects() if isinstance(o, NodeCall) and o.finished]
    finally:
        gc.enable()
    assert left == []


def test_a_transition_the_node_refuses_fails_with_the_reason_and_the_node_keeps_serving(pilot: RosHarness) -> None:
    backend = pilot.runtime.backend
    results: list[CallResult] = []
    done = threading.Event()

    def record(result: CallResult) -> None:
        results.append(result)
        done.set()

    # amcl is unconfigured: activate is not a transition of that state (rclpy would crash on the id alone).
    backend.change_state("amcl", Transition.ACTIVATE, record)
    assert done.wait(5.0)
    assert not results[0].ok and results[0].refused  # nothing ran: the caller's view was out of date
    assert results[0].reason == "activate of amcl refused: not a transition of its state unconfigured " \
                                "(available: configure, shutdown)"
    settle(pilot, pilot.manager.change_mode("amcl", "__DEFAULT__"))
    assert str(pilot.manager.actual("amcl")) == "active.__DEFAULT__"


def test_a_transition_refused_on_an_out_of_date_state_is_planned_again_from_the_state_the_node_gives(
        node_processes: Starter) -> None:
    """A refusal means the manager's view of the node was out of date, and it waits for the next
    report: when no event will tell it (one lost on a busy machine), the refusal's own explanation
    does, and the request goes on from there instead of waiting until it times out. (Liveness
    probes would correct the state of the node they probe, one per process: not here.)"""
    pilot = harness(node_processes("pilot"), backend_options={"probe_interval": 60.0})
    try:
        _refused_then_replanned(pilot)
    finally:
        pilot.close()


def _refused_then_replanned(pilot: RosHarness) -> None:
    backend = pilot.runtime.backend
    assert pilot.manager.observation("amcl").state is State.UNCONFIGURED
    # As a transition event that was never sent would leave it: the manager thinks amcl inactive.
    backend._events.on_transition_event(backend._peer("amcl"), State.INACTIVE)
    pilot.run_until(lambda: pilot.manager.observation("amcl").state is State.INACTIVE)
    request = pilot.manager.change_mode("amcl", "__DEFAULT__")  # planned as one activate: refused
    pilot.run_until(lambda: request.done, timeout=8.0)
    assert request.succeeded, request.reason
    assert str(pilot.manager.actual("amcl")) == "active.__DEFAULT__"


def test_a_transition_whose_callback_fails_fails_the_request_with_the_reason(pilot: RosHarness) -> None:
    pilot.fail_next("amcl", Transition.CONFIGURE)
    request = pilot.manager.change_state("amcl", "configure")
    pilot.run_until(lambda: request.done)
    assert not request.succeeded
    assert "configure of amcl failed: its on_configure callback did not succeed (node now unconfigured)" \
        in request.reason, request.reason


def test_a_rejected_parameter_set_fails_the_request_with_the_nodes_reason(pilot: RosHarness) -> None:
    settle(pilot, pilot.manager.change_mode("controller_server", "__DEFAULT__"))
    pilot.reject_parameters("controller_server", "locked by the safety officer")
    request = pilot.manager.change_mode("controller_server", "FAST")
    pilot.run_until(lambda: request.done)
    assert not request.succeeded
    assert "locked by the safety officer" in request.reason
    assert pilot.manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.3


def test_parameters_changed_behind_the_managers_back_are_seen(pilot: RosHarness) -> None:
    settle(pilot, pilot.manager.change_mode("controller_server", "__DEFAULT__"))
    pilot.set_parameter("controller_server", "FollowPath.max_vel_x", 0.1)
    pilot.run_until(lambda: pilot.manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.1)


def test_a_plain_node_is_reported_as_such_and_cannot_change_state(node_processes: Starter) -> None:
    process = node_processes("actuation", "--parameters-only", "manipulator", "--only", "drive_base")
    rig = harness(process, "actuation")
    try:
        observed = rig.manager.observation("manipulator")
        assert observed.reachable and not observed.lifecycle
        actual = rig.manager.actual("manipulator")
        assert actual.state is State.ACTIVE and actual.state_inferred, "inferred, not reported"
        request = rig.manager.change_state("manipulator", "deactivate")
        rig.run_until(lambda: request.done)
        assert not request.succeeded
        assert "no lifecycle services" in request.reason
        # Its parameters are still managed.
        settle(rig, rig.manager.change_mode("manipulator", "STRONG"))
        assert rig.manager.observation("manipulator").parameters["max_torque"] == 0.2
    finally:
        rig.close()


# -- crashes and restarts -----------------------------------------------------------------------------


def test_killing_a_node_mid_change_fails_the_request_marks_it_unknown_and_recovery_restores_it(
        node_processes: Starter, ros_context: RosContext) -> None:
    others = node_processes("pilot", "--only", "amcl,pointcloud_to_laser,laser_resender")
    controller = node_processes("pilot", "--only", "controller_server")
    rig = harness(others, recovery=True, grace_period=0.5)
    try:
        rig.set_parameter("controller_server", "sim.transition_delay", 3.0)
        request = rig.manager.change_mode("pilot", "f_normal_mode")
        rig.run_until(lambda: rig.manager.observation("amcl").state is State.ACTIVE, 5.0)
        controller.kill()
        killed = time.monotonic()
        rig.run_until(lambda: request.done, 15.0)
        assert not request.succeeded
        assert "controller_server" in request.reason, request.reason
        rig.run_until(lambda: not rig.manager.observation("controller_server").reachable, 10.0)
        assert time.monotonic() - killed < BACKEND_OPTIONS["call_timeout"] + BACKEND_OPTIONS["liveness_timeout"] + 1
        assert rig.manager.actual("controller_server").state is State.UNKNOWN
        assert rig.manager.actual("controller_server").reason, "unknown, with a reason"
        # The manager keeps serving its interface.
        get_state = ros_context.client(GetState, "/pilot/get_state")
        ros_context.wait_for([get_state])
        assert call(get_state, GetState.Request(), timeout=2.0).current_state.id == StateMsg.PRIMARY_STATE_UNKNOWN
        # A fresh process (unconfigured, default parameters): recovery brings it back to its target.
        controller.start()
        rig.run_until(lambda: str(rig.manager.actual("pilot")) == "active.f_normal_mode", 20.0)
        assert str(rig.manager.actual("controller_server")) == "active.__DEFAULT__"
        assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
    finally:
        rig.close()


def test_a_node_shut_down_and_restarted_rejoins_its_system_over_ros(node_processes: Starter) -> None:
    """Issue 27, item 3, on ROS: controller_server shut down (finalized), its process restarted.
    Before, the manager shut the new process down again and refused every later request of the
    pilot ("controller_server is finalized (it must be restarted)")."""
    others = node_processes("pilot", "--only", "amcl,pointcloud_to_laser,laser_resender")
    controller = node_processes("pilot", "--only", "controller_server")
    rig = harness(others, recovery=True, grace_period=0.5)
    try:
        settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
        settle(rig, rig.manager.change_state("controller_server", "shutdown"))
        assert rig.manager.actual("controller_server").state is State.FINALIZED
        refused = rig.manager.change_mode("pilot", "f_degraded_mode")
        assert refused.refused and "controller_server is finalized (it must be restarted)" in refused.reason
        controller.stop()
        controller.start()  # a new process, unconfigured
        rig.run_until(lambda: str(rig.manager.actual("controller_server")) == "active.__DEFAULT__", 15.0)
        assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
        settle(rig, rig.manager.change_mode("pilot", "f_degraded_mode"), 15.0)
        assert str(rig.manager.actual("pilot")) == "active.f_degraded_mode"
    finally:
        rig.close()


def test_a_node_that_stops_cleanly_is_reported_gone_at_once(node_processes: Starter) -> None:
    others = node_processes("pilot", "--only", "amcl,controller_server,pointcloud_to_laser")
    laser = node_processes("pilot", "--only", "laser_resender")
    rig = harness(others)
    try:
        laser.stop()
        took = wait_until(lambda: not rig.manager.observation("laser_resender").reachable, 5.0, "not reported gone")
        assert took < BACKEND_OPTIONS["liveness_timeout"] + 1.0
        assert "left the ROS graph" in rig.manager.observation("laser_resender").gone
    finally:
        rig.close()


def test_a_node_missing_from_the_graph_while_the_manager_stands_still_is_looked_at_again_then_judged(
        node_processes: Starter) -> None:
    """Right after this process stood still, the graph may lack nodes that are there (seen under load:
    every node of a process missing for 0.1 s after a 1.8 s stop, told as "left the ROS graph"): a
    node missing then is looked at again, and judged once the process has gone on for a while."""
    others = node_processes("pilot", "--only", "amcl,controller_server,pointcloud_to_laser")
    laser = node_processes("pilot", "--only", "laser_resender")
    rig = harness(others)
    clock = rig.runtime.clock
    standing = threading.Event()

    def stand_still() -> None:  # what the clock's thread records after each stall
        while not standing.wait(0.05):
            clock.resumed = clock.now()

    stalls = threading.Thread(target=stand_still)
    try:
        stalls.start()
        laser.stop()
        stopped = time.monotonic()
        time.sleep(2.0)
        assert rig.manager.observation("laser_resender").reachable, rig.manager.observation("laser_resender")
        standing.set()
        stalls.join()
        went_on = time.monotonic()
        wait_until(lambda: not rig.manager.observation("laser_resender").reachable, 5.0, "never judged")
        assert "left the ROS graph" in rig.manager.observation("laser_resender").gone
        assert time.monotonic() - went_on >= GRAPH_CATCH_UP - 0.1, f"judged {time.monotonic() - stopped:.2f} s after"
    finally:
        standing.set()
        if stalls.is_alive():
            stalls.join()
        rig.close()


# -- the manager node's interface, for plain rclpy clients ---------------------------------------------


@pytest.fixture
def manager_process(tmp_path: Path) -> Iterator[subprocess.Popen[str]]:
    """``sm-bt manager actuation`` in its own process (SIGINT, then SIGKILL at teardown). Its log
    goes to a file (a pipe nobody reads could fill up and block it)."""
    log = (tmp_path / "manager.log").open("w")
    process = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "manager", "actuation", "--grace-period", "0.5"],
                               stdout=subprocess.PIPE, stderr=log, text=True)
    yield process
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(3.0)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5.0)
    log.close()


def test_a_plain_client_changes_the_mode_of_actuation_and_sees_mode_event(
        node_processes: Starter, manager_process: subprocess.Popen[str], ros_context: RosContext,
        tmp_path: Path) -> None:
    node_processes("actuation")
    ros = ros_context
    change_mode = ros.client(ChangeMode, "/actuation/change_mode")
    get_mode = ros.client(GetMode, "/actuation/get_mode")
    modes = ros.client(GetAvailableModes, "/actuation/get_available_modes")
    change_state = ros.client(ChangeState, "/actuation/change_state")
    get_state = ros.client(GetState, "/actuation/get_state")
    states = ros.client(GetAvailableStates, "/actuation/get_available_states")
    events: list[Any] = []
    ros.node.create_subscription(ModeEvent, "/actuation/mode_event", events.append, LATCHED)
    requests: list[Any] = []
    ros.node.create_subscription(ModeEvent, "/actuation/mode_request_info", requests.append, LATCHED)
    transitions: list[Any] = []
    ros.node.create_subscription(TransitionEvent, "/actuation/transition_event", transitions.append, LATCHED)
    ros.wait_for([change_mode, get_mode, modes, change_state, get_state, states], timeout=20.0)
    # The manager must have found the nodes before the modes can be inferred.

    def state_id() -> int | None:
        try:
            return int(call(get_state, GetState.Request(), 2.0).current_state.id)
        except AssertionError:  # no answer: a new client's first one may be lost to discovery (seen under load)
            return None

    wait_until(lambda: state_id() == StateMsg.PRIMARY_STATE_UNCONFIGURED, 20.0, "actuation never inferred unconfigured")

    assert call(modes, GetAvailableModes.Request(), 2.0).available_modes == ["MODERATE", "PERFORMANCE", "__DEFAULT__"]
    assert [s.label for s in call(states, GetAvailableStates.Request(), 2.0).available_states] == \
        ["unconfigured", "inactive", "active"]
    assert call(change_mode, ChangeMode.Request(mode_name="NO_SUCH_MODE"), 2.0).success is False

    before = time.time_ns()
    assert call(change_mode, ChangeMode.Request(mode_name="PERFORMANCE"), 2.0).success is True
    wait_until(lambda: any(e.goal_mode.label == "PERFORMANCE" for e in events), 10.0, "no mode_event PERFORMANCE")
    event = next(e for e in events if e.goal_mode.label == "PERFORMANCE")
    assert event.start_mode.label != "PERFORMANCE"
    assert event.timestamp >= before, "a real timestamp"
    assert call(get_mode, GetMode.Request(), 2.0).current_mode == "PERFORMANCE"
    # Topics of their own: under load they may arrive after the mode_event (seen: a fresh-clone run).
    # Seen in full runs: none came, the request having been taken while the manager was still making
    # its interface (fixed; test_ros_topics_property.py). What was heard and logged says more if again.
    try:
        wait_until(lambda: any(r.goal_mode.label == "PERFORMANCE" for r in requests), 5.0, "no mode_request_info")
    except AssertionError as error:
        info = ros.node.get_publishers_info_by_topic("/actuation/mode_request_info")
        raise AssertionError(f"{error}; heard {[(r.start_mode.label, r.goal_mode.label) for r in requests]}; "
                             f"writers in the graph: {len(info)}; the manager's log:\n"
                             f"{(tmp_path / 'manager.log').read_text()[-3000:]}") from None
    wait_until(lambda: transitions and transitions[-1].goal_state.id == StateMsg.PRIMARY_STATE_ACTIVE, 5.0,
               "no transition_event to active")
    assert transitions[-1].start_state.id != StateMsg.PRIMARY_STATE_ACTIVE

    # A late joiner gets the current mode at once (latched).
    late: list[Any] = []
    ros.node.create_subscription(ModeEvent, "/actuation/mode_event", late.append, LATCHED)
    wait_until(lambda: bool(late), 5.0, "a late subscriber got nothing")
    assert late[-1].goal_mode.label == "PERFORMANCE"

    # change_state by id, as the reference's clients send it.
    request = ChangeState.Request(transition=TransitionMsg(id=TransitionMsg.TRANSITION_DEACTIVATE))
    assert call(change_state, request, 2.0).success is True
    wait_until(lambda: state_id() == StateMsg.PRIMARY_STATE_INACTIVE, 10.0, "actuation never became inactive")
    # An id that is not a transition at all is refused, not a crash.
    assert call(change_state, ChangeState.Request(transition=TransitionMsg(id=99)), 2.0).success is False
    assert call(get_mode, GetMode.Request(), 2.0).current_mode == ""


def test_the_manager_node_is_a_clean_ros_process(manager_process: subprocess.Popen[str]) -> None:
    # Serving first (on a loaded machine its start takes seconds: a SIGINT during Python's own
    # imports ends any Python program by the signal), then a moment of running.
    out = ""
    while "serving 1 system(s) and 2 node(s)" not in out:
        line = line_within(manager_process.stdout, 30.0, "sm-bt manager: its serving line")
        assert line, f"sm-bt manager ended before serving: {out}"
        out += line
    time.sleep(0.5)
    manager_process.send_signal(signal.SIGINT)
    assert manager_process.wait(5.0) == 0


def test_the_runtime_reports_a_node_appearing_late(node_processes: Starter) -> None:
    runtime = RosRuntime(bundled("actuation"), node_name="late_test", serve=False, backend_options=BACKEND_OPTIONS)
    reports: list[NodeReport] = []
    try:
        runtime.manager.subscribe(lambda event: reports.append(event.actual) if event.part == "drive_base" else None)
        time.sleep(0.3)
        assert not runtime.manager.observation("drive_base").seen
        node_processes("actuation", "--state", "inactive")
        wait_until(lambda: runtime.manager.observation("drive_base").reachable, 15.0, "drive_base never appeared")
        assert runtime.manager.observation("drive_base").state is State.INACTIVE
        assert runtime.manager.observation("drive_base").parameters == {"max_speed": 0.1, "controller": "PID"}
    finally:
        runtime.close()


def test_requests_through_the_interface_come_from_the_operator_and_respect_holds(
        pilot: RosHarness, ros_context: RosContext, capsys: pytest.CaptureFixture[str]) -> None:
    """A rule's hold (priority 100) refuses an operator's change_mode (80) over ROS; a tree's
    hold (40) gives way to it, as the last request always did."""
    manager = pilot.manager
    settle(pilot, manager.change_mode("pilot", "f_normal_mode", requester="tree"))
    rule = manager.hold("pilot", "f_degraded_mode", requester="rule")
    settle(pilot, rule.request)
    refused = ros_context.call(ChangeMode, "/pilot/change_mode", ChangeMode.Request(mode_name="f_normal_mode"))
    assert not refused.success and str(manager.actual("pilot")) == "active.f_degraded_mode"
    # sm_bt's own service says who asks, at which priority, and why it is refused.
    metacontroller = ros_context.call(RequestChange, "/pilot/request_change", RequestChange.Request(
        mode="f_normal_mode", requester="metacontroller", priority=-1))
    assert not metacontroller.accepted
    assert re.fullmatch(r"pilot is held in active\.f_degraded_mode by rule \(priority 100\) since \d+\.\d s",
                        metacontroller.reason), metacontroller.reason
    # Queued, it waits for the hold to end (released here), then goes ahead.
    queued = ros_context.call(RequestChange, "/pilot/request_change", RequestChange.Request(
        mode="f_performance_mode", requester="metacontroller", priority=-1, queue=True))
    assert queued.accepted and queued.reason.startswith("queued: pilot is held in active.f_degraded_mode"), queued
    rule.release()
    wait_until(lambda: str(manager.actual("pilot")) == "active.f_performance_mode", 10.0, "the queued change")
    rule = manager.hold("pilot", "f_degraded_mode", requester="rule")
    settle(pilot, rule.request)
    code = main(["mode", "set", "pilot", "f_slow_mode", "--timeout", "15"])  # the operator's shell
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("sm-bt: error: the manager refused mode 'f_slow_mode' for pilot: pilot is "
                                        "held in active.f_degraded_mode by rule (priority 100)"), err
    code = main(["mode", "set", "pilot", "f_slow_mode", "--priority", "100", "--wait", "--timeout", "10"])
    assert code == 0 and not rule.active, capsys.readouterr()
    assert rule.reason.startswith("superseded by request #") and rule.reason.endswith("of operator")
    assert str(manager.actual("pilot")) == "active.f_slow_mode"
    tree = manager.hold("pilot", "f_slow_mode", requester="tree")
    settle(pilot, tree.request)
    accepted = ros_context.call(ChangeMode, "/pilot/change_mode", ChangeMode.Request(mode_name="f_normal_mode"))
    assert accepted.success and not tree.active
    assert tree.reason.startswith("superseded by request #") and tree.reason.endswith("of operator")


def test_a_hold_over_ros_keeps_its_part_while_renewed_and_ends_with_its_lease_or_a_release(
        pilot: RosHarness, ros_context: RosContext, capsys: pytest.CaptureFixture[str]) -> None:
    """/pilot/hold_mode: a metacontroller's hold refuses the tree's lower request, lasts while
    renewed, ends when its lease runs out unrenewed (a client that died) or when released;
    `sm-bt mode hold` holds while it runs and releases at its end."""
    manager = pilot.manager
    settle(pilot, manager.change_mode("pilot", "f_normal_mode", requester="tree"))

    def hold(**fields: Any) -> Any:
        return ros_context.call(HoldMode, "/pilot/hold_mode", HoldMode.Request(**{"priority": -1, **fields}))

    made = hold(mode="f_degraded_mode", requester="metacontroller", lease=1.5)
    assert made.accepted and made.hold > 0, made.reason
    wait_until(lambda: str(manager.actual("pilot")) == "active.f_degraded_mode", 10.0, "pilot degraded")
    for _ in range(3):  # renewed: it lasts past its lease
        time.sleep(0.7)
        assert hold(hold=made.hold).accepted
    refused = manager.change_mode("pilot", "f_normal_mode", requester="tree")
    assert refused.refused and "by metacontroller (priority 60" in refused.reason
    wait_until(lambda: not manager.holds(), 5.0, "the lease never ran out")  # not renewed: the client died
    late = hold(hold=made.hold)
    assert not late.accepted and late.reason == f"hold #{made.hold} ended: its lease of 1.5 s ran out"
    again = hold(mode="f_slow_mode", requester="operator")
    assert again.accepted and hold(hold=again.hold, release=True).accepted and not manager.holds()
    # The command: held while it runs, released at its end.
    assert main(["mode", "hold", "pilot", "f_degraded_mode", "--for", "1", "--lease", "0.6"]) == 0
    out = capsys.readouterr().out
    assert re.match(r"pilot: held in f_degraded_mode \(hold #\d+, lease 0\.6 s\); released in 1 s or at Ctrl-C\n"
                    r"pilot: released\n$", out), out
    assert not manager.holds() and str(manager.actual("pilot")) == "active.f_degraded_mode"


def test_a_manager_serving_its_systems_only_has_no_interface_for_its_nodes(ros_context: RosContext) -> None:
    ros = RosRuntime(bundled("pilot"), node_name="sm_bt_systems_only_test", serve_nodes=False,
                     manager_options={"rules": False, "recovery": False})
    try:
        def served() -> set[str]:
            from rclpy._rclpy_pybind11 import NodeNameNonExistentError

            try:
                return {name for name, _ in ros_context.node.get_service_names_and_types_by_node(
                    "sm_bt_systems_only_test", "/")}
            except NodeNameNonExistentError:  # not discovered yet
                return set()

        wait_until(lambda: "/pilot/change_mode" in served(), 10.0, "the system's interface is not served")
        names = served()
        assert {"/pilot/change_state", "/pilot/get_mode", "/pilot/get_available_modes"} <= names
        assert not [name for name in names if name.startswith("/amcl/")], sorted(names)
    finally:
        ros.close()
