"""The baseline of ``bench.ros``: a plain rclpy client, in a process of its own.

``python -m bench.ros_baseline MODEL`` serves commands on stdin (one JSON answer per line); the
benchmark drives it through :class:`BaselineProcess`. Its executors spin only while it works.
"""

from __future__ import annotations

import contextlib
import gc
import json
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any, Literal

from sm_bt.model.types import Model, NodeMode
from sm_bt.ros.cdr import parameter_event_node
from sm_bt.ros.node_process import stop_process

SYSTEM = "robot"
#: Seconds any one wait of the benchmark may take.
TIMEOUT = 20.0

#: How long a resting executor of the baseline spins before it is used: it takes what came meanwhile
#: (the manager's answers reach every client of a service, and wake its executor) first.
DRAIN = 0.03


class SpunClient:
    """A plain rclpy node of a context of its own, spun by one ``SingleThreadedExecutor`` thread from
    :meth:`spin` on (once its subscriptions and clients are made) until :meth:`close`: the bench's
    clients of the nodes and of the managers."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.signals import SignalHandlerOptions

        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(name, context=self.context)
        self._stopping = threading.Event()
        self._thread: threading.Thread | None = None

    def spin(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, name=f"{self.node.get_name()}-spin", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        # spin_once in a loop rather than spin(): shutting an executor down under spin() can fail
        # in its thread (see sm_bt.ros.runtime._Spinner).
        while not self._stopping.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        self._stopping.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self.executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        self.context.try_shutdown()


class _Spinner:
    """An executor spun by a thread of its own while it is awake. The baseline's executors rest while
    the manager is measured: the instrument's work competes with the manager for two cores."""

    def __init__(self, executor: Any, name: str) -> None:
        self.executor = executor
        self._awake = threading.Event()
        self._closed = False
        self._thread = threading.Thread(target=self._spin, daemon=True, name=name)
        self._thread.start()

    def _spin(self) -> None:
        while not self._closed:
            if self._awake.is_set():
                self.executor.spin_once(timeout_sec=0.05)
            else:
                self._awake.wait(0.1)

    def wake(self) -> None:
        """Spin again, and take what came while resting (callbacks run for it) before returning."""
        self._awake.set()
        time.sleep(DRAIN)

    def rest(self) -> None:
        self._awake.clear()

    @property
    def awake(self) -> bool:
        return self._awake.is_set()

    def close(self) -> None:
        self._closed = True
        self._awake.set()
        self._thread.join(2.0)
        self.executor.shutdown(timeout_sec=2.0)


