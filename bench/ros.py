"""P1, P2 and idle: the manager over real ROS 2 against raw rclpy calls, in the same run.

One child process runs 20 rclpy lifecycle nodes (``sm-bt sim-nodes``) of a model
made here: one system ``robot`` of 20 nodes, 5 parameters each, two modes that differ in all of
them. This process holds the embedded manager (``RosRuntime``, serving the system_modes interface)
and a plain rclpy client in a process of its own: the floor. The floor's executors spin only while
it works (its calls, or listening to a switch of the manager's for P2): the manager's answers reach
every client of a service and would wake it, and on two cores the instrument's work competes with
the manager's.

* P1: a confirmed reconfiguration through the manager (the request is done and succeeded),
  against the same ``set_parameters_atomically``/``change_state`` calls made by the plain client
  to all nodes at once and awaited; (a) a mode switch, (b) bring-up as two requests (configure,
  activate), (c) bring-up as one ``change_mode`` from unconfigured. Manager and floor take turns,
  each bringing up from a shutdown it made itself; the figure is the ratio of medians. The
  manager runs with rules and recovery off, so that the floor's calls (which move the nodes
  behind its back) are not undone.
* P2: from the node event that completes a mode switch (the last ``/parameter_events`` message
  of the nodes, as the client receives it) to the system's ``mode_event`` from the manager.
* Idle: CPU of an ``sm-bt manager`` process over the 20 idle nodes, and the time it takes the
  embedded manager to see a node vanish when the nodes' process is killed.
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

from bench.figures import Figure
from sm_bt.engine.manager import ModeManager
from sm_bt.model.states import State
from sm_bt.model.types import Model, NodeMode
from sm_bt.ros.cdr import parameter_event_node
from sm_bt.ros.node_process import stop_process

SYSTEM = "robot"
P1_GOAL, P2_GOAL_MS, IDLE_GOAL, VANISH_GOAL = 1.25, 10.0, 1.0, 1.0
TIMEOUT = 20.0


def model_text(nodes: int) -> str:
    names = [f"bench_n{i}" for i in range(nodes)]
    out = [f"{SYSTEM}:\n  ros__parameters:\n    type: system\n    parts:\n"]
    out += [f"      {name}\n" for name in names]
    out.append("    modes:\n")
    for mode in ("__DEFAULT__", "FAST"):
        out.append(f"      {mode}:\n" + "".join(f"        {name}: active.{mode}\n" for name in names))
    for index, name in enumerate(names):
        out.append(f"{name}:\n  ros__parameters:\n    type: node\n    modes:\n")
        for scale, mode in enumerate(("__DEFAULT__", "FAST"), start=1):
            out.append(f"      {mode}:\n        ros__parameters:\n"
                       f"          speed: {0.5 * scale + index}\n          rate: {10 * scale}\n"
                       f"          planner: \"{mode.strip('_').lower()}\"\n"
                       f"          enabled: {'true' if scale == 2 else 'false'}\n"
                       f"          tolerance: {0.1 * scale}\n")
    return "".join(out)


#: How long a resting executor of the floor spins before it is used: it takes what came meanwhile
#: (the manager's answers reach every client of a service, and wake its executor) first.
DRAIN = 0.03


class _Spinner:
    """An executor spun by a thread of its own while it is awake. The floor's executors rest while
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


class _Floor:
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
        self.node = rclpy.create_node("sm_bt_bench_floor", context=self.context)
        self.listener = rclpy.create_node("sm_bt_bench_floor_listener", context=self.context)
        self.calls = _Spinner(SingleThreadedExecutor(context=self.context), "bench-floor-calls")
        self.calls.executor.add_node(self.node)
        self.listening = _Spinner(SingleThreadedExecutor(context=self.context), "bench-floor-listener")
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
            _wait(published, "events of the switch", 5.0)
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
            raise RuntimeError("the floor's calls are resting: wake them first")
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


