"""bench/ros_fleet.py's plain rclpy client of the robots' managers (the floor, and the checker of what each
robot's own manager says), and what it shares with the fleet's rows."""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from bench.ros_baseline import SpunClient
from sm_bt.model.states import State

ROBOT_SYSTEM = "pilot"
#: The fleet's modes, and the mode each asks of every robot's ``pilot``.
ROBOT_MODE = {"__DEFAULT__": "__DEFAULT__", "NIGHT": "f_energy_saving_mode"}
#: Seconds any one wait may take (a request, a batch of calls, discovery).
TIMEOUT = 20.0
#: Seconds one query of a robot's or the fleet's manager may take.
CALL_TIMEOUT = 2.0
#: A new client's first request that must not be asked twice waits this long after discovery (the
#: server's path back to a new client is matched a moment after the client sees the service).
RESPONSE_PATH_GRACE = 0.3


def wait_for(condition: Callable[[], bool], what: str, limit: float = TIMEOUT, poll: float = 0.005) -> float:
    """Poll ``condition`` until true; the seconds it took, or ``RuntimeError(what)`` after ``limit``."""
    began = time.perf_counter()
    while not condition():
        if time.perf_counter() - began > limit:
            raise RuntimeError(f"{what}: not within {limit:g} s")
        time.sleep(poll)
    return time.perf_counter() - began


class RobotsClient(SpunClient):
    """A plain rclpy client of the robots' managers (and of a fleet manager process): one node,
    one ``SingleThreadedExecutor`` spun by one thread throughout; every call has a timeout."""

    def __init__(self, robots: Sequence[str], name: str) -> None:
        from lifecycle_msgs.srv import GetState
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from system_modes_msgs.msg import ModeEvent
        from system_modes_msgs.srv import ChangeMode, GetMode

        self.robots = list(robots)
        super().__init__(name)
        self.change_mode = {r: self.node.create_client(ChangeMode, f"/{r}/{ROBOT_SYSTEM}/change_mode") for r in robots}
        self.get_state = {r: self.node.create_client(GetState, f"/{r}/{ROBOT_SYSTEM}/get_state") for r in robots}
        self.get_mode = {r: self.node.create_client(GetMode, f"/{r}/{ROBOT_SYSTEM}/get_mode") for r in robots}
        self._lock = threading.Lock()
        self._watching: dict[str, float] = {}  # robot -> when its mode_event said the mode awaited
        self._awaited = ""
        self._events = threading.Event()
        # As the fleet's backend subscribes (sm_bt.ros.remote_parts): reliable, volatile.
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        self.subscriptions = [self.node.create_subscription(
            ModeEvent, f"/{r}/{ROBOT_SYSTEM}/mode_event", functools.partial(self._mode_event, r), qos)
            for r in robots]
        self.spin()

    def _mode_event(self, robot: str, message: Any) -> None:
        now = time.perf_counter()
        with self._lock:
            if str(message.goal_mode.label) == self._awaited and robot not in self._watching:
                self._watching[robot] = now
                if len(self._watching) == len(self.robots):
                    self._events.set()

    def ready(self, *, events: bool = True) -> float:
        """Wait until every robot's services are discovered and (``events``) every ``mode_event``
        subscription is matched; the seconds it took."""
        clients = [*self.change_mode.values(), *self.get_state.values(), *self.get_mode.values()]

        def found() -> bool:
            return (all(client.service_is_ready() for client in clients)
                    and (not events or all(s.get_publisher_count() > 0 for s in self.subscriptions)))

        try:
            took = wait_for(found, "the robots' managers discovered", TIMEOUT, 0.02)
        except RuntimeError:
            missing = [c.srv_name for c in clients if not c.service_is_ready()]
            missing += [s.topic_name for s in self.subscriptions if events and s.get_publisher_count() == 0]
            raise RuntimeError(f"not discovered within {TIMEOUT:g} s: {', '.join(missing[:4])}"
                               f"{' ...' if len(missing) > 4 else ''}") from None
        time.sleep(RESPONSE_PATH_GRACE)
        return took

    def call(self, client: Any, request: Any, timeout: float = CALL_TIMEOUT) -> Any:
        """The response of ``client`` to ``request``; ``RuntimeError`` after ``timeout`` s."""
        from sm_bt.ros.node_calls import answer

        try:
            response = answer(client, request, timeout)
        except Exception as error:
            raise RuntimeError(f"{client.srv_name}: {error!r}") from error
        if response is None:
            raise RuntimeError(f"{client.srv_name}: no answer within {timeout:g} s")
        return response

    def switch(self, fleet_mode: str, *, answers: bool = True) -> float:
        """Every robot's ``change_mode`` at once; seconds until every ``mode_event`` says the mode
        and (``answers``) every answer has come, successful."""
        from system_modes_msgs.srv import ChangeMode

        mode = ROBOT_MODE[fleet_mode]
        request = ChangeMode.Request(mode_name=mode)
        answered: dict[str, float] = {}
        refused: list[str] = []
        all_answered = threading.Event()

        def answer(robot: str, future: Any) -> None:
            now = time.perf_counter()
            error = future.exception()
            with self._lock:
                if error is not None or not future.result().success:
                    refused.append(f"{robot}: {error!r}" if error is not None else f"{robot} refused {mode}")
                answered[robot] = now
                if len(answered) == len(self.robots):
                    all_answered.set()

        with self._lock:
            self._watching, self._awaited = {}, mode
            self._events.clear()
        futures = {}
        began = time.perf_counter()
        for robot in self.robots:
            future = self.change_mode[robot].call_async(request)
            future.add_done_callback(lambda future, robot=robot: answer(robot, future))
            futures[robot] = future
        ok = self._events.wait(TIMEOUT) and (not answers or all_answered.wait(max(0.0, began + TIMEOUT
                                                                                  - time.perf_counter())))
        with self._lock:
            events, self._awaited = dict(self._watching), ""
        for robot, future in futures.items():
            if robot not in answered:
                self.change_mode[robot].remove_pending_request(future)
        if not ok:
            raise RuntimeError(f"the robots' own switch to {mode}: after {TIMEOUT:g} s no mode_event from "
                               f"{sorted(set(self.robots) - set(events))}, no answer from "
                               f"{sorted(set(self.robots) - set(answered)) if answers else '(not awaited)'}")
        if refused:
            raise RuntimeError(f"the robots' own switch to {mode}: {refused[0]}")
        ends = [*events.values(), *(answered.values() if answers else [])]
        return max(ends) - began

    def robot_view(self, robot: str) -> tuple[State, str]:
        """``robot``'s state and mode as its own manager answers them."""
        from lifecycle_msgs.srv import GetState
        from system_modes_msgs.srv import GetMode

        state = self.call(self.get_state[robot], GetState.Request()).current_state.id
        mode = self.call(self.get_mode[robot], GetMode.Request()).current_mode
        try:
            return State(int(state)), str(mode)
        except ValueError:
            return State.UNKNOWN, str(mode)