class _Baseline:
    """A plain rclpy client: calls every node at once and waits for every answer. Its calls and its
    listening (to the nodes' and the manager's events, for P2) are two nodes with an executor each,
    each awake only when needed."""

    def __init__(self, nodes: Sequence[str]) -> None:
        import rclpy
        from lifecycle_msgs.srv import ChangeState
        from rcl_interfaces.msg import ParameterEvent
        from rcl_interfaces.srv import SetParametersAtomically
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_parameter_events
        from rclpy.signals import SignalHandlerOptions
        from system_modes_msgs.msg import ModeEvent

        self.context = Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("sm_bt_bench_baseline", context=self.context)
        self.listener = rclpy.create_node("sm_bt_bench_baseline_listener", context=self.context)
        self.calls = _Spinner(SingleThreadedExecutor(context=self.context), "bench-baseline-calls")
        self.calls.executor.add_node(self.node)
        self.listening = _Spinner(SingleThreadedExecutor(context=self.context), "bench-baseline-listener")
        self.listening.executor.add_node(self.listener)
        self.nodes = list(nodes)
        self.change = {n: self.node.create_client(ChangeState, f"/{n}/change_state") for n in nodes}
        self.set = {n: self.node.create_client(SetParametersAtomically, f"/{n}/set_parameters_atomically")
                    for n in nodes}
        self.parameter_events: list[tuple[float, str]] = []  # (receive time, node)
        self.mode_events: list[tuple[float, str]] = []  # (receive time, mode)
        self._since = 0.0  # events stamped before this (time.time()) are old ones
        # Raw: only the node's name and the stamp are read (the instrument's work stays small).
        self.listener.create_subscription(ParameterEvent, "/parameter_events", self._on_parameters,
                                          qos_profile_parameter_events, raw=True)
        self.listener.create_subscription(ModeEvent, f"/{SYSTEM}/mode_event", self._on_mode, 10)

    def switch_events(self, count: int, mode: str) -> tuple[float, float]:
        """Wait for a switch's events: when the last node's (of ``count``) parameter event came,
        and the system's ``mode_event`` for ``mode``."""
        def published() -> bool:
            return len({n for _, n in self.parameter_events}) >= count and any(
                m == mode for _, m in self.mode_events)

        try:
            wait_for(published, "events of the switch", 5.0)
            self.listening.rest()
        except RuntimeError:
            raise RuntimeError(f"events of the switch to {mode}: parameter events from "
                               f"{sorted({n for _, n in self.parameter_events})}, mode events "
                               f"{[m for _, m in self.mode_events]}") from None
        last_node_event = max(t for t, _ in self.parameter_events[:count])  # one message per atomic set
        return last_node_event, min(t for t, m in self.mode_events if m == mode)

    def serve(self, values: dict[str, dict[str, dict[str, Any]]]) -> None:
        """Answer the parent's commands, one per line on stdin, one line each on stdout."""
        print("READY", flush=True)
        for line in sys.stdin:
            command, _, argument = line.strip().partition(" ")
            if command == "transition":
                answer: object = self.transition(argument)
            elif command == "parameters":
                answer = self.parameters(values[argument])
            elif command == "wake":
                self.calls.wake()
                answer = 0
            elif command == "rest":
                self.calls.rest()
                answer = 0
            elif command == "clear":  # a switch of the manager's comes: listen
                self.listening.wake()
                self._since = time.time()
                self.parameter_events.clear()
                self.mode_events.clear()
                answer = 0
            elif command == "switch_events":
                count, mode = argument.split(" ", 1)
                answer = self.switch_events(int(count), mode)
            else:
                break
            print(json.dumps(answer), flush=True)

    def _on_parameters(self, message: bytes) -> None:
        received = time.perf_counter()
        if _event_stamp(message) >= self._since:
            self.parameter_events.append((received, parameter_event_node(message) or "?"))

    def _on_mode(self, message: Any) -> None:
        if message.timestamp * 1e-9 >= self._since:  # ROS time in nanoseconds
            self.mode_events.append((time.perf_counter(), message.goal_mode.label))

    def ready(self) -> None:
        for client in (*self.change.values(), *self.set.values()):
            if not client.wait_for_service(timeout_sec=TIMEOUT):
                raise RuntimeError(f"service {client.srv_name} did not appear within {TIMEOUT:g} s")

    def _all(self, calls: Sequence[tuple[Any, Any]], ok: Callable[[Any], bool]) -> float:
        """Send every ``(client, request)`` at once; seconds until every answer came (all must be ok)."""
        remaining = [len(calls)]
        done = threading.Event()
        failures: list[str] = []

        def answered(future: Any) -> None:
            if future.exception() is not None or not ok(future.result()):
                failures.append(str(future.exception() or future.result()))
            remaining[0] -= 1
            if remaining[0] == 0:
                done.set()

        if not self.calls.awake:
            raise RuntimeError("the baseline's calls are resting: wake them first")
        start = time.perf_counter()
        for client, request in calls:
            client.call_async(request).add_done_callback(answered)
        if not done.wait(TIMEOUT):
            raise RuntimeError("raw rclpy calls not answered in time")
        elapsed = time.perf_counter() - start
        if failures:
            raise RuntimeError(f"raw rclpy calls failed: {failures[0]}")
        return elapsed

    def transition(self, label: str) -> float:
        from lifecycle_msgs.msg import Transition as TransitionMsg
        from lifecycle_msgs.srv import ChangeState

        from sm_bt.engine.lifecycle import Transition

        ids = {t.label: int(t) for t in Transition if int(t) < 10 and t.label != "shutdown"}
        calls = [(self.change[n], ChangeState.Request(transition=TransitionMsg(id=ids[label], label=label)))
                 for n in self.nodes]
        return self._all(calls, lambda response: bool(response.success))

    def parameters(self, values: dict[str, dict[str, Any]]) -> float:
        from rcl_interfaces.srv import SetParametersAtomically

        from sm_bt.ros.parameters import to_parameters

        calls = [(self.set[n], SetParametersAtomically.Request(parameters=to_parameters(values[n])))
                 for n in self.nodes]
        return self._all(calls, lambda response: bool(response.result.successful))

    def close(self) -> None:
        self.calls.close()
        self.listening.close()
        self.node.destroy_node()
        self.listener.destroy_node()
        self.context.try_shutdown()


def _event_stamp(serialized: bytes) -> float:
    """The ``stamp`` of a serialized ``ParameterEvent``, the field before its node's name (see
    :mod:`sm_bt.ros.cdr`): seconds of the nodes' clock, ``time.time()``."""
    order: Literal["little", "big"] = "little" if serialized[1] & 1 else "big"
    return (int.from_bytes(serialized[4:8], order, signed=True)
            + int.from_bytes(serialized[8:12], order) * 1e-9)


