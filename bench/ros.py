"""P1, P2 and idle: the manager over real ROS 2 against raw rclpy calls, in the same run.

One child process runs 20 rclpy lifecycle nodes (``sm-bt sim-nodes``) of a model
made here: one system ``robot`` of 20 nodes, 5 parameters each, two modes that differ in all of
them. This process holds the embedded manager (``RosRuntime``, serving the system_modes interface)
and a plain rclpy client in a process of its own: the baseline. The baseline's executors spin only while
it works (its calls, or listening to a switch of the manager's for P2): the manager's answers reach
every client of a service and would wake it, and on two cores the instrument's work competes with
the manager's.

* P1: a confirmed reconfiguration through the manager (the request is done and succeeded),
  against the same ``set_parameters_atomically``/``change_state`` calls made by the plain client
  to all nodes at once and awaited; (a) a mode switch, (b) bring-up as two requests (configure,
  activate), (c) bring-up as one ``change_mode`` from unconfigured. Manager and baseline take turns,
  each bringing up from a shutdown it made itself; the figure is the ratio of medians. The
  manager runs with rules and recovery off, so that the baseline's calls (which move the nodes
  behind its back) are not undone.
* P2: from the node event that completes a mode switch (the last ``/parameter_events`` message
  of the nodes, as the client receives it) to the system's ``mode_event`` from the manager.
* Idle: CPU of an ``sm-bt manager`` process over the 20 idle nodes, and the time it takes the
  embedded manager to see a node vanish when the nodes' process is killed.
"""

from __future__ import annotations

import functools
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.figures import Figure
from bench.ros_baseline import SYSTEM, TIMEOUT, BaselineProcess, freeze_garbage, mode_values, wait_for
from sm_bt.engine.events import EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.model.states import State
from sm_bt.ros.node_process import stop_process

P1_GOAL, P2_GOAL_MS, IDLE_GOAL, VANISH_GOAL = 1.25, 10.0, 1.0, 1.0
#: A rollback of a failed change, against the change itself (issue 32).
ROLLBACK_GOAL = 1.5


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

    # Bring-ups vary widely from one to the next on a shared machine (12-60 ms for the baseline's):
    # 100 turns put the ratio of medians within about 0.03 (bootstrap); switches keep 40 turns.
    count, bring_ups, switches, idle_window = (3, 2, 2, 2.0) if quick else (20, 100, 40, 20.0)
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-ros-") as tmp:
        path = Path(tmp) / "bench_ros.yaml"
        path.write_text(model_text(count))
        model = load_model(path)
        names = [f"bench_n{i}" for i in range(count)]
        values = mode_values(model, names)
        process = NodesProcess(str(path), "--state", "unconfigured").start()
        baseline: BaselineProcess | None = None
        runtime: Any = None
        try:
            # Idle first, with only the nodes and that manager running (no other client of the nodes).
            idle = _idle_cpu(path, idle_window)
            baseline = BaselineProcess(path, names)
            runtime = RosRuntime(model, manager_options={"rules": False, "recovery": False})
            manager = runtime.manager
            wait_for(lambda: all(manager.observation(n).reachable for n in names), "the manager sees every node")
            freeze_garbage()  # as sm-bt manager does once it is up
            figures += _p1_p2(baseline, manager, values, bring_ups, switches, count)
            figures += _rollback(runtime, manager, names, 4 if quick else 20)
            figures.append(Figure("idle", f"manager process CPU, {count} idle nodes", idle,
                                  "% of a core", IDLE_GOAL, details={"window_s": idle_window}))
            began = time.perf_counter()
            process.kill()
            detected = wait_for(lambda: not manager.observation(names[0]).reachable, "vanish detected", 30.0)
            figures.append(Figure("idle", "vanished node detected after the process was killed",
                                  detected, "s", VANISH_GOAL, details={"killed_at": began}))
        finally:
            if runtime is not None:
                runtime.close()
            if baseline is not None:
                baseline.close()
            process.stop()
    return figures


