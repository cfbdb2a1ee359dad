"""P1 as an application sees it: the embedded manager against a plain rclpy client in the same process.

One child process runs 20 rclpy lifecycle nodes (``sm-bt sim-nodes``) of ``bench.ros``'s model (one
system ``robot`` of 20 nodes, 5 parameters each, two modes that differ in all of them), active in
``__DEFAULT__``. This process embeds the manager as an application does (``RosRuntime(model)``,
default options: the system_modes interface and diagnostics served, its executor threads spinning
throughout) and times its requests, from making one to its ``add_done_callback`` (no polling).
With the runtime closed, a plain rclpy client in this same process (one node, a
``SingleThreadedExecutor`` spun by one thread, as an application would write it) makes the same
calls to all nodes at once, timed to the last answer's future callback:

* (a) a mode switch: ``change_mode robot FAST`` / ``__DEFAULT__`` in turns, against
  ``set_parameters_atomically`` of the mode's 5 values to the 20 nodes;
* (b) bring-up as two requests: ``change_state configure`` then ``activate``, against
  ``change_state`` configure to every node, a barrier, then activate;
* (c) bring-up as one request: ``change_mode robot __DEFAULT__`` from unconfigured, against one
  configure → activate chain per node (each node's activate as soon as its configure is answered).

Each side brings up from a shutdown (deactivate, cleanup) it made itself, untimed, after one
untimed request of each kind. Unlike ``bench.ros``, nothing else listens to the nodes while the
client works, and the manager's threads share the interpreter with the thread that makes its
requests. A round is one block of each side (20 switches and 8 bring-ups of each kind), in turns
(manager first, then client first, ...): on a shared machine a single block pair can land in a
slow spell of one side only. The figures are ratios of the medians over all rounds; each round's
own ratio is in the details, to show the spread.
"""
from __future__ import annotations

import statistics
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench.figures import Figure
from bench.ros import P1_GOAL, model_text
from bench.ros_baseline import SYSTEM, TIMEOUT, SpunClient, freeze_garbage, mode_values
from bench.ros_baseline import confirmed as confirmed_request

#: Per round and side on a full run: switches, bring-ups of each kind; rounds. ``--quick`` takes a few.
SWITCHES, BRING_UPS, ROUNDS = 20, 8, 6
KINDS = ("switch", "two", "one")


def _manager_times(model: Any, names: Sequence[str], switches: int, bring_ups: int) -> dict[str, list[float]]:
    """Seconds of each confirmed request of an embedded ``RosRuntime`` (from making it to its done callback)."""
    from sm_bt.ros.runtime import RosRuntime

    times: dict[str, list[float]] = {kind: [] for kind in KINDS}
    runtime = RosRuntime(model)
    try:
        manager = runtime.manager
        runtime.wait_for_nodes(TIMEOUT, names)
        freeze_garbage()  # as sm-bt manager does once it is up

        def confirmed(start: Callable[[], Any]) -> float:
            return confirmed_request(manager, start)

        def reset() -> None:  # active to unconfigured, untimed
            confirmed(lambda: manager.change_state(SYSTEM, "deactivate"))
            confirmed(lambda: manager.change_state(SYSTEM, "cleanup"))

        def two() -> float:
            return (confirmed(lambda: manager.change_state(SYSTEM, "configure"))
                    + confirmed(lambda: manager.change_state(SYSTEM, "activate")))

        def one() -> float:
            return confirmed(lambda: manager.change_mode(SYSTEM, "__DEFAULT__"))

        def switch(mode: str) -> float:
            return confirmed(lambda: manager.change_mode(SYSTEM, mode))

        _turns(times, reset, two, one, switch, switches, bring_ups)
    finally:
        runtime.close()
    return times


