"""The brain's instrument in tests/e2e/stress_fleet_hosts.py: one rclpy process in the brain's namespace
(tests/support/fleet_hosts.py) that asks the robots' managers and the fleet's, driven over stdin.

``python tests/support/fleet_agent.py ROBOTS`` knows ``/robot1`` ... ``/robotROBOTS`` (each ``pilot``'s
manager) and the fleet's manager (system ``fleet``, parts ``robotK``). It prints ``READY`` once every
robot's services and ``mode_event`` are discovered, then answers one line per command (``ERROR what`` when
a command fails; every time is the machine's ``time.monotonic()``, comparable with the test's):

``floor MODE [untimed]``
    every robot's own ``/robotK/pilot/change_mode`` at once, as bench/ros_fleet.py's floor (its client):
    ``FLOOR SECONDS``, until every robot's ``mode_event`` says the mode and every answer has come (MODE
    is the fleet's mode: NIGHT asks each robot for ``f_energy_saving_mode``).
``fleet-ready SINCE``
    ``OK`` once the fleet's ``request_change``, ``request_outcome``, ``mode_event`` and ``transition_event``
    are discovered and its ``transition_event`` arrived at or after SINCE says it knows every robot (a
    manager started then, not its predecessor), and (once watched) a ``/diagnostics`` status of every robot
    has arrived at or after SINCE.
``diagnostics``
    ``OK`` once subscribed to ``/diagnostics`` (``unknown`` and ``agree`` need it) and a publisher is matched.
``fleet MODE``
    ``/fleet/request_change`` to MODE: ``FLEET SECONDS OUTCOME EVENT FIRST LAST``, until its
    ``request_outcome`` says succeeded and the fleet's ``mode_event`` says MODE (SECONDS is the later;
    ``ERROR`` if it failed); FIRST and LAST: the first and the last robot's own ``mode_event`` of the change,
    as heard here.
``unknown ROBOT SINCE TIMEOUT``
    ``UNKNOWN STAMP TRANSITION`` once a ``/diagnostics`` status arrived at or after SINCE says ROBOT's
    ``actual`` is unknown (TRANSITION: when ``/fleet/transition_event`` said unknown after SINCE, or -1).
``agree TIMEOUT``
    ``AGREE STAMP`` once the fleet's latest view of every robot (``actual`` on ``/diagnostics``; one it
    takes for unknown never agrees) equals what that robot's own manager answers (``get_state``, and ``get_mode``
    when active), all asked at once with a short timeout, again and again.
``views``
    ``VIEWS {json}``: the fleet's view and each robot's own answer now.

Stops at ``quit``, at the end of stdin, or on SIGINT (every ROS wait here has a timeout).
"""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # bench, beside sm_bt

from bench.ros_baseline import freeze_garbage
from bench.ros_fleet_client import ROBOT_MODE, RobotsClient

FLEET = "fleet"
#: Seconds one question of the ``agree`` loop may wait (a robot just plugged back may not answer yet).
POLL_TIMEOUT = 0.25
#: Seconds a fleet request or a discovery may take.
TIMEOUT = 30.0
#: The fleet's first request after discovery waits this long (the response path matches late).
RESPONSE_PATH_GRACE = 0.3


def _say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