def _done(request: Any) -> bool:
    return bool(request.done)


def _rollback(runtime: Any, manager: ModeManager, names: list[str], turns: int) -> list[Figure]:
    """A mode switch of every node, and the same switch failing on one node's parameter set and
    rolled back: the rollback request's own time against the switch's (each request's elapsed,
    as the manager times it), medians of ``turns`` each."""
    rollbacks: list[float] = []
    subscription = manager.subscribe(lambda event: rollbacks.append(event.request.elapsed or 0.0)
                                     if event.request is not None and event.request.requester == "rollback"
                                     and event.request.done else None, kinds=[EventKind.REQUEST])
    switched: list[float] = []
    try:
        for turn in range(turns):
            _confirmed(manager, lambda: manager.change_mode(SYSTEM, "__DEFAULT__"))
            request = manager.change_mode(SYSTEM, "FAST")
            wait_for(functools.partial(_done, request), "the switch ends")
            switched.append(request.elapsed or 0.0)
            _confirmed(manager, lambda: manager.change_mode(SYSTEM, "__DEFAULT__"))
            failing = names[turn % len(names)]
            runtime.set_parameters(failing, {"sim.reject_parameters": "busy"})
            failed = manager.change_mode(SYSTEM, "FAST", on_failure="rollback")
            wait_for(functools.partial(_done, failed), "the failed switch is rolled back")
            runtime.set_parameters(failing, {"sim.reject_parameters": ""})
            if not failed.reason.startswith("rolled back: "):
                raise RuntimeError(f"not rolled back: {failed.reason}")
    finally:
        subscription.cancel()
    mine, base = statistics.median(rollbacks), statistics.median(switched)
    return [Figure("rollback", f"rollback of a failed {len(names)}-node mode switch / the switch", mine / base, "x",
                   ROLLBACK_GOAL, details={"rollback_ms": round(mine * 1e3, 1), "switch_ms": round(base * 1e3, 1),
                                           "turns": turns})]


class Turns:
    """The steps of the manager's and the baseline's turns over the same nodes, and their times
    (seconds, by kind: ``switch``, ``switch_baseline``, ``two``, ``one``, ``bring_baseline``) and P2
    delays. A baseline step leaves the nodes where the manager has seen them (untimed)."""

    def __init__(self, baseline: BaselineProcess, manager: ModeManager,
                 values: dict[str, dict[str, dict[str, Any]]], count: int) -> None:
        self.baseline, self.manager, self.values, self.count = baseline, manager, values, count
        self.times: dict[str, list[float]] = {key: [] for key in ("switch", "switch_baseline", "two", "one",
                                                                  "bring_baseline")}
        self.delays: list[float] = []

    def seen(self, state: State) -> None:
        """Untimed: the baseline moved the nodes behind the manager's back; let it see where they are."""
        wait_for(lambda: all(self.manager.observation(n).state is state for n in self.baseline.nodes),
                 f"manager sees {state.label}")

    def baseline_reset(self) -> None:  # every node unconfigured, with the __DEFAULT__ values (untimed)
        self.baseline.transition("deactivate")
        self.baseline.transition("cleanup")
        self.seen(State.UNCONFIGURED)

    def manager_reset(self) -> None:  # the same, through the manager (untimed)
        _confirmed(self.manager, lambda: self.manager.change_state(SYSTEM, "deactivate"))
        _confirmed(self.manager, lambda: self.manager.change_state(SYSTEM, "cleanup"))

    def baseline_bring_up(self) -> float:
        elapsed = self.baseline.transition("configure") + self.baseline.transition("activate")
        self.seen(State.ACTIVE)
        return elapsed

    def manager_two(self) -> float:
        return (_confirmed(self.manager, lambda: self.manager.change_state(SYSTEM, "configure"))
                + _confirmed(self.manager, lambda: self.manager.change_state(SYSTEM, "activate")))

    def manager_one(self) -> float:
        return _confirmed(self.manager, lambda: self.manager.change_mode(SYSTEM, "__DEFAULT__"))

    def manager_to(self, mode: str) -> None:
        self.baseline.clear()
        self.times["switch"].append(_confirmed(self.manager, lambda: self.manager.change_mode(SYSTEM, mode)))
        last_node_event, system_event = self.baseline.switch_events(self.count, mode)
        self.delays.append(system_event - last_node_event)

    def baseline_to(self, mode: str) -> None:
        self.times["switch_baseline"].append(self.baseline.parameters(mode))
        wait_for(lambda: all(self.manager.observation(n).parameters == self.values[mode][n]
                             for n in self.baseline.nodes), "manager sees the baseline's values")

    def baseline_bring_ups(self, samples: int, *, reset_last: bool = True) -> None:
        """The baseline's part of a bring-up turn: an untimed bring-up and shutdown first (either side
        is measurably slower, by up to 1-2 ms of its 15-20, right after the other side made the
        calls), then ``samples`` timed bring-ups, each shut down again (the last only if
        ``reset_last``)."""
        self.baseline.wake()
        self.baseline_bring_up()
        self.baseline_reset()
        for index in range(samples):
            self.times["bring_baseline"].append(self.baseline_bring_up())
            if reset_last or index < samples - 1:
                self.baseline_reset()
        self.baseline.rest()

    def switch_turn(self) -> None:
        """The manager there and back, then the baseline there and back (the nodes end where the
        manager's target wants them, so its next switch is a real one and publishes mode_event)."""
        self.manager_to("FAST")
        self.manager_to("__DEFAULT__")
        self.baseline.wake()
        self.baseline_to("FAST")
        self.baseline_to("__DEFAULT__")
        self.baseline.rest()