class _Client(SpunClient):
    """A plain rclpy client of the nodes' ``change_state`` and ``set_parameters_atomically``,
    its node spun by one executor thread throughout."""

    def __init__(self, names: Sequence[str]) -> None:
        from lifecycle_msgs.msg import Transition as TransitionMsg
        from lifecycle_msgs.srv import ChangeState
        from rcl_interfaces.srv import SetParametersAtomically

        from sm_bt.engine.lifecycle import Transition

        self.names = list(names)
        super().__init__("sm_bt_bench_app_client")
        self.change = {n: self.node.create_client(ChangeState, f"/{n}/change_state") for n in names}
        self.set = {n: self.node.create_client(SetParametersAtomically, f"/{n}/set_parameters_atomically")
                    for n in names}
        # Made once, as the manager's backend makes its requests.
        self.requests = {label: ChangeState.Request(transition=TransitionMsg(id=int(Transition[label.upper()]),
                                                                             label=label))
                         for label in ("configure", "activate", "deactivate", "cleanup")}
        self.spin()

    def ready(self) -> None:
        """Wait until every service is discovered (polled: ``wait_for_service`` steps by 0.25 s)."""
        clients = [*self.change.values(), *self.set.values()]
        deadline = time.monotonic() + TIMEOUT
        while not all(client.service_is_ready() for client in clients):
            if time.monotonic() > deadline:
                missing = [c.srv_name for c in clients if not c.service_is_ready()]
                raise RuntimeError(f"services not found within {TIMEOUT:g} s: {', '.join(missing[:3])}")
            time.sleep(0.02)

    def _await(self, send: Callable[[Callable[[str | None], None]], None], expected: int) -> float:
        """Seconds from calling ``send(answered)`` until ``answered`` was called ``expected`` times;
        ``send`` hands ``answered`` to its futures (which may send more calls from it)."""
        lock = threading.Lock()
        remaining = [expected]
        ended: list[float] = []
        failures: list[str] = []
        done = threading.Event()

        def answered(failure: str | None) -> None:
            with lock:
                if failure is not None:
                    failures.append(failure)
                remaining[0] -= 1
                if remaining[0] == 0 or failure is not None:
                    ended.append(time.perf_counter())
                    done.set()

        began = time.perf_counter()
        send(answered)
        if not done.wait(TIMEOUT):
            raise RuntimeError(f"raw rclpy calls not answered within {TIMEOUT:g} s")
        if failures:
            raise RuntimeError(f"raw rclpy call failed: {failures[0]}")
        return ended[0] - began

    def _transition(self, node: str, label: str, then: Callable[[str | None], None]) -> None:
        """Send ``label`` to ``node``; ``then(None)`` on success, ``then(why)`` otherwise."""
        request = self.requests[label]

        def answered(future: Any) -> None:
            error = future.exception()
            then(None if error is None and future.result().success else f"{label} {node}: {error or 'refused'}")

        self.change[node].call_async(request).add_done_callback(answered)

    def transition(self, label: str) -> float:
        """Every node at once; seconds until the last answer."""
        def send(answered: Callable[[str | None], None]) -> None:
            for node in self.names:
                self._transition(node, label, answered)
        return self._await(send, len(self.names))

    def chains(self, labels: Sequence[str]) -> float:
        """One chain of transitions per node (each sent when the node's previous one is answered),
        all nodes at once; seconds until the last chain ends."""
        def send(answered: Callable[[str | None], None]) -> None:
            def step(node: str, index: int, failure: str | None) -> None:
                if failure is not None or index == len(labels):
                    answered(failure)
                else:
                    self._transition(node, labels[index], lambda why: step(node, index + 1, why))
            for node in self.names:
                step(node, 0, None)
        return self._await(send, len(self.names))

    def parameters(self, values: dict[str, dict[str, Any]]) -> float:
        """``set_parameters_atomically`` of ``values[node]`` to every node at once."""
        from rcl_interfaces.srv import SetParametersAtomically

        from sm_bt.ros.parameters import to_parameters

        requests = {n: SetParametersAtomically.Request(parameters=to_parameters(values[n])) for n in self.names}

        def send(answered: Callable[[str | None], None]) -> None:
            def check(node: str, future: Any) -> None:
                error = future.exception()
                answered(None if error is None and future.result().result.successful
                         else f"set_parameters {node}: {error or future.result().result.reason}")
            for node in self.names:
                self.set[node].call_async(requests[node]).add_done_callback(
                    lambda future, node=node: check(node, future))
        return self._await(send, len(self.names))



