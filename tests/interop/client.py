"""A plain rclpy client of a mode manager: what any ROS 2 program sees of one (no sm_bt code here).

``python client.py SCENARIO.json`` runs the scenario's steps against whichever manager serves the
system_modes interface in this ROS domain (``sm-bt manager`` or the reference's ``mode_manager``)
and prints one JSON document: per step, the request, the answer, when ``get_state``/``get_mode``
and the ``transition_event``/``mode_event`` topics first showed the expected value, every event
heard meanwhile, and the state and mode of every part afterwards (the manager's answers, and each
node's own lifecycle state).

Scenario: ``{"systems": [...], "nodes": [...], "steps": [STEP, ...]}``, a step one of

* ``{"change_state": PART, "transition": LABEL, "expect": STATE, "id": true}``: ``/PART/change_state``
  with the transition's id and label (``"id": false``: the label alone, id 0);
* ``{"change_mode": PART, "mode": MODE, "expect": MODE}``: ``/PART/change_mode``;
* ``{"node_change_state": NODE, "transition": LABEL, "watch": SYSTEM}``: the node's own
  ``change_state``, behind the manager's back; what ``get_mode`` of ``SYSTEM`` says then;
* ``{"late_subscriber": PART}``: a subscriber that joins now, with durability transient-local, as
  a latched-topic client does: what it hears of ``mode_event`` and ``transition_event`` at once.

``expect`` may be null: the step then watches the full ``window`` and records what happened.
Every call has a timeout; nothing waits longer than a step's ``window`` (default 4 s).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

import rclpy
from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetAvailableModes, GetMode

CALL_TIMEOUT = 3.0
DISCOVERY_TIMEOUT = 15.0
POLL = 0.02
WINDOW = 4.0
#: Quiet time after the nodes' last transition event before a step counts them as settled.
SETTLE = 0.3
PRIMARY = frozenset({"unconfigured", "inactive", "active", "finalized"})
#: lifecycle_msgs/Transition ids of the requestable labels (shutdown: from the primary state asked).
IDS = {"configure": 1, "cleanup": 2, "activate": 3, "deactivate": 4}
SHUTDOWN_IDS = {"unconfigured": 5, "inactive": 6, "active": 7}


class Client:
    def __init__(self, systems: list[str], nodes: list[str]) -> None:
        self.systems, self.nodes = systems, nodes
        self.node = rclpy.create_node("interop_client")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._clients: dict[str, Any] = {}
        self._absent: set[str] = set()
        self.heard: list[tuple[float, str, str]] = []
        self._lock = threading.Lock()
        volatile = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
        for part in systems + nodes:
            self.node.create_subscription(ModeEvent, f"/{part}/mode_event",
                                          lambda m, p=part: self._hear(f"/{p}/mode_event", _mode_text(m)), volatile)
            self.node.create_subscription(TransitionEvent, f"/{part}/transition_event",
                                          lambda m, p=part: self._hear(f"/{p}/transition_event", _transition_text(m)),
                                          volatile)
        self._stop = threading.Event()
        self._spinner = threading.Thread(target=self._spin, daemon=True)
        self._spinner.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        """Stop spinning first: rclpy aborts when its context ends under a spinning thread."""
        self._stop.set()
        self._spinner.join(5.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()

    def _hear(self, topic: str, text: str) -> None:
        with self._lock:
            self.heard.append((time.monotonic(), topic, text))

    def events_since(self, since: float) -> list[tuple[float, str, str]]:
        with self._lock:
            return [event for event in self.heard if event[0] >= since]

    # -- calls -------------------------------------------------------------------------------------------

    def call(self, service_type: Any, name: str, request: Any, timeout: float = CALL_TIMEOUT) -> Any:
        """The response, or None when nothing answers within ``timeout`` (or nobody serves it)."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.node.create_client(service_type, name)
        # A service that was not there once (a plain node's lifecycle services) is not waited for again.
        if not client.wait_for_service(timeout_sec=0.1 if name in self._absent else timeout):
            self._absent.add(name)
            return None
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(timeout):
            client.remove_pending_request(future)
            return None
        return future.result()

    def get_state(self, part: str) -> str | None:
        response = self.call(GetState, f"/{part}/get_state", GetState.Request())
        return None if response is None else f"{response.current_state.label}({response.current_state.id})"

    def get_mode(self, part: str) -> str | None:
        response = self.call(GetMode, f"/{part}/get_mode", GetMode.Request())
        return None if response is None else str(response.current_mode)

    def snapshot(self) -> dict[str, Any]:
        """What the manager says of every part, and each node's own lifecycle state."""
        return {
            "manager": {part: {"state": self.get_state(part) if part in self.systems else None,
                               "mode": self.get_mode(part)} for part in self.systems + self.nodes},
            "nodes": {node: self.get_state(node) for node in self.nodes},
        }

    def wait_for_services(self) -> float:
        """Make a client for every service the scenario may call and wait until each is served, so
        that the steps time a manager at work, not discovery. Seconds it took."""
        start = time.monotonic()
        services = [(GetMode, "get_mode"), (ChangeMode, "change_mode"), (GetAvailableModes, "get_available_modes")]
        wanted = [(kind, f"/{part}/{name}") for part in self.systems + self.nodes for kind, name in services]
        wanted += [(kind, f"/{part}/{name}") for part in self.systems + self.nodes
                   for kind, name in ((GetState, "get_state"), (ChangeState, "change_state"))]
        for kind, name in wanted:
            client = self._clients.get(name) or self.node.create_client(kind, name)
            self._clients[name] = client
            if not client.wait_for_service(timeout_sec=max(0.1, DISCOVERY_TIMEOUT - (time.monotonic() - start))):
                self._absent.add(name)
        return time.monotonic() - start

    # -- steps -------------------------------------------------------------------------------------------

    def run(self, step: dict[str, Any]) -> dict[str, Any]:
        window = float(step.get("window", WINDOW))
        if "change_state" in step:
            return self._change_state(step, window)
        if "change_mode" in step:
            return self._change_mode(step, window)
        if "node_change_state" in step:
            return self._node_change_state(step, window)
        if "late_subscriber" in step:
            return self._late_subscriber(step["late_subscriber"], window)
        raise ValueError(f"unknown step {step}")

    def _change_state(self, step: dict[str, Any], window: float) -> dict[str, Any]:
        part, label = step["change_state"], step["transition"]
        transition_id = IDS.get(label, 0)
        if label == "shutdown":
            transition_id = SHUTDOWN_IDS.get((self.get_state(part) or "").partition("(")[0], 6)
        if not step.get("id", True):
            transition_id = 0
        request = ChangeState.Request(transition=Transition(id=transition_id, label=label))
        expect = step.get("expect")
        return self._request(ChangeState, f"/{part}/change_state", request, window,
                             probe=lambda: (self.get_state(part) or "").partition("(")[0],
                             shown=lambda value: value == expect,
                             told=lambda topic, text: topic == f"/{part}/transition_event" and text.endswith(
                                 f"-> {expect}"),
                             expect=expect, sent={"id": transition_id, "label": label})

    def _change_mode(self, step: dict[str, Any], window: float) -> dict[str, Any]:
        part, mode = step["change_mode"], step["mode"]
        expect = step.get("expect", mode)
        return self._request(ChangeMode, f"/{part}/change_mode", ChangeMode.Request(mode_name=mode), window,
                             probe=lambda: self.get_mode(part), shown=lambda value: value == expect,
                             told=lambda topic, text: topic == f"/{part}/mode_event" and text.endswith(
                                 f"-> {expect!r}"),
                             expect=expect, sent={"mode": mode})

    def _node_change_state(self, step: dict[str, Any], window: float) -> dict[str, Any]:
        node, label, system = step["node_change_state"], step["transition"], step["watch"]
        before = self.get_mode(system)
        request = ChangeState.Request(transition=Transition(id=IDS[label], label=label))
        result = self._request(ChangeState, f"/{node}/change_state", request, window,
                               probe=lambda: self.get_mode(system), shown=lambda value: value != before,
                               told=lambda topic, text: topic == f"/{system}/mode_event",
                               expect=f"{system} leaves {before!r}", sent={"id": IDS[label], "label": label},
                               full=True)
        result["system_mode_before"] = before
        return result

    def _request(self, service_type: Any, name: str, request: Any, window: float, *, probe: Any, shown: Any,
                 told: Any, expect: str | None, sent: dict[str, Any], full: bool = False) -> dict[str, Any]:
        """Send ``request``, then ask ``probe()`` (get_state or get_mode) every POLL s and watch the
        events until ``shown(answer)`` and ``told(event)`` (or the window ends); the answers' changes
        are kept with their times. ``full``: watch the whole window (what follows, e.g. a recovery)."""
        start = time.monotonic()
        response = self.call(service_type, name, request)
        answered = time.monotonic() - start
        shown_at: float | None = None
        told_at: float | None = None
        trace: list[list[Any]] = []
        while time.monotonic() - start < window and (shown_at is None or told_at is None or expect is None or full
                                                     or not self._nodes_settled(start)):
            value = probe()
            if not trace or trace[-1][1] != value:
                trace.append([round(time.monotonic() - start, 3), value])
            if shown_at is None and expect is not None and shown(value):
                shown_at = time.monotonic() - start
            if told_at is None and expect is not None:
                told_at = next((at - start for at, topic, text in self.events_since(start) if told(topic, text)), None)
            time.sleep(POLL)
        return {
            "service": name, "sent": sent, "expect": expect, "nodes_done_s": self._nodes_done(start),
            "answer": None if response is None else bool(response.success),
            "answered_s": round(answered, 4),
            "shown_s": None if shown_at is None else round(shown_at, 4),
            "told_s": None if told_at is None else round(told_at, 4),
            "answers": trace,
            "events": [[round(at - start, 3), topic, text] for at, topic, text in self.events_since(start)],
            "after": self.snapshot(),
        }

    def _node_transitions(self, since: float) -> list[tuple[float, str, str]]:
        """The nodes' own transition_event messages since ``since``."""
        topics = {f"/{node}/transition_event" for node in self.nodes}
        return [event for event in self.events_since(since) if event[1] in topics]

    def _nodes_settled(self, since: float) -> bool:
        """No node has been heard in a transition for SETTLE s: each one's last event ends in a
        primary state."""
        events = self._node_transitions(since)
        if not events:
            return True
        last = {topic: text for _, topic, text in events}
        return (time.monotonic() - events[-1][0] >= SETTLE
                and all(text.rpartition("-> ")[2] in PRIMARY for text in last.values()))

    def _nodes_done(self, since: float) -> float | None:
        """When the last node finished its transitions of this step (None: no node moved)."""
        events = [at for at, _, text in self._node_transitions(since) if text.rpartition("-> ")[2] in PRIMARY]
        return round(max(events) - since, 4) if events else None

    def _late_subscriber(self, part: str, window: float) -> dict[str, Any]:
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        heard: list[tuple[float, str, str]] = []
        start = time.monotonic()
        subscriptions = [
            self.node.create_subscription(ModeEvent, f"/{part}/mode_event",
                                          lambda m: heard.append((time.monotonic(), "mode_event", _mode_text(m))),
                                          latched),
            self.node.create_subscription(TransitionEvent, f"/{part}/transition_event",
                                          lambda m: heard.append((time.monotonic(), "transition_event",
                                                                  _transition_text(m))), latched)]
        time.sleep(window)
        for subscription in subscriptions:
            self.node.destroy_subscription(subscription)
        return {"late_subscriber": part, "heard": [[round(at - start, 3), topic, text] for at, topic, text in heard],
                "mode_now": self.get_mode(part)}

    def available_modes(self) -> dict[str, list[str] | None]:
        out: dict[str, list[str] | None] = {}
        for part in self.systems + self.nodes:
            response = self.call(GetAvailableModes, f"/{part}/get_available_modes", GetAvailableModes.Request())
            out[part] = None if response is None else list(response.available_modes)
        return out


def _mode_text(message: Any) -> str:
    return f"{message.start_mode.label!r} -> {message.goal_mode.label!r}"


def _transition_text(message: Any) -> str:
    return f"{_clean(message.start_state.label)} -> {_clean(message.goal_state.label)}"


def _clean(label: str) -> str:
    """A label as text (the reference sometimes sends a raw byte in a label)."""
    return label if label.isprintable() else repr(label)


def main() -> int:
    with open(sys.argv[1], encoding="utf-8") as stream:
        scenario = json.load(stream)
    rclpy.init()
    client = Client(scenario["systems"], scenario["nodes"])
    try:
        discovered = client.wait_for_services()
        report: dict[str, Any] = {"discovery_s": round(discovered, 3), "first": client.snapshot(),
                                  "available_modes": client.available_modes(), "steps": []}
        for step in scenario["steps"]:
            report["steps"].append({"step": step, **client.run(step)})
        json.dump(report, sys.stdout)
        return 0
    finally:
        client.close()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