class Agent:
    """The robots' client (bench's), with the fleet's services and topics on the same node."""

    def __init__(self, robots: int) -> None:
        from lifecycle_msgs.msg import TransitionEvent
        from lifecycle_msgs.srv import GetState
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sm_bt_msgs.msg import RequestOutcome
        from sm_bt_msgs.srv import RequestChange
        from system_modes_msgs.msg import ModeEvent
        from system_modes_msgs.srv import GetMode

        self.robots = [f"robot{k}" for k in range(1, robots + 1)]
        self.client = RobotsClient(self.robots, "sm_bt_fleet_agent")
        node = self.client.node
        self.lock = threading.RLock()  # fleet_view() is asked under _wait()
        self.changed = threading.Condition(self.lock)
        self.diagnostics: dict[str, tuple[float, str]] = {}  # part -> (arrived, actual)
        self.unknown_at: dict[str, list[float]] = {robot: [] for robot in self.robots}
        self.outcomes: dict[int, tuple[float, str, str]] = {}  # request -> (arrived, outcome, reason)
        self.fleet_modes: list[tuple[float, str]] = []
        self.fleet_states: list[tuple[float, str]] = []
        volatile = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.request_change = node.create_client(RequestChange, f"/{FLEET}/request_change")
        self.get_state = {r: node.create_client(GetState, f"/{r}/pilot/get_state") for r in self.robots}
        self.get_mode = {r: node.create_client(GetMode, f"/{r}/pilot/get_mode") for r in self.robots}
        self.fleet_topics = [
            node.create_subscription(RequestOutcome, f"/{FLEET}/request_outcome", self._outcome, volatile),
            node.create_subscription(ModeEvent, f"/{FLEET}/mode_event", self._fleet_mode, latched),
            node.create_subscription(TransitionEvent, f"/{FLEET}/transition_event", self._fleet_state, latched),
        ]
        self._volatile = volatile
        self.watching_diagnostics = False

    def watch_diagnostics(self) -> str:
        """Subscribe to ``/diagnostics`` (every manager's: not while switches are timed, where its messages
        would be this process's work and the robots'); ``OK`` once a publisher is matched."""
        from diagnostic_msgs.msg import DiagnosticArray

        topic = self.client.node.create_subscription(DiagnosticArray, "/diagnostics", self._diagnostics,
                                                     self._volatile)
        self.fleet_topics.append(topic)
        self.watching_diagnostics = True
        deadline = time.monotonic() + TIMEOUT
        while topic.get_publisher_count() == 0:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no publisher of /diagnostics within {TIMEOUT:g} s")
            time.sleep(0.02)
        return "OK"

    # -- what the fleet says -------------------------------------------------------------------------

    def _outcome(self, message: Any) -> None:
        with self.changed:
            self.outcomes[int(message.request)] = (time.monotonic(), str(message.outcome), str(message.reason))
            self.changed.notify_all()

    def _fleet_mode(self, message: Any) -> None:
        with self.changed:
            self.fleet_modes.append((time.monotonic(), str(message.goal_mode.label)))
            self.changed.notify_all()

    def _fleet_state(self, message: Any) -> None:
        with self.changed:
            self.fleet_states.append((time.monotonic(), str(message.goal_state.label)))
            self.changed.notify_all()

    def _diagnostics(self, message: Any) -> None:
        now = time.monotonic()
        with self.changed:
            for status in message.status:
                actual = next((str(pair.value) for pair in status.values if pair.key == "actual"), None)
                part = str(status.hardware_id)
                if actual is None:
                    continue
                self.diagnostics[part] = (now, actual)
                if actual == "unknown" and part in self.unknown_at:
                    self.unknown_at[part].append(now)
            self.changed.notify_all()

    def _wait(self, condition: Any, timeout: float, what: str) -> Any:
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                result = condition()
                if result:
                    return result
                left = deadline - time.monotonic()
                if left <= 0:
                    raise RuntimeError(f"{what}: not within {timeout:g} s")
                self.changed.wait(min(left, 0.05))

    # -- the commands --------------------------------------------------------------------------------

    def floor(self, mode: str, untimed: bool) -> str:
        if untimed:
            return f"FLOOR {self.client.switch(mode, answers=False):.6f}"
        return f"FLOOR {self.client.switch(mode):.6f}"

    def fleet_ready(self, since: float) -> str:
        deadline = time.monotonic() + TIMEOUT
        while not (self.request_change.service_is_ready()
                   and all(topic.get_publisher_count() > 0 for topic in self.fleet_topics)
                   and any(at >= since and label != "unknown" for at, label in list(self.fleet_states))
                   and (not self.watching_diagnostics
                        or all(value is not None for value in self.fleet_view(since).values()))):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the fleet's manager not discovered, or it knew not every robot, within "
                                   f"{TIMEOUT:g} s: {self.fleet_states[-3:]} {self.fleet_view(since)}")
            time.sleep(0.02)
        time.sleep(RESPONSE_PATH_GRACE)
        with self.lock:  # a new manager numbers its requests from 1 again
            self.outcomes.clear()
        return "OK"

    def fleet(self, mode: str) -> str:
        from sm_bt_msgs.srv import RequestChange

        client = self.client
        with client._lock:  # the robots' own mode_events, as the floor awaits them: when the robots were done
            client._watching, client._awaited = {}, ROBOT_MODE[mode]
        began_clock, began = time.perf_counter(), time.monotonic()
        answer = self.client.call(self.request_change, RequestChange.Request(mode=mode, priority=-1), TIMEOUT)
        if not answer.accepted:
            raise RuntimeError(f"the fleet refused {mode}: {answer.reason}")
        number = int(answer.request)

        def ended() -> tuple[float, str, str] | None:
            found = self.outcomes.get(number)
            return found if found is not None and found[0] >= began else None

        outcome = self._wait(ended, TIMEOUT, f"the fleet's request #{number}'s outcome")
        if outcome[1] != "succeeded":
            raise RuntimeError(f"the fleet's request #{number} ({mode}) {outcome[1]}: {outcome[2]}")
        event = self._wait(lambda: next((at for at, label in self.fleet_modes if at >= began and label == mode),
                                        None), TIMEOUT, f"the fleet's mode_event {mode}")
        with client._lock:
            robots, client._awaited = dict(client._watching), ""
        done = [at - began_clock for at in robots.values()] if len(robots) == len(self.robots) else [math.nan]
        return (f"FLEET {max(outcome[0], event) - began:.6f} {outcome[0] - began:.6f} {event - began:.6f} "
                f"{min(done):.6f} {max(done):.6f}")

    def unknown(self, robot: str, since: float, timeout: float) -> str:
        stamp = self._wait(lambda: next((at for at in self.unknown_at[robot] if at >= since), None), timeout,
                           f"{robot} unknown at the fleet")
        with self.lock:
            state = next((at for at, label in self.fleet_states if at >= since and label == "unknown"), -1.0)
        return f"UNKNOWN {stamp:.6f} {state:.6f}"

    def own(self, timeout: float = POLL_TIMEOUT) -> dict[str, str | None]:
        """What each robot's manager answers now (all asked at once): ``active.MODE`` or the state;
        ``None`` for a robot that did not answer within ``timeout``."""
        from lifecycle_msgs.srv import GetState
        from system_modes_msgs.srv import GetMode

        calls = {robot: (self.get_state[robot], GetState.Request()) for robot in self.robots}
        modes = {robot: (self.get_mode[robot], GetMode.Request()) for robot in self.robots}
        pending = []
        for client, request in [*calls.values(), *modes.values()]:
            done = threading.Event()
            future = client.call_async(request)
            future.add_done_callback(lambda _future, done=done: done.set())
            pending.append((client, future, done))
        deadline = time.monotonic() + timeout
        for client, future, done in pending:
            if not done.wait(max(0.0, deadline - time.monotonic())):
                client.remove_pending_request(future)
        results = [future.result() if future.done() and future.exception() is None else None
                   for _, future, _ in pending]
        views: dict[str, str | None] = {}
        for index, robot in enumerate(self.robots):
            state, mode = results[index], results[len(self.robots) + index]
            if state is None or mode is None:
                views[robot] = None
                continue
            label = str(state.current_state.label)
            views[robot] = f"{label}.{mode.current_mode}" if label == "active" else label
        return views

    def fleet_view(self, since: float = -1.0) -> dict[str, str | None]:
        with self.lock:
            return {robot: (self.diagnostics[robot][1] if robot in self.diagnostics
                            and self.diagnostics[robot][0] >= since else None) for robot in self.robots}

    def agree(self, timeout: float) -> str:
        deadline = time.monotonic() + timeout
        while True:
            before = self.fleet_view()
            own = self.own()
            now = time.monotonic()
            if all(value is not None and value != "unknown" for value in own.values()) and before == own \
                    and self.fleet_view() == before:
                return f"AGREE {now:.6f}"
            if now > deadline:
                wrong = {robot: (before[robot], own[robot]) for robot in self.robots if before[robot] != own[robot]}
                raise RuntimeError(f"the fleet disagrees with its robots after {timeout:g} s (fleet, robot): {wrong}")
            time.sleep(0.01)

    def views(self) -> str:
        return "VIEWS " + json.dumps({"fleet": self.fleet_view(), "robots": self.own(1.0)})

    def run(self, line: str) -> str:
        word, *args = line.split()
        if word == "floor":
            return self.floor(args[0], untimed=args[1:] == ["untimed"])
        if word == "fleet-ready":
            return self.fleet_ready(float(args[0]))
        if word == "fleet":
            return self.fleet(args[0])
        if word == "unknown":
            return self.unknown(args[0], float(args[1]), float(args[2]))
        if word == "agree":
            return self.agree(float(args[0]))
        if word == "diagnostics":
            return self.watch_diagnostics()
        if word == "views":
            return self.views()
        raise ValueError(f"no such command: {word}")


def main(argv: list[str]) -> int:
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    agent = Agent(int(argv[0]))
    try:
        agent.client.ready()
        freeze_garbage()  # as bench/ros_fleet.py's floor: no full collection lands on a measurement
        _say("READY")
        for raw in sys.stdin:
            line = raw.strip()
            if line == "quit" or stop.is_set():
                break
            if not line:
                continue
            try:
                _say(agent.run(line))
            except Exception as error:  # the harness reads the line, and asks on
                _say(f"ERROR {type(error).__name__}: {error}".replace("\n", " "))
    except KeyboardInterrupt:
        pass
    finally:
        agent.client.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
