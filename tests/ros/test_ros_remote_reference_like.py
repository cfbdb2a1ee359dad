"""A fleet's robot whose manager behaves as the reference's ``mode_manager`` does, scripted here.

The scripted manager serves ``/robot1/pilot``'s system_modes interface from this test's own rclpy
node and does what the reference was seen to do (docs/reference.md): it answers ``unknown`` until a
node of its moves; its ``activate`` means ``__DEFAULT__`` while its ``change_mode`` of an inactive
system activates it in that mode; it answers ``success`` at once and reports later, and sometimes
sends no event at all. Against it, the fleet (sm_bt.ros.remote_parts) must ask for the right
things in the right order and learn where the robot is without the events. The real reference is
driven in ``make interop`` (tests/interop/interop_fleet.py).

As the reference, it offers no liveliness lease on ``mode_event``, and the fleet asks it for none
(it probes such a robot at the fast pace). Where it plays sm-bt manager (``served_by`` left out) it
offers sm-bt manager's lease, serves its ``request_change`` and tells each request's end on
``request_outcome``, as scripted (failed, never, before its answer); offering no lease there, it
is an older sm-bt manager: told as a warning, probed at the fast pace, its events still heard.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.duration import Duration
from rclpy.qos import LivelinessPolicy, QoSProfile
from ros_processes import RosContext, wait_until
from sm_bt_msgs.msg import RequestOutcome
from sm_bt_msgs.srv import PreviewChange, RequestChange
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.engine.requests import Request
from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.ros.manager_node import MODE_EVENT_LEASE, OUTCOMES
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

FLEET = """\
fleet:
  ros__parameters:
    type: system
    modes:
      __DEFAULT__:
        robot1: active.f_normal_mode
      FAST:
        robot1: active.f_performance_mode
      REST:
        robot1: inactive