class BaselineProcess:
    """The baseline in a process of its own (``python -m bench.ros_baseline PATH``), so that its executor and
    its event handling do not compete with the manager for this interpreter. Its times are
    ``perf_counter`` (CLOCK_MONOTONIC: the same clock in both processes)."""

    def __init__(self, path: Path, nodes: Sequence[str]) -> None:
        self.nodes = list(nodes)
        self.process = subprocess.Popen([sys.executable, "-m", "bench.ros_baseline", str(path)],
                                        cwd=Path(__file__).resolve().parents[1], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if self._line() != "READY":
            raise RuntimeError(f"the baseline process did not start: {self._stderr()}")

    def _line(self) -> str:
        assert self.process.stdout is not None
        return self.process.stdout.readline().strip()

    def _stderr(self) -> str:
        self.process.kill()
        return (self.process.communicate(timeout=5)[1] or "").strip()[-500:]

    def _ask(self, command: str) -> Any:
        assert self.process.stdin is not None
        self.process.stdin.write(command + "\n")
        self.process.stdin.flush()
        line = self._line()
        if not line:
            raise RuntimeError(f"baseline process failed on {command!r}: {self._stderr()}")
        return json.loads(line)

    def transition(self, label: str) -> float:
        return float(self._ask(f"transition {label}"))

    def parameters(self, mode: str) -> float:
        return float(self._ask(f"parameters {mode}"))

    def clear(self) -> None:
        self._ask("clear")

    def wake(self) -> None:
        self._ask("wake")

    def rest(self) -> None:
        self._ask("rest")

    def switch_events(self, count: int, mode: str) -> tuple[float, float]:
        last, system = self._ask(f"switch_events {count} {mode}")
        return float(last), float(system)

    def close(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            assert self.process.stdin is not None
            self.process.stdin.write("quit\n")
            self.process.stdin.close()
        try:
            self.process.wait(5.0)
        except subprocess.TimeoutExpired:
            stop_process(self.process)


def node_values(model: Model, node: str, mode: str) -> dict[str, Any]:
    spec = model.part(node).modes[mode]
    assert isinstance(spec, NodeMode)
    return spec.values()


def mode_values(model: Model, nodes: Iterable[str]) -> dict[str, dict[str, dict[str, Any]]]:
    """mode -> node -> its parameter values, for the benchmarks' two modes."""
    names = list(nodes)
    return {mode: {n: node_values(model, n, mode) for n in names} for mode in ("__DEFAULT__", "FAST")}


def wait_for(condition: Callable[[], bool], what: str, limit: float = TIMEOUT) -> float:
    began = time.perf_counter()
    while not condition():
        if time.perf_counter() - began > limit:
            raise RuntimeError(f"{what}: not within {limit:g} s")
        time.sleep(0.002)
    return time.perf_counter() - began


def confirmed(manager: Any, start: Callable[[], Any], limit: float = TIMEOUT) -> float:
    """Seconds from making a request of ``manager`` (``start()``) to its done callback; it must
    succeed within ``limit`` s (``RuntimeError`` otherwise)."""
    ended: list[float] = []
    done = threading.Event()

    def finished(_request: Any) -> None:
        ended.append(time.perf_counter())
        done.set()

    # Under the manager's lock: the request cannot end between its start and the registration.
    with manager.lock:
        began = time.perf_counter()
        request = start()
        request.add_done_callback(finished)
    if not done.wait(limit):
        raise RuntimeError(f"{request.description} not done in {limit:g} s: {request.feedback}")
    if not request.succeeded:
        raise RuntimeError(f"{request.description} failed: {request.reason}")
    return ended[0] - began


def freeze_garbage() -> None:
    """Keep what the process has made so far out of the garbage collector's passes (``gc.freeze()``):
    a full pass over a ROS process's objects takes 20-50 ms here, and lands on a measurement."""
    gc.collect()
    gc.freeze()


def _baseline_main(path: str) -> int:
    """The baseline's process: ``python -m bench.ros_baseline MODEL`` (see :class:`BaselineProcess`)."""
    from sm_bt.model.loader import load_model

    model = load_model(path)
    names = [part.name for part in model.nodes]
    values = mode_values(model, names)
    baseline = _Baseline(names)
    try:
        baseline.ready()
        freeze_garbage()  # the instrument's own collections stay out of its figures
        baseline.serve(values)
    finally:
        baseline.close()
    return 0


if __name__ == "__main__":
    sys.exit(_baseline_main(sys.argv[1]))