class _FloorProcess:
    """The floor in a process of its own (``python -m bench.ros PATH``), so that its executor and
    its event handling do not compete with the manager for this interpreter. Its times are
    ``perf_counter`` (CLOCK_MONOTONIC: the same clock in both processes)."""

    def __init__(self, path: Path, nodes: Sequence[str]) -> None:
        self.nodes = list(nodes)
        self.process = subprocess.Popen([sys.executable, "-m", "bench.ros", str(path)],
                                        cwd=Path(__file__).resolve().parents[1], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if self._line() != "READY":
            raise RuntimeError(f"the floor process did not start: {self._stderr()}")

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
            raise RuntimeError(f"floor process failed on {command!r}: {self._stderr()}")
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


def _node_values(model: Model, node: str, mode: str) -> dict[str, Any]:
    spec = model.part(node).modes[mode]
    assert isinstance(spec, NodeMode)
    return spec.values()


def _confirmed(runtime: Any, start: Callable[[], Any]) -> float:
    """Seconds from making the manager request to its being done; it must have succeeded."""
    done = threading.Event()
    began = time.perf_counter()
    request = start()
    request.add_done_callback(lambda _request: done.set())
    if not done.wait(TIMEOUT):
        raise RuntimeError(f"{request.description} not done in {TIMEOUT:g} s: {request.feedback}")
    elapsed = time.perf_counter() - began
    if not request.succeeded:
        raise RuntimeError(f"{request.description} failed: {request.reason}")
    return elapsed


def _wait(condition: Callable[[], bool], what: str, limit: float = TIMEOUT) -> float:
    began = time.perf_counter()
    while not condition():
        if time.perf_counter() - began > limit:
            raise RuntimeError(f"{what}: not within {limit:g} s")
        time.sleep(0.002)
    return time.perf_counter() - began


def _freeze_garbage() -> None:
    """Keep what the process has made so far out of the garbage collector's passes (``gc.freeze()``):
    a full pass over a ROS process's objects takes 20-50 ms here, and lands on a measurement."""
    gc.collect()
    gc.freeze()


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _idle_cpu(path: Path, seconds: float) -> float:
    """Percent of one core an ``sm-bt manager`` process uses over the idle nodes."""
    manager = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "manager", str(path), "--log-level", "warning"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(5.0)  # start-up and discovery are not idle
        if manager.poll() is not None:
            raise RuntimeError(f"sm-bt manager exited: {manager.stderr.read()[-500:] if manager.stderr else ''}")
        before, began = _cpu_seconds(manager.pid), time.perf_counter()
        time.sleep(seconds)
        return 100 * (_cpu_seconds(manager.pid) - before) / (time.perf_counter() - began)
    finally:
        stop_process(manager)


def run(quick: bool) -> list[Figure]:
    from sm_bt.ros.environment import prepare, require_ros

    prepare(own_domain=True)
    require_ros()
    from sm_bt.model.loader import load_model
    from sm_bt.ros.node_process import NodesProcess
    from sm_bt.ros.runtime import RosRuntime

    # Bring-ups vary widely from one to the next on a shared machine (12-60 ms for the floor's):
    # 100 turns put the ratio of medians within about 0.03 (bootstrap); switches keep 40 turns.
    count, bring_ups, switches, idle_window = (3, 2, 2, 2.0) if quick else (20, 100, 40, 20.0)
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-ros-") as tmp:
        path = Path(tmp) / "bench_ros.yaml"
        path.write_text(model_text(count))
        model = load_model(path)
        names = [f"bench_n{i}" for i in range(count)]
        values = {mode: {n: _node_values(model, n, mode) for n in names} for mode in ("__DEFAULT__", "FAST")}
        process = NodesProcess(str(path), "--state", "unconfigured").start()
        floor: _FloorProcess | None = None
        runtime: Any = None
        try:
            # Idle first, with only the nodes and that manager running (no other client of the nodes).
            idle = _idle_cpu(path, idle_window)
            floor = _FloorProcess(path, names)
            runtime = RosRuntime(model, manager_options={"rules": False, "recovery": False})
            manager = runtime.manager
            _wait(lambda: all(manager.observation(n).reachable for n in names), "the manager sees every node")
            _freeze_garbage()  # as sm-bt manager does once it is up
            figures += _p1_p2(floor, manager, values, bring_ups, switches, count)
            figures.append(Figure("idle", f"manager process CPU, {count} idle nodes", idle,
                                  "% of a core", IDLE_GOAL, details={"window_s": idle_window}))
            began = time.perf_counter()
            process.kill()
            detected = _wait(lambda: not manager.observation(names[0]).reachable, "vanish detected", 30.0)
            figures.append(Figure("idle", "vanished node detected after the process was killed",
                                  detected, "s", VANISH_GOAL, details={"killed_at": began}))
        finally:
            if runtime is not None:
                runtime.close()
            if floor is not None:
                floor.close()
            process.stop()
    return figures


def _p1_p2(floor: _FloorProcess, manager: ModeManager, values: dict[str, dict[str, dict[str, Any]]], bring_ups: int,
           switches: int, count: int) -> list[Figure]:
    times: dict[str, list[float]] = {key: [] for key in ("switch", "switch_floor", "two", "one", "bring_floor")}
    delays: list[float] = []

    def seen(state: State) -> None:
        """Untimed: the floor moved the nodes behind the manager's back; let it see where they are."""
        _wait(lambda: all(manager.observation(n).state is state for n in floor.nodes), f"manager sees {state.label}")

    def floor_reset() -> None:  # every node unconfigured, with the __DEFAULT__ values (untimed)
        floor.transition("deactivate")
        floor.transition("cleanup")
        seen(State.UNCONFIGURED)

    def manager_reset() -> None:  # the same, through the manager (untimed)
        _confirmed(manager, lambda: manager.change_state(SYSTEM, "deactivate"))
        _confirmed(manager, lambda: manager.change_state(SYSTEM, "cleanup"))

    def floor_bring_up() -> float:
        elapsed = floor.transition("configure") + floor.transition("activate")
        seen(State.ACTIVE)
        return elapsed

    def manager_two() -> float:
        return (_confirmed(manager, lambda: manager.change_state(SYSTEM, "configure"))
                + _confirmed(manager, lambda: manager.change_state(SYSTEM, "activate")))

    def manager_one() -> float:
        return _confirmed(manager, lambda: manager.change_mode(SYSTEM, "__DEFAULT__"))

    # Bring-up, each in turn from a shutdown it made itself, as in use (a manager's targets then
    # agree with the nodes; either side is measurably slower, by up to 1-2 ms of its 15-20, right
    # after the other side made the calls): a turn starts with an untimed bring-up and shutdown.
    for index in range(bring_ups):
        manager_one()
        manager_reset()
        times["two"].append(manager_two())
        manager_reset()
        times["one"].append(manager_one())
        manager_reset()
        floor.wake()
        floor_bring_up()
        floor_reset()
        times["bring_floor"].append(floor_bring_up())
        floor_reset()
        times["bring_floor"].append(floor_bring_up())
        if index != bring_ups - 1:
            floor_reset()
        floor.rest()

    def manager_to(mode: str) -> None:
        floor.clear()
        times["switch"].append(_confirmed(manager, lambda: manager.change_mode(SYSTEM, mode)))
        last_node_event, system_event = floor.switch_events(count, mode)
        delays.append(system_event - last_node_event)

    def floor_to(mode: str) -> None:
        times["switch_floor"].append(floor.parameters(mode))
        _wait(lambda: all(manager.observation(n).parameters == values[mode][n] for n in floor.nodes),
              "manager sees the floor's values")

    # Mode switches: the manager there and back, then the floor there and back (the nodes end where
    # the manager's target wants them, so its next switch is a real one and publishes mode_event).
    for _ in range(switches):
        manager_to("FAST")
        manager_to("__DEFAULT__")
        floor.wake()
        floor_to("FAST")
        floor_to("__DEFAULT__")
        floor.rest()

    def ratio(ours: str, floor_key: str) -> tuple[float, dict[str, Any]]:
        mine, base = statistics.median(times[ours]), statistics.median(times[floor_key])
        return mine / base, {"sm_bt_ms": round(mine * 1e3, 1), "floor_ms": round(base * 1e3, 1),
                             "repeats": len(times[ours]), "nodes": count}

    figures = []
    for key, floor_key, label in (("switch", "switch_floor", "(a) mode switch setting parameters"),
                                  ("two", "bring_floor", "(b) bring-up as configure + activate"),
                                  ("one", "bring_floor", "(c) bring-up as one change_mode")):
        value, details = ratio(key, floor_key)
        figures.append(Figure("P1", f"{label}, {count} nodes / raw rclpy", value, "x", P1_GOAL, details=details))
    delays_ms = [d * 1e3 for d in delays]
    figures.append(Figure("P2", "system mode_event after the last node event, median", statistics.median(delays_ms),
                          "ms", P2_GOAL_MS, details={"max_ms": round(max(delays_ms), 2), "samples": len(delays)}))
    figures.append(Figure("P2", "system mode_event after the last node event, max", max(delays_ms), "ms",
                          P2_GOAL_MS, details={"samples": len(delays)}))
    return figures


def _floor_main(path: str) -> int:
    """The floor's process: ``python -m bench.ros MODEL`` (see :class:`_FloorProcess`)."""
    from sm_bt.model.loader import load_model

    model = load_model(path)
    names = [part.name for part in model.nodes]
    values = {mode: {n: _node_values(model, n, mode) for n in names} for mode in ("__DEFAULT__", "FAST")}
    floor = _Floor(names)
    try:
        floor.ready()
        _freeze_garbage()  # the instrument's own collections stay out of its figures
        floor.serve(values)
    finally:
        floor.close()
    return 0


if __name__ == "__main__":
    sys.exit(_floor_main(sys.argv[1]))
