"""The fleet's switch across processes: ``sm-bt manager FLEET.yaml`` asked by a client, against the floor.

bench/ros_fleet.py's first row times a fleet embedded in the measuring process. Here the fleet is a
process of its own, as it is deployed: its client asks ``/fleet/request_change`` and the switch is
confirmed once the fleet's ``request_outcome`` says succeeded and its ``mode_event`` says the mode (a
network crossing more each way than the robots' own requests). The floor is the same as row 1's
(every robot's own ``change_mode`` at once, from the same client). The fleet's process is stopped
while the floor switches (it would restore its target); rounds of a block of each, in turns (fleet
first, then floor first); each block one untimed switch, then timed ones; the figure is the ratio of
medians.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections.abc import Callable
from typing import Any

from bench.figures import Figure

#: Seconds a fleet request, or the fleet process's discovery, may take.
TIMEOUT = 30.0
#: A new client's first request waits this long after discovery (the response path matches late).
RESPONSE_PATH_GRACE = 0.3


class FleetAsker:
    """``/{fleet}/request_change``, ``request_outcome`` and ``mode_event`` on ``node`` (spun by its owner)."""

    def __init__(self, node: Any, fleet: str) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sm_bt_msgs.msg import RequestOutcome
        from sm_bt_msgs.srv import RequestChange
        from system_modes_msgs.msg import ModeEvent

        self._node = node
        self._changed = threading.Condition()
        self._outcomes: dict[int, tuple[float, str, str]] = {}  # request -> (arrived, outcome, reason)
        self._modes: list[tuple[float, str]] = []  # (arrived, mode)
        volatile = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.request_change = node.create_client(RequestChange, f"/{fleet}/request_change")
        self._topics = [node.create_subscription(RequestOutcome, f"/{fleet}/request_outcome", self._outcome, volatile),
                        node.create_subscription(ModeEvent, f"/{fleet}/mode_event", self._mode, latched)]

    def close(self) -> None:
        for topic in self._topics:
            self._node.destroy_subscription(topic)
        self._node.destroy_client(self.request_change)

    def _outcome(self, message: Any) -> None:
        with self._changed:
            self._outcomes[int(message.request)] = (time.perf_counter(), str(message.outcome), str(message.reason))
            self._changed.notify_all()

    def _mode(self, message: Any) -> None:
        with self._changed:
            self._modes.append((time.perf_counter(), str(message.goal_mode.label)))
            self._changed.notify_all()

    def _wait(self, found: Callable[[], Any], what: str) -> Any:
        deadline = time.perf_counter() + TIMEOUT
        with self._changed:
            while not (result := found()):
                left = deadline - time.perf_counter()
                if left <= 0:
                    raise RuntimeError(f"{what}: not within {TIMEOUT:g} s")
                self._changed.wait(min(left, 0.05))
            return result

    def ready(self) -> None:
        """The fleet process's service and topics are discovered (a fresh process: its requests from 1)."""
        deadline = time.perf_counter() + TIMEOUT
        while not (self.request_change.service_is_ready()
                   and all(topic.get_publisher_count() > 0 for topic in self._topics)):
            if time.perf_counter() > deadline:
                raise RuntimeError(f"the fleet process's request_change and topics not discovered within {TIMEOUT:g} s")
            time.sleep(0.02)
        time.sleep(RESPONSE_PATH_GRACE)
        with self._changed:
            self._outcomes.clear()

    def switch(self, mode: str, *, answer: bool = True) -> float:
        """Seconds from asking the fleet for ``mode`` until its request succeeded and its mode_event says it;
        not ``answer``: until its mode_event alone (a new client's first answer may be lost to discovery)."""
        from sm_bt_msgs.srv import RequestChange

        done = threading.Event()
        began = time.perf_counter()
        future = self.request_change.call_async(RequestChange.Request(mode=mode, priority=-1))
        future.add_done_callback(lambda _future: done.set())
        if not answer:
            event: float = self._wait(lambda: next((at for at, said in self._modes if at >= began and said == mode),
                                                   None), f"the fleet's mode_event {mode}")
            if not done.is_set():
                self.request_change.remove_pending_request(future)
            return event - began
        if not done.wait(TIMEOUT):
            self.request_change.remove_pending_request(future)
            raise RuntimeError(f"the fleet process did not answer request_change {mode} within {TIMEOUT:g} s")
        reply = future.result()
        if not reply.accepted:
            raise RuntimeError(f"the fleet process refused {mode}: {reply.reason}")
        number = int(reply.request)
        arrived, outcome, reason = self._wait(
            lambda: (found if (found := self._outcomes.get(number)) is not None and found[0] >= began else None),
            f"the fleet's request #{number}'s outcome")
        if outcome != "succeeded":
            raise RuntimeError(f"the fleet's request #{number} ({mode}) {outcome}: {reason}")
        event = self._wait(lambda: next((at for at, said in self._modes if at >= began and said == mode), None),
                           f"the fleet's mode_event {mode}")
        return max(float(arrived), float(event)) - began


def process_switches(asker: FleetAsker, start: Callable[[], None], stop: Callable[[], None],
                     floor: Callable[[str], float], at: str, rounds: int, switches: int, goal: float,
                     say: Callable[[str], None]) -> Figure:
    """Blocks of the fleet process's switches (``start`` it before, ``stop`` it after; it runs when
    called) and of the floor's (``floor(mode)``: one switch's seconds), in turns; the fleet modes
    alternate from ``at``."""
    fleet: list[float] = []
    base: list[float] = []
    by_round: list[float] = []
    running = True
    for index in range(rounds):
        got: dict[str, list[float]] = {}
        for side in ("fleet", "floor") if index % 2 == 0 else ("floor", "fleet"):
            times = []
            if side == "fleet":
                if not running:
                    start()
                    asker.ready()
                    running = True
                for timed in (False, *[True] * switches):
                    at = "NIGHT" if at == "__DEFAULT__" else "__DEFAULT__"
                    took = asker.switch(at, answer=timed)
                    if timed:
                        times.append(took)
                stop()
                running = False
            else:
                for timed in (False, *[True] * switches):
                    at = "NIGHT" if at == "__DEFAULT__" else "__DEFAULT__"
                    took = floor(at)
                    if timed:
                        times.append(took)
            got[side] = times
        fleet += got["fleet"]
        base += got["floor"]
        by_round.append(round(statistics.median(got["fleet"]) / statistics.median(got["floor"]), 2))
        say(f"across processes, round {index + 1}/{rounds}: fleet {statistics.median(got['fleet']) * 1e3:.0f} ms, "
            f"floor {statistics.median(got['floor']) * 1e3:.0f} ms (medians of {switches})")
    ours, floor_median = statistics.median(fleet), statistics.median(base)
    return Figure("fleet", "fleet mode switch across processes (sm-bt manager FLEET.yaml asked by a client) / every "
                  "robot's own change_mode at once", ours / floor_median, "x", goal,
                  details={"fleet_ms": round(ours * 1e3, 1), "floor_ms": round(floor_median * 1e3, 1),
                           "switches": len(fleet), "rounds": rounds, "round_ratios": by_round,
                           "fleet_all_ms": [round(t * 1e3, 1) for t in fleet],
                           "floor_all_ms": [round(t * 1e3, 1) for t in base]})
