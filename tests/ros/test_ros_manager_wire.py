"""``sm-bt manager`` on the wire, as a plain rclpy client of the reference's interface sees it.

The manager runs in its own process (``python -m sm_bt.cli manager pilot``), the pilot's nodes in
another (``sm-bt sim-nodes``); the client side uses only rclpy, lifecycle_msgs and
system_modes_msgs. What is checked (issue 10, items 6 to 9): an empty mode name is refused and
changes nothing; ``mode_event`` carries one message per change of the actual mode with its real
start; ``transition_request_info`` carries the requested transition and the state it starts
from, before ``mode_request_info``; the manager logs what an operator needs on stderr.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest
from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import LOG_LINE, ManagerProcess, RosContext, Starter, wait_until
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

pytestmark = pytest.mark.ros

#: As the manager publishes: a subscriber that joins late still gets the last message.
LATCHED = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: As the reference's publishers and most clients: volatile, depth 1.
VOLATILE = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")
#: The first call after discovery can take a while; later ones are fast.
CALL_TIMEOUT = 3.0


# -- the client's side (rclpy only) ----------------------------------------------------------------------


def latched(ros: RosContext, message_type: Any, topic: str) -> list[Any]:
    """Messages on one of the manager's topics, subscribed as latched; returns once matched."""
    received: list[Any] = []
    subscription = ros.node.create_subscription(message_type, topic, received.append, LATCHED)
    wait_until(lambda: subscription.get_publisher_count() > 0, 20.0, f"{topic} never matched")
    return received


def state_of(ros: RosContext, part: str) -> int:
    return int(ros.call(GetState, f"/{part}/get_state", GetState.Request(), CALL_TIMEOUT).current_state.id)


def mode_of(ros: RosContext, part: str) -> str:
    return str(ros.call(GetMode, f"/{part}/get_mode", GetMode.Request(), CALL_TIMEOUT).current_mode)


def change_mode(ros: RosContext, part: str, mode: str) -> bool:
    return bool(ros.call(ChangeMode, f"/{part}/change_mode", ChangeMode.Request(mode_name=mode), CALL_TIMEOUT).success)


def change_state(ros: RosContext, part: str, transition: int) -> bool:
    request = ChangeState.Request(transition=TransitionMsg(id=transition))  # by id, as reference clients do
    return bool(ros.call(ChangeState, f"/{part}/change_state", request, CALL_TIMEOUT).success)


def _unanswered_is_no(ask: Callable[[], bool]) -> Callable[[], bool]:
    """``ask`` for a polling loop: a call that gets no answer counts as "not yet". The first call of a
    client can go unanswered when the server's reply is sent before the reply path is matched (DDS
    discovery; seen on a loaded machine), and the next one is answered."""
    def polled() -> bool:
        try:
            return ask()
        except AssertionError:
            return False
    return polled


def wait_for_pilot(ros: RosContext, state: int = StateMsg.PRIMARY_STATE_UNCONFIGURED) -> None:
    """Until the manager has found the pilot's nodes and infers the pilot in ``state``."""
    wait_until(_unanswered_is_no(lambda: state_of(ros, "pilot") == state), 20.0,
               f"the pilot never became state {state}", poll=0.05)


def wait_for_mode(ros: RosContext, part: str, mode: str, timeout: float = 10.0) -> None:
    wait_until(_unanswered_is_no(lambda: mode_of(ros, part) == mode), timeout, f"{part} never reached {mode}",
               poll=0.02)


def pairs(events: list[Any]) -> list[tuple[str, str]]:
    return [(event.start_mode.label, event.goal_mode.label) for event in events]


# -- 6: an empty mode name -------------------------------------------------------------------------------