robot1:
  ros__parameters:
    type: remote
    manager: /robot1
    system: pilot
{extra}    modes: [__DEFAULT__, f_normal_mode, f_performance_mode]
"""
#: The scripted manager's delay between accepting a request and its system having moved.
DELAY = 0.1
#: Long enough for the fleet to have read and probed the robot several times.
SETTLE = 1.5
#: The mode_event writer of sm-bt manager's part: the lease it offers (its other QoS do not matter here).
LEASED = QoSProfile(depth=10, liveliness=LivelinessPolicy.AUTOMATIC,
                    liveliness_lease_duration=Duration(nanoseconds=round(MODE_EVENT_LEASE * 1e9)))


class ScriptedManager:
    """``/robot1/pilot`` served as the reference serves it; ``requests`` lists what it was asked.
    ``lease``: its ``mode_event`` offers sm-bt manager's liveliness lease (the reference offers none).
    ``outcomes``: it serves sm-bt manager's ``request_change`` and ``request_outcome``, whose writer it
    makes ``outcomes_after`` s late (what it tells meanwhile is lost, as under load an outcome is that
    a fleet's new reader has not matched yet)."""

    def __init__(self, ros: RosContext, *, lease: bool = False, outcomes: bool = False,
                 outcomes_after: float = 0.0) -> None:
        node = ros.node
        self._node = node
        self.state, self.mode = State.UNKNOWN, "unknown"
        self.requests: list[str] = []
        # How its next requests end on request_outcome: "succeeded" or "failed" once it moved (failed:
        # it does not move), None: never told; first: told before its answer. refusal: refused so.
        self.outcome: str | None = "succeeded"
        self.outcome_first = False
        # Its answers to change requests (change_state, change_mode, request_change) held back (a reply
        # lost or late) until `released` is set; on a node and executor of their own, threads enough for
        # several, so that the rest goes on meanwhile.
        self.hold_answers = False
        self.released = threading.Event()
        self.refusal = ""
        # Its preview of a change while it knows no state: its nodes out of its reach (refused), not seen
        # yet (waits), or between modes (possible).
        self.preview: tuple[bool, list[str]] = (False, [])
        self._numbers = iter(range(1, 1000))
        self.events = True  # publish events for its moves (the reference sometimes does not)
        self.sm_bt_switch = False  # switch an active system as sm-bt manager tells it (switch_as_sm_bt)
        self.running = threading.Event()  # cleared: its Python hangs (in the next get_state it answers)
        self.running.set()
        self.reads = 0  # get_mode calls answered
        self._lock = threading.Lock()
        self._moves: list[threading.Thread] = []
        prefix = "/robot1/pilot"
        self._transition_events = node.create_publisher(TransitionEvent, f"{prefix}/transition_event", 10)
        self._mode_events = node.create_publisher(ModeEvent, f"{prefix}/mode_event", LEASED if lease else 10)
        import rclpy
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.executors import MultiThreadedExecutor

        self._answers = rclpy.create_node("scripted_answers", context=ros.context)
        group = ReentrantCallbackGroup()
        self._services = [
            node.create_service(GetState, f"{prefix}/get_state", self._get_state),
            node.create_service(GetMode, f"{prefix}/get_mode", self._get_mode),
            self._answers.create_service(ChangeState, f"{prefix}/change_state", self._held(self._change_state),
                                         callback_group=group),
            self._answers.create_service(ChangeMode, f"{prefix}/change_mode", self._held(self._change_mode),
                                         callback_group=group)]
        self._outcomes: Any = None
        self.lost_outcomes = 0
        if outcomes and outcomes_after > 0:
            self._start(threading.Timer(outcomes_after, self._open_outcomes))
        elif outcomes:
            self._open_outcomes()
        if outcomes:
            self._services.append(self._answers.create_service(RequestChange, f"{prefix}/request_change",
                                                               self._held(self._request_change), callback_group=group))
            self._services.append(node.create_service(PreviewChange, f"{prefix}/preview_change", self._preview_change))
        self._answering = MultiThreadedExecutor(num_threads=8, context=ros.context)
        self._answering.add_node(self._answers)
        threading.Thread(target=self._spin_answers, daemon=True).start()

    def move(self, state: State, mode: str) -> None:
        """Its system is now ``state`` in ``mode`` (its nodes moved), told as its timer would."""
        with self._lock:
            before = self.state
            self.state, self.mode = state, mode
        if self.events:
            event = TransitionEvent()
            event.start_state.id, event.goal_state.id = int(before.value), int(state.value)
            self._transition_events.publish(event)
            if state is State.ACTIVE:
                mode_event = ModeEvent()
                mode_event.goal_mode.label = mode
                self._mode_events.publish(mode_event)

    def set(self, state: State, mode: str) -> None:
        """Its system is now ``state`` in ``mode``, told by no event (see tell_state, tell_mode)."""
        with self._lock:
            self.state, self.mode = state, mode

    def tell_state(self, start: State, goal: State) -> None:
        event = TransitionEvent()
        event.start_state.id, event.goal_state.id = int(start.value), int(goal.value)
        self._transition_events.publish(event)

    def tell_mode(self, mode: str) -> None:
        event = ModeEvent()
        event.goal_mode.label = mode
        self._mode_events.publish(event)

    def _later(self, state: State, mode: str) -> None:
        self._start(threading.Timer(DELAY, self.move, (state, mode)))

    def _get_state(self, request: GetState.Request, response: GetState.Response) -> GetState.Response:
        self.running.wait(30.0)  # hung: the executor thread of its node waits here, DDS's threads go on
        with self._lock:
            response.current_state.id = int(self.state.value)
        return response

    def _get_mode(self, request: GetMode.Request, response: GetMode.Response) -> GetMode.Response:
        with self._lock:
            response.current_mode = self.mode
            self.reads += 1
        return response

    def _change_state(self, request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        transition = request.transition.id  # the reference reads the id only
        self.requests.append(f"change_state {transition}")
        response.success = True  # the reference answers success for anything it forwards
        if transition == 1:  # configure
            self._later(State.INACTIVE, "")
        elif transition == 3:  # activate: the reference goes to __DEFAULT__
            self._later(State.ACTIVE, "__DEFAULT__")
        elif transition == 4:  # deactivate
            self._later(State.INACTIVE, "")
        return response

    def switch_as_sm_bt(self, mode: str) -> None:
        """A switch of an active system as sm-bt manager tells it: activating, then at its end the
        mode event before the state event (both at once, on topics of their own)."""
        self.move(State.ACTIVATING, self.mode)
        time.sleep(DELAY)
        with self._lock:
            self.state, self.mode = State.ACTIVE, mode
        mode_event = ModeEvent()
        mode_event.goal_mode.label = mode
        self._mode_events.publish(mode_event)
        time.sleep(DELAY)  # the state event overtaken (another topic, another path)
        event = TransitionEvent()
        event.start_state.id, event.goal_state.id = int(State.ACTIVATING.value), int(State.ACTIVE.value)
        self._transition_events.publish(event)

    def _change_mode(self, request: ChangeMode.Request, response: ChangeMode.Response) -> ChangeMode.Response:
        self.requests.append(f"change_mode {request.mode_name}")
        response.success = True
        if self.sm_bt_switch and self.state is State.ACTIVE:
            self._start(threading.Thread(target=self.switch_as_sm_bt, args=(request.mode_name,)))
            return response
        with self._lock:
            redundant = self.state is State.ACTIVE and self.mode == request.mode_name
            configured = self.state in (State.INACTIVE, State.ACTIVE)
        if not redundant and configured:  # it activates parts, never configures them
            self._later(State.ACTIVE, request.mode_name)
        return response


    def _start(self, thread: threading.Thread) -> None:
        """Start a move or a message to come: :meth:`close` waits for it (after the test, its node is gone)."""
        self._moves.append(thread)
        thread.start()

    def close(self) -> None:
        """Stop answering change requests (a held answer is let go), once the moves under way are done."""
        self.released.set()
        for thread in self._moves:
            thread.join(5.0)
        self._answering.shutdown(5.0)
        self._answers.destroy_node()

    def _open_outcomes(self) -> None:
        with self._lock:
            self._outcomes = self._node.create_publisher(RequestOutcome, "/robot1/pilot/request_outcome", OUTCOMES)

    def lose_outcomes(self) -> None:
        """From now on what it tells on request_outcome is lost (as before a fleet's reader matched)."""
        with self._lock:
            self._outcomes = None

    def _tell_outcome(self, message: RequestOutcome) -> None:
        """Published; lost before its writer is made, as DDS loses a volatile message sent before the
        reader matched the writer (which, between two nodes of one process as here, it does at once)."""
        with self._lock:
            lost = self._outcomes is None
            self.lost_outcomes += lost
        if not lost:
            self._outcomes.publish(message)

    def _spin_answers(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            self._answering.spin()

    def _held(self, serve: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """``serve``, whose answer waits for `released` while answers are held."""
        def answer(request: Any, response: Any) -> Any:
            answered = serve(request, response)
            if self.hold_answers:
                self.released.wait(30.0)
            return answered
        return answer

    def _request_change(self, request: RequestChange.Request,
                        response: RequestChange.Response) -> RequestChange.Response:
        what = request.mode or request.transition
        self.requests.append(f"request_change {what} [{request.requester}]")
        response.request = number = next(self._numbers)
        if self.refusal:
            response.accepted, response.reason = False, self.refusal
            return response
        response.accepted = True
        outcome = self.outcome
        told = RequestOutcome(request=number, description=f"change_mode pilot {what}", requester=request.requester,
                              outcome=outcome or "", reason="" if outcome == "succeeded" else "amcl: activate failed")
        if outcome is None:
            return response
        if self.outcome_first:
            self._tell_outcome(told)
            if outcome == "succeeded":
                self.move(State.ACTIVE, request.mode)
            return response
        if outcome == "succeeded" and self.sm_bt_switch and self.state is State.ACTIVE:
            self._start(threading.Thread(target=self.switch_as_sm_bt, args=(request.mode,)))
        elif outcome == "succeeded":
            self._later(State.ACTIVE, request.mode)
        self._start(threading.Timer(2 * DELAY, self._tell_outcome, (told,)))
        return response


    def _preview_change(self, request: PreviewChange.Request,
                        response: PreviewChange.Response) -> PreviewChange.Response:
        possible, waits = self.preview
        response.possible = possible
        response.refused = "" if possible else "amcl is not reachable (no answer from /robot1/amcl for 0.9 s)"
        response.json = json.dumps({"waits": waits})
        return response


@pytest.fixture
def scripted(ros_context: RosContext) -> Iterator[ScriptedManager]:
    scripted = ScriptedManager(ros_context)
    yield scripted
    scripted.close()


@pytest.fixture
def scripted_sm_bt(ros_context: RosContext) -> Iterator[ScriptedManager]:
    """It plays sm-bt manager: its mode_event offers sm-bt manager's lease, it takes request_change and
    tells request_outcome."""
    scripted = ScriptedManager(ros_context, lease=True, outcomes=True)
    yield scripted
    scripted.close()


def _leases_asked(ros: RosContext, topic: str) -> list[float]:
    """The finite liveliness leases (s) the readers of ``topic`` ask for, as the graph shows them."""
    return [info.qos_profile.liveliness_lease_duration.nanoseconds / 1e9
            for info in ros.node.get_subscriptions_info_by_topic(topic)
            if info.qos_profile.liveliness_lease_duration.nanoseconds < 10 ** 18]


def _fleet(tmp_path: Path, extra: str = "    served_by: reference\n", **backend: float) -> RosRuntime:
    path = tmp_path / "fleet.yaml"
    path.write_text(FLEET.format(extra=extra), encoding="utf-8")
    return RosRuntime(load_model(path), node_name="fleet_manager", manager_options={"request_timeout": 10.0},
                      backend_options=backend)


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[RosRuntime]:
    runtime = _fleet(tmp_path)
    yield runtime
    runtime.close()


@contextlib.contextmanager
def _reading(scripted: ScriptedManager, tmp_path: Path, **backend: float) -> Iterator[RosRuntime]:
    """A fleet over the scripted sm-bt robot, active in f_normal_mode, once it has read it."""
    scripted.move(State.ACTIVE, "f_normal_mode")
    runtime = _fleet(tmp_path, extra="", **backend)
    try:
        wait_until(lambda: str(runtime.manager.actual("robot1")) == "active.f_normal_mode", 10.0, "robot1 never read")
        yield runtime
    finally:
        runtime.close()


def _fails(runtime: RosRuntime, mode: str, *, within: float, after: float = 0.0) -> Request:
    """The fleet's request for ``mode``, failed between ``after`` and ``within`` s after it was made."""
    request = runtime.manager.change_mode("fleet", mode)
    took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
    assert after <= took < within and not request.succeeded, (took, request)
    return request


def _done(runtime: RosRuntime, mode: str) -> None:
    request = runtime.manager.change_mode("fleet", mode)
    wait_until(lambda: request.done, 15.0, f"fleet {mode} did not end")
    assert request.succeeded, request.reason


def test_a_robot_its_manager_knows_nothing_of_is_taken_for_unconfigured_and_brought_up_configure_then_mode(
        scripted: ScriptedManager, fleet: RosRuntime, ros_context: RosContext) -> None:
    manager = fleet.manager
    wait_until(lambda: manager.actual("robot1").state is State.UNCONFIGURED, 10.0, "robot1 never taken in")
    time.sleep(SETTLE)  # its manager goes on answering unknown: that is no loss of the robot
    assert manager.actual("robot1").state is State.UNCONFIGURED
    # The reference offers no lease: asked for one, its mode_event would not reach the fleet.
    assert _leases_asked(ros_context, "/robot1/pilot/mode_event") == []
    _done(fleet, "__DEFAULT__")
    # Configure by id, then activation as the mode: never the reference's activate (its __DEFAULT__).
    assert scripted.requests == ["change_state 1", "change_mode f_normal_mode"]
    assert str(manager.actual("robot1")) == "active.f_normal_mode"

    _done(fleet, "REST")
    _done(fleet, "FAST")  # its mode asked while inactive is kept for the activation: one call
    assert scripted.requests[2:] == ["change_state 4", "change_mode f_performance_mode"]
    assert (scripted.state, scripted.mode) == (State.ACTIVE, "f_performance_mode")
    assert str(manager.actual("fleet")) == "active.FAST"


def test_a_change_whose_answer_is_lost_ends_when_the_references_events_say_it_was_done(
        scripted: ScriptedManager, fleet: RosRuntime) -> None:
    """The reference's answers can be lost as any server's (see the sm-bt robot's case below). It tells
    no outcome, but its events say where its system went: a change_state or change_mode call still
    unanswered ends when they say it reached what the call asked, not at the call's timeout (10 s)."""
    manager = fleet.manager
    wait_until(lambda: manager.actual("robot1").state is State.UNCONFIGURED, 10.0, "robot1 never taken in")
    scripted.hold_answers = True
    for mode, steps in (("__DEFAULT__", 2), ("REST", 1), ("FAST", 1)):
        request = manager.change_mode("fleet", mode)
        took = wait_until(lambda request=request: request.done, 15.0, f"fleet {mode} never ended")
        # each step a tick's event away, and the next paced after it (REFERENCE_EVENTS)
        assert request.succeeded and took < 3.0 * steps, (mode, took, request.reason)
    assert scripted.requests == ["change_state 1", "change_mode f_normal_mode", "change_state 4",
                                 "change_mode f_performance_mode"]
    scripted.hold_answers = False
    scripted.released.set()  # the late answers change nothing
    time.sleep(SETTLE)
    assert str(manager.actual("fleet")) == "active.FAST"
    _done(fleet, "__DEFAULT__")
    assert scripted.requests[4:] == ["change_mode f_normal_mode"]


def test_served_by_sm_bt_a_robot_its_manager_knows_nothing_of_stays_out_of_reach(
        scripted_sm_bt: ScriptedManager, tmp_path: Path, ros_context: RosContext) -> None:
    scripted = scripted_sm_bt
    runtime = _fleet(tmp_path, extra="")
    try:
        # Served by sm-bt manager: the fleet asks for a lease of its liveness window.
        wait_until(lambda: _leases_asked(ros_context, "/robot1/pilot/mode_event") == [0.9], 10.0,
                   f"no lease asked: {_leases_asked(ros_context, '/robot1/pilot/mode_event')}")
        time.sleep(SETTLE + 1.0)
        assert not runtime.manager.observation("robot1").seen
        assert scripted.requests == []
        # Once its manager knows its system, it is read.
        scripted.move(State.INACTIVE, "")
        wait_until(lambda: runtime.manager.actual("robot1").state is State.INACTIVE, 5.0, "robot1 never read")
    finally:
        runtime.close()


def test_without_events_the_fleet_learns_a_robots_moves_from_its_answers(
        scripted: ScriptedManager, fleet: RosRuntime) -> None:
    manager = fleet.manager
    wait_until(lambda: manager.actual("robot1").state is State.UNCONFIGURED, 10.0, "robot1 never taken in")
    _done(fleet, "__DEFAULT__")
    scripted.events = False  # as the reference after a failed switch: no event for the rest of the run
    _done(fleet, "FAST")  # confirmed by reading its mode, and by the probes
    assert str(manager.actual("robot1")) == "active.f_performance_mode"
    # A redundant request: accepted, nothing moves, nothing is sent; read, it is there already.
    before = len(scripted.requests)
    scripted.move(State.ACTIVE, "f_normal_mode")  # someone else switched it back, silently
    _done(fleet, "__DEFAULT__")
    assert scripted.requests[before:] == ["change_mode f_normal_mode"]
    # Someone deactivates it behind the fleet's back and no event comes: the probes tell.
    scripted.move(State.INACTIVE, "")
    wait_until(lambda: manager.actual("robot1").state is State.INACTIVE, 3.0, "the silent move never seen")


def test_a_switch_whose_mode_event_overtakes_its_end_is_never_seen_back_in_the_old_mode(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    scripted = scripted_sm_bt
    scripted.move(State.ACTIVE, "f_normal_mode")
    scripted.sm_bt_switch = True
    runtime = _fleet(tmp_path, extra="")
    try:
        manager = runtime.manager
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_normal_mode", 10.0, "robot1 never read")
        seen: list[str] = []
        watching = threading.Event()

        def watch() -> None:
            while not watching.is_set():
                view = str(manager.actual("robot1"))
                if not seen or seen[-1] != view:
                    seen.append(view)
                time.sleep(0.001)

        watcher = threading.Thread(target=watch)
        watcher.start()
        try:
            _done(runtime, "FAST")
            time.sleep(2 * DELAY)
        finally:
            watching.set()
            watcher.join(5.0)
        assert seen[0] == "active.f_normal_mode" and seen[-1] == "active.f_performance_mode", seen
        assert "active.f_normal_mode" not in seen[1:], seen
    finally:
        runtime.close()


def test_served_by_sm_bt_a_switch_whose_mode_event_came_on_the_way_is_not_read_again_at_its_end(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """A switch as sm-bt manager tells it (activating, its mode event, active): the mode is known when the
    robot is active again, and the fleet asks its manager nothing more meanwhile (over ten robots, a read
    each was on every switch's way). A robot activated with no mode event on the way is read."""
    scripted = scripted_sm_bt
    scripted.sm_bt_switch = True
    # Its accepted mode is read at the probes' pace (unconfirmed changes): slow here, to tell the reads apart.
    with _reading(scripted, tmp_path, probe_interval=3.0) as runtime:
        manager = runtime.manager
        time.sleep(SETTLE)
        reads = scripted.reads
        _done(runtime, "FAST")
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_performance_mode", 5.0, "never seen in FAST")
        time.sleep(4 * DELAY)
        assert scripted.reads == reads, f"read {scripted.reads - reads} times during the switch"
        assert str(manager.actual("robot1")) == "active.f_performance_mode"
        # Deactivated, then active again with its mode told by no event on the way (one that came while it
        # was inactive says which mode it will be activated in, no more): read at its activation.
        scripted.set(State.INACTIVE, "")
        scripted.tell_state(State.ACTIVE, State.INACTIVE)
        wait_until(lambda: manager.actual("robot1").state is State.INACTIVE, 5.0, "never seen inactive")
        scripted.tell_mode("f_performance_mode")
        time.sleep(4 * DELAY)
        scripted.set(State.ACTIVE, "f_normal_mode")
        scripted.tell_state(State.INACTIVE, State.ACTIVE)
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_normal_mode", 2.0, "its mode never read")


def test_served_by_sm_bt_a_manager_that_offers_no_lease_is_probed_at_the_fast_pace_and_heard(
        scripted: ScriptedManager, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """An older sm-bt manager: its mode_event offers no lease, so the fleet's liveliness reader does
    not match it. Told as a warning; its events still come (they have a reader of their own), and
    its probes keep the fast pace (a silent move is seen within a second, not at a slow probe's)."""
    caplog.set_level(logging.WARNING, logger="sm_bt.ros.remote_parts")
    scripted.move(State.ACTIVE, "f_normal_mode")
    runtime = _fleet(tmp_path, extra="")
    try:
        manager = runtime.manager
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_normal_mode", 10.0, "robot1 never read")
        wait_until(lambda: "offers no liveliness lease" in caplog.text, 10.0, "no warning of the missing lease")
        scripted.move(State.ACTIVE, "f_performance_mode")  # told by its mode_event
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_performance_mode", 3.0, "its event unheard")
        scripted.events = False
        for state in (State.INACTIVE, State.ACTIVE, State.INACTIVE):  # told by nothing: each by the next probe
            scripted.move(state, "f_normal_mode" if state is State.ACTIVE else "")
            took = wait_until(lambda state=state: manager.actual("robot1").state is state, 5.0,
                              f"the silent move to {state.label} never seen")
            assert took <= 1.0, f"the silent move to {state.label} seen after {took:.2f} s: probed at the slow pace"
    finally:
        runtime.close()


def test_served_by_sm_bt_a_manager_hung_while_its_dds_threads_live_is_told_by_its_slow_probes(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """Its liveliness goes on (DDS's threads assert it), so only a probe can tell: one left unanswered
    for the window is asked again at once, and a fast probe interval later it is out of reach. Then
    it answers again, and is read afresh."""
    scripted = scripted_sm_bt
    scripted.move(State.ACTIVE, "f_normal_mode")
    slow = 1.0  # the slow probes' pace (3 s by default), short for the test
    runtime = _fleet(tmp_path, extra="", slow_probe_interval=slow)
    try:
        manager = runtime.manager
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_normal_mode", 10.0, "robot1 never read")
        time.sleep(SETTLE)
        assert str(manager.actual("robot1")) == "active.f_normal_mode"
        scripted.running.clear()
        hung = time.monotonic()
        try:
            # The next slow probe, its window, the one asked again, a fast interval (and the report).
            took = wait_until(lambda: manager.actual("robot1").state is State.UNKNOWN, 10.0, "robot1 never unknown")
            assert took <= slow + 0.9 + 0.3 + 0.5, f"robot1 unknown {time.monotonic() - hung:.2f} s after it hung"
            assert manager.observation("robot1").gone == (
                "no answer from the manager of robot1 (/robot1/pilot) for 0.9 s (DDS still sees its process: it "
                "hangs?)")
        finally:
            scripted.running.set()
        wait_until(lambda: str(manager.actual("robot1")) == "active.f_normal_mode", 5.0, "robot1 never read again")
    finally:
        runtime.close()


def test_served_by_sm_bt_a_change_is_done_when_the_robots_request_ends_told_before_or_after_its_answer(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """Asked through request_change, as the fleet: done with the robot's request, whose outcome may
    come before the answer that numbers it (two channels)."""
    scripted = scripted_sm_bt
    with _reading(scripted, tmp_path) as runtime:
        _done(runtime, "FAST")
        scripted.outcome_first = True
        _done(runtime, "__DEFAULT__")
        assert scripted.requests == ["request_change f_performance_mode [fleet]",
                                     "request_change f_normal_mode [fleet]"]


def test_served_by_sm_bt_a_request_whose_answer_is_lost_ends_with_the_outcome_the_robot_told(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """A server that has not discovered a new client's reply reader drops its reply: the robot's
    request ends and says so on request_outcome, and the fleet's ends with it, not at its timeout."""
    scripted = scripted_sm_bt
    with _reading(scripted, tmp_path) as runtime:  # its request timeout: 10 s
        scripted.outcome_first, scripted.hold_answers = True, True
        request = runtime.manager.change_mode("fleet", "FAST")
        took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
        assert request.succeeded and took < 3.0, (took, request.reason)
        assert str(runtime.manager.actual("robot1")) == "active.f_performance_mode"
        scripted.outcome = "failed"
        request = _fails(runtime, "__DEFAULT__", within=3.0)
        assert request.reason == ("robot1: change_mode f_normal_mode failed: its manager's request #2 failed: "
                                  "amcl: activate failed"), request.reason
        # The answers come at last: taken for what they are, late (nothing ends twice), and the next
        # request, answered, is done as ever.
        scripted.hold_answers = False
        scripted.released.set()
        scripted.outcome = "succeeded"
        _done(runtime, "__DEFAULT__")
        assert scripted.requests == ["request_change f_performance_mode [fleet]",
                                     "request_change f_normal_mode [fleet]", "request_change f_normal_mode [fleet]"]


def test_served_by_sm_bt_a_request_whose_answer_and_outcome_are_lost_ends_when_the_robots_events_say_it_was_done(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """Seen in make bench under load (3 runs of 9): a new fleet's first change of a robot lost both its
    answer and its outcome (the robot's manager had not matched the fleet's readers yet) and waited its
    timeout, while the robot's events, latched, said it had got there."""
    scripted = scripted_sm_bt
    with _reading(scripted, tmp_path) as runtime:  # its request timeout: 10 s, the outcome's 60 s
        scripted.lose_outcomes()
        scripted.hold_answers = True
        request = runtime.manager.change_mode("fleet", "FAST")
        took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
        assert request.succeeded and took < 3.0, (took, request.reason)
        assert str(runtime.manager.actual("robot1")) == "active.f_performance_mode"
        # Answered, its outcome lost: its events end it too.
        scripted.hold_answers = False
        scripted.released.set()
        request = runtime.manager.change_mode("fleet", "__DEFAULT__")
        took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
        assert request.succeeded and took < 3.0, (took, request.reason)
        wait_until(lambda: scripted.lost_outcomes == 2, 2.0, "an outcome was told")
        assert scripted.requests == [
            "request_change f_performance_mode [fleet]", "request_change f_normal_mode [fleet]"]


def test_served_by_sm_bt_an_activation_whose_answer_and_outcome_are_lost_ends_when_the_mode_read_says_it_was_done(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """As above, its events the other way round (each on a topic of its own, as a late match delivers
    them): the mode event while the fleet still takes the robot for inactive says nothing yet; the
    mode the fleet reads once the robot is active ends the activation."""
    scripted = scripted_sm_bt
    scripted.move(State.INACTIVE, "")
    runtime = _fleet(tmp_path, extra="")
    try:
        wait_until(lambda: runtime.manager.actual("robot1").state is State.INACTIVE, 10.0, "robot1 never read")
        scripted.lose_outcomes()
        scripted.hold_answers, scripted.events = True, False
        request = runtime.manager.change_mode("fleet", "FAST")
        wait_until(lambda: "request_change f_performance_mode [fleet]" in scripted.requests, 5.0, "never asked")
        wait_until(lambda: scripted.mode == "f_performance_mode", 2.0, "it never moved")
        scripted.tell_mode("f_performance_mode")
        time.sleep(DELAY)
        scripted.tell_state(State.INACTIVE, State.ACTIVE)
        took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
        assert request.succeeded and took < 3.0, (took, request.reason)
        assert str(runtime.manager.actual("robot1")) == "active.f_performance_mode"
    finally:
        runtime.close()


def test_served_by_sm_bt_a_request_waits_until_the_robots_outcomes_reach_the_fleet(
        ros_context: RosContext, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Seen in make bench under load: a new fleet's first change over ten robots waited the call's
    timeout for four of them, their answers lost (a new client's reply reader matches late) and
    their outcomes too (sent before the fleet's reader matched the robot's writer). Here the robot's
    writer is made late, its answers are held, and it tells the outcome the moment it can: the
    fleet's request waits for the match, then ends with the outcome."""
    import sm_bt.ros.remote_robots

    monkeypatch.setattr(sm_bt.ros.remote_robots, "OUTCOMES_MATCH", 10.0)  # a loaded machine's match included
    scripted = ScriptedManager(ros_context, lease=True, outcomes=True, outcomes_after=2.0)
    try:
        scripted.move(State.ACTIVE, "f_normal_mode")
        scripted.outcome_first, scripted.hold_answers = True, True
        runtime = _fleet(tmp_path, extra="")
        try:
            wait_until(lambda: str(runtime.manager.actual("robot1")) == "active.f_normal_mode", 10.0,
                       "robot1 never read")
            request = runtime.manager.change_mode("fleet", "FAST")
            wait_until(lambda: request.done, 10.0, "the fleet's request never ended (its outcome was lost)")
            assert request.succeeded, request.reason
            assert str(runtime.manager.actual("robot1")) == "active.f_performance_mode"
            assert scripted.lost_outcomes == 0, "asked before the fleet could hear how it ended"
        finally:
            runtime.close()
    finally:
        scripted.close()


def test_served_by_sm_bt_a_robots_failed_or_refused_request_fails_the_fleets_at_once_with_its_reason(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    scripted = scripted_sm_bt
    with _reading(scripted, tmp_path) as runtime:  # its request timeout: 10 s
        scripted.outcome = "failed"
        request = _fails(runtime, "FAST", within=3.0)
        assert request.reason == ("robot1: change_mode f_performance_mode failed: its manager's request #1 failed: "
                                  "amcl: activate failed"), request.reason
        scripted.refusal = "pilot is held in active.f_normal_mode by safety (priority 90)"
        request = _fails(runtime, "FAST", within=3.0)
        assert request.reason == (
            "robot1: change_mode f_performance_mode failed: the manager of robot1 refused mode f_performance_mode: "
            "pilot is held in active.f_normal_mode by safety (priority 90)"), request.reason


def test_served_by_sm_bt_a_request_whose_outcome_never_comes_fails_at_the_outcome_timeout_or_when_out_of_reach(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    scripted = scripted_sm_bt
    with _reading(scripted, tmp_path, outcome_timeout=1.5) as runtime:
        scripted.outcome = None
        request = _fails(runtime, "FAST", within=4.0, after=1.5)
        assert request.reason == ("robot1: change_mode f_performance_mode failed: its manager told no outcome of its "
                                  "request #1 (change_mode f_performance_mode) within 1.5 s"), request.reason
    with _reading(scripted, tmp_path) as runtime:  # the outcome timeout: 60 s
        manager = runtime.manager
        request = manager.change_mode("fleet", "FAST")
        wait_until(lambda: "request_change f_performance_mode [fleet]" in scripted.requests[1:], 5.0, "never asked")
        scripted.running.clear()  # hung: out of reach a few probes later, and what it owes fails
        try:
            took = wait_until(lambda: request.done, 10.0, "the fleet's request never ended")
        finally:
            scripted.running.set()
        assert took < 5.0 and not request.succeeded
        assert "no answer from the manager of robot1" in request.reason, request.reason
        # What it owed failed with it: the next request is sent (not held up by the one never told).
        scripted.outcome = "succeeded"
        wait_until(lambda: manager.actual("robot1").state is State.ACTIVE, 5.0, "robot1 never read again")
        _done(runtime, "FAST")


def test_served_by_sm_bt_a_robot_between_modes_is_asked_for_its_target_and_one_whose_nodes_are_out_of_reach_is_lost(
        scripted_sm_bt: ScriptedManager, tmp_path: Path) -> None:
    """Its manager answers unknown. Its preview says which: refused (its nodes out of its reach) or
    waiting for nodes to appear: not there for the fleet; possible: its nodes answer between modes,
    so the fleet takes it for active in no mode and asks it for the mode it wants."""
    scripted = scripted_sm_bt
    runtime = _fleet(tmp_path, extra="")
    try:
        manager = runtime.manager
        scripted.preview = (True, ["amcl to appear"])
        time.sleep(SETTLE)
        assert not manager.observation("robot1").seen
        scripted.preview = (True, [])
        wait_until(lambda: manager.observation("robot1").seen, 5.0, "robot1 never taken for between modes")
        assert str(manager.actual("robot1")) == "active", manager.actual("robot1")
        _done(runtime, "FAST")
        assert scripted.requests == ["request_change f_performance_mode [fleet]"]
        scripted.preview = (False, [])
        scripted.move(State.UNKNOWN, "unknown")
        wait_until(lambda: manager.actual("robot1").state is State.UNKNOWN, 5.0, "robot1 never lost")
        assert manager.observation("robot1").gone == "the manager of robot1 does not know where /robot1/pilot is"
    finally:
        runtime.close()


def test_a_mode_accepted_that_its_manager_reported_already_is_not_read_again(
        ros_context: RosContext, tmp_path: Path) -> None:
    """Its mode event usually comes before the answer to the request: nothing is left to confirm, and
    the reads would land on the fleet's next switch. A mode not reported yet is read at the probes' pace."""
    from sm_bt.ros.remote_parts import RemoteBackend

    path = tmp_path / "fleet.yaml"
    path.write_text(FLEET.format(extra=""), encoding="utf-8")
    backend = RemoteBackend(ros_context.node, load_model(path))
    try:
        robot = backend._robots["robot1"]  # what the fleet knows of it, as its events left it
        robot.present, robot.state, robot.mode, robot.lively = True, State.ACTIVE, "f_performance_mode", True
        backend._accepted(robot, "f_performance_mode")
        assert (robot.asked, robot.timer) == (None, None)
        backend._accepted(robot, "f_normal_mode")
        assert robot.asked == "f_normal_mode" and robot.timer is not None
    finally:
        backend.clock.close()