def _p1_p2(baseline: BaselineProcess, manager: ModeManager, values: dict[str, dict[str, dict[str, Any]]],
           bring_ups: int, switches: int, count: int) -> list[Figure]:
    turns = Turns(baseline, manager, values, count)
    times, delays = turns.times, turns.delays
    manager_one, manager_two, manager_reset = turns.manager_one, turns.manager_two, turns.manager_reset

    # Bring-up, each in turn from a shutdown it made itself, as in use (a manager's targets then
    # agree with the nodes): a turn starts with an untimed bring-up and shutdown. The last leaves
    # the nodes up for the switches.
    for index in range(bring_ups):
        manager_one()
        manager_reset()
        times["two"].append(manager_two())
        manager_reset()
        times["one"].append(manager_one())
        manager_reset()
        turns.baseline_bring_ups(2, reset_last=index != bring_ups - 1)
    for _ in range(switches):
        turns.switch_turn()

    def ratio(ours: str, baseline_key: str) -> tuple[float, dict[str, Any]]:
        mine, base = statistics.median(times[ours]), statistics.median(times[baseline_key])
        return mine / base, {"sm_bt_ms": round(mine * 1e3, 1), "baseline_ms": round(base * 1e3, 1),
                             "repeats": len(times[ours]), "nodes": count}

    figures = []
    for key, baseline_key, label in (("switch", "switch_baseline", "(a) mode switch setting parameters"),
                                  ("two", "bring_baseline", "(b) bring-up as configure + activate"),
                                  ("one", "bring_baseline", "(c) bring-up as one change_mode")):
        value, details = ratio(key, baseline_key)
        figures.append(Figure("P1", f"{label}, {count} nodes / raw rclpy", value, "x", P1_GOAL, details=details))
    delays_ms = [d * 1e3 for d in delays]
    figures.append(Figure("P2", "system mode_event after the last node event, median", statistics.median(delays_ms),
                          "ms", P2_GOAL_MS, details={"max_ms": round(max(delays_ms), 2), "samples": len(delays)}))
    figures.append(Figure("P2", "system mode_event after the last node event, max", max(delays_ms), "ms",
                          P2_GOAL_MS, details={"samples": len(delays)}))
    return figures