def test_an_empty_mode_name_is_refused_logged_once_and_changes_nothing(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    manager = start_manager("--grace-period", "0.3")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    targets = {(part, topic): latched(ros, kind, f"/{part}/{topic}") for part in ("pilot", "amcl")
               for kind, topic in ((ModeEvent, "mode_request_info"), (TransitionEvent, "transition_request_info"))}
    wait_for_pilot(ros)
    modes_before = {part: mode_of(ros, part) for part in ("pilot", *NODES)}

    assert change_mode(ros, "pilot", "") is False
    assert change_mode(ros, "amcl", "") is False

    time.sleep(0.5)  # a change would have started at once (the target is set before the answer)
    assert state_of(ros, "pilot") == StateMsg.PRIMARY_STATE_UNCONFIGURED
    for node in NODES:  # asked of the nodes themselves: not one was touched
        assert ros.call(GetState, f"/{node}/get_state", GetState.Request(), CALL_TIMEOUT).current_state.id == \
            StateMsg.PRIMARY_STATE_UNCONFIGURED, node
    assert {part: mode_of(ros, part) for part in ("pilot", *NODES)} == modes_before
    assert not any(targets.values()), "no target was set (the request topics are latched: any would show)"
    # One line each, saying why and what names the default mode; and the manager is still serving.
    for part in ("pilot", "amcl"):
        lines = manager.lines(part, "empty", severities=("WARN",))
        assert len(lines) == 1 and "__DEFAULT__" in lines[0], manager.stderr
    assert change_mode(ros, "pilot", "__DEFAULT__") is True
    wait_for_mode(ros, "pilot", "__DEFAULT__")
    # At the default level (info), the per-call lines of the service callbacks stay out; every
    # line on stderr is a log line in the one format.
    assert not [line for line in manager.log() if line[0] == "DEBUG"]
    assert not manager.lines("-> callback")
    assert [line for line in manager.stderr.splitlines() if line and not LOG_LINE.match(line)] == []


# -- 7: mode_event start and goal -----------------------------------------------------------------------


def test_mode_event_has_one_message_per_mode_change_with_the_previous_mode_as_start(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    manager = start_manager("--log-level", "warning")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    events = latched(ros, ModeEvent, "/pilot/mode_event")
    laser_events = latched(ros, ModeEvent, "/laser_resender/mode_event")
    wait_for_pilot(ros)
    assert not events, "no mode is known yet: nothing on mode_event"

    def announced(mode: str) -> Callable[[], bool]:
        return lambda: bool(events) and events[-1].goal_mode.label == mode

    before = time.time_ns()
    for mode in ("__DEFAULT__", "f_normal_mode", "f_degraded_mode"):
        assert change_mode(ros, "pilot", mode) is True
        wait_for_mode(ros, "pilot", mode)
        wait_until(announced(mode), 5.0, f"no mode_event {mode}")
    time.sleep(0.3)  # nothing more may come

    assert pairs(events) == [("", "__DEFAULT__"), ("__DEFAULT__", "f_normal_mode"),
                             ("f_normal_mode", "f_degraded_mode")]
    stamps = [event.timestamp for event in events]
    assert stamps == sorted(stamps) and stamps[0] >= before, "real timestamps, in order"
    # A node: a mode_event only while it is active in a mode (inactive, then unconfigured: nothing).
    assert pairs(laser_events) == [("", "__DEFAULT__")]
    # --log-level warning: none of the INFO lines (start-up, nodes appearing, requests).
    assert not [line for line in manager.log() if line[0] in ("DEBUG", "INFO")], manager.stderr


# -- 8: transition_request_info ----------------------------------------------------------------------------


def test_transition_request_info_carries_the_requested_transition_and_comes_before_mode_request_info(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    manager = start_manager("--log-level", "debug")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    transitions = latched(ros, TransitionEvent, "/pilot/transition_request_info")
    mode_requests = latched(ros, ModeEvent, "/pilot/mode_request_info")
    wait_for_pilot(ros)

    before = time.time_ns()
    assert change_state(ros, "pilot", TransitionMsg.TRANSITION_CONFIGURE) is True
    wait_until(lambda: bool(transitions), 5.0, "no transition_request_info")
    wait_for_pilot(ros, StateMsg.PRIMARY_STATE_INACTIVE)
    [configure] = transitions
    assert (configure.transition.id, configure.transition.label) == (1, "configure")
    assert (configure.start_state.id, configure.start_state.label) == (1, "unconfigured")
    assert (configure.goal_state.id, configure.goal_state.label) == (2, "inactive")
    assert configure.timestamp >= before
    assert not mode_requests, "a target that is not active has no mode"

    assert change_state(ros, "pilot", TransitionMsg.TRANSITION_ACTIVATE) is True
    wait_until(lambda: len(transitions) == 2 and bool(mode_requests), 5.0, "no requests for activate")
    wait_for_pilot(ros, StateMsg.PRIMARY_STATE_ACTIVE)
    activate = transitions[1]
    assert (activate.transition.id, activate.transition.label) == (3, "activate")
    assert (activate.start_state.label, activate.goal_state.label) == ("inactive", "active")
    [mode] = mode_requests
    assert pairs([mode]) == [("", "__DEFAULT__")]
    # The reference's monitor reads a goal "active" as __DEFAULT__: the mode request must come after.
    assert activate.timestamp < mode.timestamp

    # A mode change within active: no transition, a mode request from the mode before.
    assert change_mode(ros, "pilot", "f_normal_mode") is True
    wait_until(lambda: len(mode_requests) == 2, 5.0, "no mode_request_info for f_normal_mode")
    assert pairs(mode_requests[1:]) == [("__DEFAULT__", "f_normal_mode")]
    wait_for_mode(ros, "pilot", "f_normal_mode")
    assert len(transitions) == 2, "the state did not change: no transition_request_info"
    # --log-level debug: the service callbacks' own lines.
    assert manager.lines("change_state", "pilot", severities=("DEBUG",)), manager.stderr


def test_what_nobody_read_when_it_changed_reaches_a_reader_that_comes_later(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    # A reader that comes late gets the latest message of each topic, and nothing older.
    manager = start_manager("--log-level", "warning")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    wait_for_pilot(ros)
    before = time.time_ns()
    for mode in ("__DEFAULT__", "f_normal_mode"):
        assert change_mode(ros, "pilot", mode) is True
        wait_for_mode(ros, "pilot", mode)
    came = time.time_ns()
    topics = {topic: latched(ros, kind, topic) for kind, topic in (
        (ModeEvent, "/pilot/mode_event"), (TransitionEvent, "/pilot/transition_event"),
        (ModeEvent, "/pilot/mode_request_info"), (TransitionEvent, "/pilot/transition_request_info"),
        (ModeEvent, "/amcl/mode_event"))}
    wait_until(lambda: all(topics.values()), 2.0, f"not every topic: {[t for t, m in topics.items() if not m]}")
    time.sleep(0.5)  # nothing older may follow
    # Exactly the latest of each, stamped when it happened (before this reader came).
    assert pairs(topics["/pilot/mode_event"]) == [("__DEFAULT__", "f_normal_mode")]
    [state] = topics["/pilot/transition_event"]
    assert (state.start_state.label, state.goal_state.label) == ("activating", "active")
    assert pairs(topics["/pilot/mode_request_info"]) == [("__DEFAULT__", "f_normal_mode")]
    [request] = topics["/pilot/transition_request_info"]
    # (f_normal_mode, within active, asked no transition: the last one is __DEFAULT__'s, from unconfigured)
    assert (request.start_state.label, request.transition.label, request.goal_state.label) == (
        "unconfigured", "configure", "active")
    assert pairs(topics["/amcl/mode_event"]) == [("", "__DEFAULT__")]  # active (its default) in both
    for messages in topics.values():
        assert before <= messages[0].timestamp <= came


def test_a_volatile_reader_hears_only_what_happens_after_it_subscribed(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    """As most clients subscribe (the reference's own publishers are volatile, depth 1): before, a
    reader that came while the pilot sat in __DEFAULT__ got '' -> __DEFAULT__ about a second later,
    an event from before it subscribed, and acted on a change that did not happen."""
    manager = start_manager("--log-level", "warning")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    wait_for_pilot(ros)
    assert change_mode(ros, "pilot", "__DEFAULT__") is True
    wait_for_mode(ros, "pilot", "__DEFAULT__")
    received: list[Any] = []
    subscription = ros.node.create_subscription(ModeEvent, "/pilot/mode_event", received.append, VOLATILE)
    wait_until(lambda: subscription.get_publisher_count() > 0, 20.0, "/pilot/mode_event never matched")
    time.sleep(1.5)  # longer than the old wait for a reader
    assert received == [], pairs(received)
    asked = time.time_ns()
    assert change_mode(ros, "pilot", "f_degraded_mode") is True
    wait_until(lambda: received, 10.0, "no mode_event for the change")
    time.sleep(0.3)
    assert pairs(received) == [("__DEFAULT__", "f_degraded_mode")]
    assert asked <= received[0].timestamp <= time.time_ns()


def test_a_late_latched_reader_gets_the_current_value_first_not_an_older_one(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    """Before, a topic whose reader left kept its last message in the writer's history while newer
    ones waited unsent: a reader that came later got that stale one first (configuring -> inactive
    while the pilot was active), and the current one after."""
    manager = start_manager("--log-level", "warning")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    wait_for_pilot(ros)
    first: list[Any] = []
    reader = ros.node.create_subscription(TransitionEvent, "/pilot/transition_event", first.append, LATCHED)
    wait_until(lambda: reader.get_publisher_count() > 0, 20.0, "/pilot/transition_event never matched")
    assert change_state(ros, "pilot", TransitionMsg.TRANSITION_CONFIGURE) is True
    wait_for_pilot(ros, StateMsg.PRIMARY_STATE_INACTIVE)
    wait_until(lambda: [m for m in first if m.goal_state.label == "inactive"], 5.0, "the first reader heard nothing")
    ros.node.destroy_subscription(reader)  # the reader leaves
    assert change_mode(ros, "pilot", "f_degraded_mode") is True
    wait_for_mode(ros, "pilot", "f_degraded_mode")
    late = latched(ros, TransitionEvent, "/pilot/transition_event")
    wait_until(lambda: late, 5.0, "the late reader got nothing")
    time.sleep(0.5)
    assert [(m.start_state.label, m.goal_state.label) for m in late] == [("activating", "active")]


# -- 9: what the manager logs when a node dies ------------------------------------------------------------


def set_parameter(ros: RosContext, node: str, name: str, value: bool) -> None:
    """Set a bool parameter of ``node`` as any ROS client does (``sim.broken`` of a simulated node).

    Tried a few times: after a restart, the killed process's services still look ready for the DDS
    lease, and a first request can go to them alone and be lost."""
    parameter = Parameter(name=name, value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value))
    request = SetParameters.Request(parameters=[parameter])
    for attempt in range(5):
        try:
            response = ros.call(SetParameters, f"/{node}/set_parameters", request, 1.0)
            break
        except AssertionError:
            if attempt == 4:
                raise
    assert response.results[0].successful, response.results[0].reason


def test_the_manager_logs_a_node_vanishing_the_request_failing_on_it_its_recovery_and_giving_up(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    manager = start_manager("--grace-period", "0.3", "--recovery-attempts", "2")
    node_processes("pilot", "--only", "amcl,controller_server,pointcloud_to_laser")
    laser = node_processes("pilot", "--only", "laser_resender")
    manager.ready()
    ros = ros_context
    wait_for_pilot(ros)
    for node in NODES:
        assert len(manager.lines(node, "appeared", severities=("INFO",))) == 1, f"one line per event\n{manager.stderr}"
    mark = len(manager.log())

    def since_mark(*words: str, severities: tuple[str, ...] = ()) -> list[str]:
        return [message for severity, _, message in manager.log()[mark:]
                if all(word.lower() in message.lower() for word in words)
                and (not severities or severity in severities)]

    # A request is one line when it starts and one when it ends: its calls to the nodes are DEBUG.
    assert change_mode(ros, "pilot", "f_normal_mode") is True
    wait_for_mode(ros, "pilot", "f_normal_mode")
    time.sleep(0.2)
    request_lines = [line for line in manager.log()[mark:] if line[0] != "DEBUG"]
    assert 1 <= len(request_lines) <= 2, "\n".join(map(str, request_lines))

    # Killed: one line when the manager notices (the DDS lease would take 20 s; its probe 2 s).
    mark = len(manager.log())
    laser.kill()
    wait_until(lambda: bool(since_mark("laser_resender", "vanished")), 10.0,
               f"no line about laser_resender vanishing:\n{manager.stderr}")
    assert len(since_mark("laser_resender", "vanished", severities=("WARN",))) == 1, manager.stderr

    # A request that needs it fails, and says so with the node's name.
    mark = len(manager.log())
    change_mode(ros, "laser_resender", "__DEFAULT__")
    wait_until(lambda: any(("fail" in m or "refus" in m) for m in since_mark("laser_resender",
                                                                             severities=("WARN", "ERROR"))),
               5.0, f"no line about the request failing on laser_resender:\n{manager.stderr}")

    # Back (a new process, unconfigured): recovery restores it, and says so.
    mark = len(manager.log())
    laser.start()
    wait_until(lambda: bool(since_mark("laser_resender", "restor")), 15.0,
               f"no recovery attempt for laser_resender:\n{manager.stderr}")
    wait_for_mode(ros, "pilot", "f_normal_mode")
    assert since_mark("laser_resender", "appeared", severities=("INFO",)), manager.stderr

    # Failing by itself whenever active: restored until the budget is used, then one ERROR line.
    mark = len(manager.log())
    set_parameter(ros, "laser_resender", "sim.broken", True)
    wait_until(lambda: bool(since_mark("laser_resender", "gave up", severities=("ERROR",))), 15.0,
               f"recovery never gave up on laser_resender:\n{manager.stderr}")
    time.sleep(0.5)
    assert len(since_mark("gave up", severities=("ERROR",))) == 1, "gave up once, not on every evaluation"
    assert since_mark("laser_resender", "restor"), "a recovery attempt came first"
