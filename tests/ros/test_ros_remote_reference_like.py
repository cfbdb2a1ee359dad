"""A fleet's robot whose manager behaves as the reference's ``mode_manager`` does, scripted here.

The scripted manager serves ``/robot1/pilot``'s system_modes interface from this test's own rclpy
node and does what the reference was seen to do (docs/reference.md): it answers ``unknown`` until a
node of its moves; its ``activate`` means ``__DEFAULT__`` while its ``change_mode`` of an inactive
system activates it in that mode; it answers ``success`` at once and reports later, and sometimes
sends no event at all. Against it, the fleet (sm_bt.ros.remote_parts) must ask for the right
things in the right order and learn where the robot is without the events. The real reference is
driven in ``make interop`` (tests/interop/interop_fleet.py).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from ros_processes import RosContext, wait_until
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.model import load_model
from sm_bt.model.states import State
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


class ScriptedManager:
    """``/robot1/pilot`` served as the reference serves it; ``requests`` lists what it was asked."""

    def __init__(self, ros: RosContext) -> None:
        node = ros.node
        self.state, self.mode = State.UNKNOWN, "unknown"
        self.requests: list[str] = []
        self.events = True  # publish events for its moves (the reference sometimes does not)
        self.sm_bt_switch = False  # switch an active system as sm-bt manager tells it (switch_as_sm_bt)
        self._lock = threading.Lock()
        prefix = "/robot1/pilot"
        self._transition_events = node.create_publisher(TransitionEvent, f"{prefix}/transition_event", 10)
        self._mode_events = node.create_publisher(ModeEvent, f"{prefix}/mode_event", 10)
        self._services = [
            node.create_service(GetState, f"{prefix}/get_state", self._get_state),
            node.create_service(GetMode, f"{prefix}/get_mode", self._get_mode),
            node.create_service(ChangeState, f"{prefix}/change_state", self._change_state),
            node.create_service(ChangeMode, f"{prefix}/change_mode", self._change_mode)]

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

    def _later(self, state: State, mode: str) -> None:
        threading.Timer(DELAY, self.move, (state, mode)).start()

    def _get_state(self, request: GetState.Request, response: GetState.Response) -> GetState.Response:
        with self._lock:
            response.current_state.id = int(self.state.value)
        return response

    def _get_mode(self, request: GetMode.Request, response: GetMode.Response) -> GetMode.Response:
        with self._lock:
            response.current_mode = self.mode
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
            threading.Thread(target=self.switch_as_sm_bt, args=(request.mode_name,)).start()
            return response
        with self._lock:
            redundant = self.state is State.ACTIVE and self.mode == request.mode_name
            configured = self.state in (State.INACTIVE, State.ACTIVE)
        if not redundant and configured:  # it activates parts, never configures them
            self._later(State.ACTIVE, request.mode_name)
        return response


@pytest.fixture
def scripted(ros_context: RosContext) -> ScriptedManager:
    return ScriptedManager(ros_context)


def _fleet(tmp_path: Path, extra: str = "    served_by: reference\n") -> RosRuntime:
    path = tmp_path / "fleet.yaml"
    path.write_text(FLEET.format(extra=extra), encoding="utf-8")
    return RosRuntime(load_model(path), node_name="fleet_manager", manager_options={"request_timeout": 10.0})


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[RosRuntime]:
    runtime = _fleet(tmp_path)
    yield runtime
    runtime.close()


def _done(runtime: RosRuntime, mode: str) -> None:
    request = runtime.manager.change_mode("fleet", mode)
    wait_until(lambda: request.done, 15.0, f"fleet {mode} did not end")
    assert request.succeeded, request.reason


def test_a_robot_its_manager_knows_nothing_of_is_taken_for_unconfigured_and_brought_up_configure_then_mode(
        scripted: ScriptedManager, fleet: RosRuntime) -> None:
    manager = fleet.manager
    wait_until(lambda: manager.actual("robot1").state is State.UNCONFIGURED, 10.0, "robot1 never taken in")
    time.sleep(SETTLE)  # its manager goes on answering unknown: that is no loss of the robot
    assert manager.actual("robot1").state is State.UNCONFIGURED
    _done(fleet, "__DEFAULT__")
    # Configure by id, then activation as the mode: never the reference's activate (its __DEFAULT__).
    assert scripted.requests == ["change_state 1", "change_mode f_normal_mode"]
    assert str(manager.actual("robot1")) == "active.f_normal_mode"

    _done(fleet, "REST")
    _done(fleet, "FAST")  # its mode asked while inactive is kept for the activation: one call
    assert scripted.requests[2:] == ["change_state 4", "change_mode f_performance_mode"]
    assert (scripted.state, scripted.mode) == (State.ACTIVE, "f_performance_mode")
    assert str(manager.actual("fleet")) == "active.FAST"


def test_served_by_sm_bt_a_robot_its_manager_knows_nothing_of_stays_out_of_reach(
        scripted: ScriptedManager, tmp_path: Path) -> None:
    runtime = _fleet(tmp_path, extra="")
    try:
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
        scripted: ScriptedManager, tmp_path: Path) -> None:
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