def _client_times(names: Sequence[str], values: dict[str, dict[str, dict[str, Any]]], switches: int,
                  bring_ups: int) -> dict[str, list[float]]:
    """The same changes made by a plain rclpy client (see :class:`_Client`)."""
    times: dict[str, list[float]] = {kind: [] for kind in KINDS}
    client = _Client(names)
    try:
        client.ready()
        freeze_garbage()  # as the manager's side does: no full collection lands on a sample

        def reset() -> None:
            client.transition("deactivate")
            client.transition("cleanup")

        def two() -> float:
            return client.transition("configure") + client.transition("activate")

        def one() -> float:
            return client.chains(("configure", "activate"))

        def switch(mode: str) -> float:
            return client.parameters(values[mode])

        _turns(times, reset, two, one, switch, switches, bring_ups)
    finally:
        client.close()
    return times


def _turns(times: dict[str, list[float]], reset: Callable[[], None], two: Callable[[], float],
           one: Callable[[], float], switch: Callable[[str], float], switches: int, bring_ups: int) -> None:
    """The same sequence for either side, from every node active in ``__DEFAULT__`` back to there."""
    reset()  # one of each untimed: first calls of a kind cost more (type support, connections)
    one()
    reset()
    two()
    switch("FAST")
    switch("__DEFAULT__")
    for _ in range(bring_ups):
        reset()
        times["two"].append(two())
        reset()
        times["one"].append(one())
    for index in range(switches):
        times["switch"].append(switch("FAST" if index % 2 == 0 else "__DEFAULT__"))
    if switches % 2:
        switch("__DEFAULT__")


def run(quick: bool) -> list[Figure]:
    from sm_bt.ros.environment import prepare, require_ros

    prepare(own_domain=True)
    require_ros()
    from sm_bt.model.loader import load_model
    from sm_bt.ros.node_process import NodesProcess

    count, switches, bring_ups, rounds = (3, 4, 2, 2) if quick else (20, SWITCHES, BRING_UPS, ROUNDS)
    mine: dict[str, list[float]] = {kind: [] for kind in KINDS}
    base: dict[str, list[float]] = {kind: [] for kind in KINDS}
    by_round: dict[str, list[float]] = {kind: [] for kind in KINDS}
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-ros-app-") as tmp:
        path = Path(tmp) / "bench_ros_app.yaml"
        path.write_text(model_text(count))
        model = load_model(path)
        names = [f"bench_n{i}" for i in range(count)]
        values = mode_values(model, names)
        process = NodesProcess(str(path), "--state", "active").start()  # with the default mode's values
        try:
            for index in range(rounds):
                got: dict[bool, dict[str, list[float]]] = {}
                for manager_side in (True, False) if index % 2 == 0 else (False, True):
                    got[manager_side] = (_manager_times(model, names, switches, bring_ups) if manager_side
                                         else _client_times(names, values, switches, bring_ups))
                for kind in KINDS:
                    mine[kind] += got[True][kind]
                    base[kind] += got[False][kind]
                    by_round[kind].append(round(statistics.median(got[True][kind])
                                                / statistics.median(got[False][kind]), 2))
        finally:
            process.stop()
    figures = []
    for kind, label in (("switch", "(a) mode switch setting parameters"),
                        ("two", "(b) bring-up as configure + activate"),
                        ("one", "(c) bring-up as one change_mode")):
        ours, floor = statistics.median(mine[kind]), statistics.median(base[kind])
        figures.append(Figure("P1 app", f"{label}, {count} nodes / raw rclpy in the same process", ours / floor, "x",
                              P1_GOAL, details={"sm_bt_ms": round(ours * 1e3, 2), "baseline_ms": round(floor * 1e3, 2),
                                                "repeats": len(mine[kind]), "nodes": count,
                                                "round_ratios": by_round[kind]}))
    return figures
