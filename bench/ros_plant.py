"""P1, P2 and idle at plant size: 200 rclpy lifecycle nodes in 10 processes, against raw rclpy.

The shape of a large robot or a small fleet: a model made here, one top system ``robot`` of 10
subsystems (``sub0`` ... ``sub9``) of 20 nodes each, 5 parameters per node, two modes that differ
in all of them; each subsystem's nodes run in a ``sm-bt sim-nodes --only`` process of their own.
The method is :mod:`bench.ros`'s (its helpers, and :mod:`bench.ros_baseline`'s plain rclpy client
in a process of its own, used as they are); what differs is said here.

In order: the 10 node processes start (at once); the embedded manager (``RosRuntime`` serving the
system_modes interface, as ``sm-bt manager`` does, with its receive room; rules and recovery off,
since the baseline moves the nodes behind its back) is made and finds every node; the baseline
starts; then everything waits until the node and baseline processes are quiet: each new DDS
entity is news to every participant, and a participant of thousands keeps the others busy for
seconds after it is made.

* P1: a confirmed request of the manager against the same ``set_parameters_atomically`` /
  ``change_state`` calls sent by the baseline to all 200 nodes at once and awaited: (a) a
  whole-system mode switch, (c) bring-up as one ``change_mode`` from unconfigured (the baseline:
  configure all, then activate all). Each side brings up from a shutdown it made itself, after an
  untimed bring-up and shutdown of its own; the figure is the ratio of medians. A turn that fails
  (a node reported vanished, most often) is counted, with its reason, as a figure with goal 0;
  the nodes are brought back through the manager and the turns go on (after ``MAX_FAILED``
  failures they stop: the figures are then those of the turns done).
* P2: from the last of the 200 nodes' ``/parameter_events`` messages of a switch, as the
  baseline's process receives it, to the ``mode_event`` of ``robot`` from the manager.
* Idle: CPU of this process, which holds nothing but the manager, over the idle nodes with all 10
  processes up and watched, before the baseline's process is started (as bench/ros.py measures
  with only the nodes running); bench/ros.py starts an ``sm-bt manager`` process instead, but at this size a
  manager takes 35-50 s to make and as long to close (its figures below), so it is made once.
  Then one node process is killed: the time until the manager reports all its nodes vanished.
* Discovery (no goal): seconds from the manager's construction until it has every node, with
  the other start-up and the closing times in its details.

The run takes 3-5 minutes on 2 cores, most of it the manager's making and closing. The baseline is
raw rclpy with Fast DDS's defaults; the manager has ``sm-bt manager``'s receive room (without it,
answers and events overflowed its shared-memory port in a change and came 3 s late:
docs/ros-interface.md, "Receive room").
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from bench.figures import Figure
from bench.ros import P1_GOAL, P2_GOAL_MS, VANISH_GOAL, Turns, _cpu_seconds
from bench.ros_baseline import SYSTEM, BaselineProcess, freeze_garbage, mode_values, wait_for
from sm_bt.engine.manager import ModeManager
from sm_bt.ros.node_process import NodesProcess

#: The plant goal for the idle manager (bench/ros.py's 1 % is for 20 nodes in one process).
IDLE_GOAL = 2.0
MODES = ("__DEFAULT__", "FAST")
#: Seconds to start the node processes (all at once, on two cores) and to discover 200 nodes.
START_LIMIT, DISCOVERY_LIMIT = 90.0, 90.0
#: The node processes are quiet below this percent of a core, together, over this many seconds.
QUIET, QUIET_WINDOW = 10.0, 1.0
#: Turns that may fail (each is counted and reported) before the run gives up.
MAX_FAILED = 3


def groups(processes: int, per_process: int) -> list[list[str]]:
    """The nodes of each process (and subsystem): ``bench_n0`` ... in order."""
    return [[f"bench_n{k * per_process + i}" for i in range(per_process)] for k in range(processes)]


def _system(name: str, parts: list[str]) -> str:
    out = [f"{name}:\n  ros__parameters:\n    type: system\n    parts:\n", *(f"      {p}\n" for p in parts),
           "    modes:\n"]
    for mode in MODES:
        out.append(f"      {mode}:\n" + "".join(f"        {p}: active.{mode}\n" for p in parts))
    return "".join(out)


def model_text(nodes: list[list[str]]) -> str:
    """``robot`` of one subsystem per process; every node as bench/ros.py's (all 5 parameters differ)."""
    subsystems = [f"sub{k}" for k in range(len(nodes))]
    out = [_system(SYSTEM, subsystems), *(_system(s, names) for s, names in zip(subsystems, nodes, strict=True))]
    for index, name in enumerate(n for names in nodes for n in names):
        out.append(f"{name}:\n  ros__parameters:\n    type: node\n    modes:\n")
        for scale, mode in enumerate(MODES, start=1):
            out.append(f"      {mode}:\n        ros__parameters:\n"
                       f"          speed: {0.5 * scale + index}\n          rate: {10 * scale}\n"
                       f"          planner: \"{mode.strip('_').lower()}\"\n"
                       f"          enabled: {'true' if scale == 2 else 'false'}\n"
                       f"          tolerance: {0.1 * scale}\n")
    return "".join(out)


def _start(processes: list[NodesProcess]) -> None:
    """Start every node process at once (one after the other took about as long each, on 2 cores);
    each start is bounded by its ``ready_timeout``. The first failure is raised once all are done."""
    with ThreadPoolExecutor(len(processes)) as pool:
        errors = [error for error in pool.map(start_one, processes) if error is not None]
    if errors:
        raise errors[0]


def start_one(process: NodesProcess) -> BaseException | None:
    """Start ``process``: the error its start raised, or ``None``."""
    try:
        process.start()
    except BaseException as error:  # returned: one failure must not hide the others' state
        return error
    return None


def _stop(processes: list[NodesProcess]) -> None:
    """SIGINT, grace, SIGKILL (NodesProcess.stop), all at once: one by one adds up to 30 s."""
    with ThreadPoolExecutor(len(processes)) as pool:
        list(pool.map(lambda process: process.stop(), processes))


def _cpu(pids: list[int]) -> float:
    return sum(_cpu_seconds(pid) for pid in pids)


def _quiet(pids: list[int], limit: float) -> float:
    """Wait until the processes ``pids`` together use less than ``QUIET`` % of a core over
    ``QUIET_WINDOW`` s (bounded by ``limit``); the seconds it took. A participant's new entities keep
    every other participant busy for a while after they are made (see the module's doc)."""
    began = time.perf_counter()
    while True:
        before, start = _cpu(pids), time.perf_counter()
        time.sleep(QUIET_WINDOW)
        if 100 * (_cpu(pids) - before) / (time.perf_counter() - start) < QUIET:
            return time.perf_counter() - began
        if time.perf_counter() - began > limit:
            raise RuntimeError(f"processes {pids} still busy after {limit:g} s")


def _say(began: float, what: str) -> None:
    """Progress on stderr (``bench.one`` prints the figures on stdout): where the time goes."""
    print(f"bench.ros_plant: {time.perf_counter() - began:6.1f} s  {what}", file=sys.stderr, flush=True)


def run(quick: bool) -> list[Figure]:
    from sm_bt.ros.environment import manager_profile, prepare, require_ros

    prepare(own_domain=True)
    require_ros()
    from sm_bt.model.loader import load_model
    from sm_bt.ros.runtime import RosRuntime

    # A 200-node bring-up takes the baseline 0.1-0.4 s, and a turn is twelve requests or batches
    # (both sides, with their untimed warm-ups and shutdowns) and the waits for the manager to see
    # the baseline's: 5-15 s a turn, more with late answers. Turns are what a few minutes allow.
    count, per, turns, switches, window = (2, 3, 2, 2, 2.0) if quick else (10, 20, 6, 10, 10.0)
    nodes = groups(count, per)
    names = [n for group in nodes for n in group]
    shape = {"nodes": len(names), "processes": count}
    figures: list[Figure] = []
    clock = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-ros-plant-") as tmp:
        path = Path(tmp) / "bench_ros_plant.yaml"
        path.write_text(model_text(nodes))
        model = load_model(path)
        values = mode_values(model, names)
        processes = [NodesProcess(str(path), "--state", "unconfigured", "--only", ",".join(group),
                                  ready_timeout=START_LIMIT) for group in nodes]
        baseline: BaselineProcess | None = None
        runtime: Any = None
        timings: dict[str, float] = {}
        try:
            began = time.perf_counter()
            _start(processes)
            timings["processes_started_s"] = time.perf_counter() - began
            pids = [p.pid for p in processes if p.pid is not None]
            _say(clock, f"node processes started in {timings['processes_started_s']:.1f} s")
            # After the nodes, as bench/ros.py: made first, the manager took nodes whose lifecycle
            # services it found more than a second after their parameter services (the discovery of
            # 200 nodes at once on 2 cores) for nodes without lifecycle services.
            began = time.perf_counter()
            # As sm-bt manager --receive-room: this process is the manager's.
            with manager_profile(room=True) as profile:
                runtime = RosRuntime(model, manager_options={"rules": False, "recovery": False})
            timings["receive_room"] = float(profile is not None)
            timings["constructed_s"] = time.perf_counter() - began
            manager = runtime.manager
            wait_for(lambda: all(manager.observation(n).reachable for n in names), "the manager sees every node",
                     DISCOVERY_LIMIT)
            timings["discovered_s"] = time.perf_counter() - began
            plain = [n for n in names if not manager.observation(n).lifecycle]
            if plain:
                raise RuntimeError(f"the manager took {len(plain)} lifecycle nodes for nodes without lifecycle "
                                   f"services: {', '.join(plain[:5])}")
            _say(clock, f"manager constructed in {timings['constructed_s']:.1f} s, all nodes reached after "
                        f"{timings['discovered_s']:.1f} s")
            # Idle with only the nodes and the manager, as bench/ros.py, before the floor's process
            # comes: once it leaves, the manager's participant hears of each of its thousands of
            # entities going (11.9 % of a core over the next 10 s, against 2.5-2.9 % before).
            _quiet(pids, DISCOVERY_LIMIT)
            freeze_garbage()  # as sm-bt manager does once it is up
            before, start = _cpu_seconds(os.getpid()), time.perf_counter()
            time.sleep(window)
            idle = 100 * (_cpu_seconds(os.getpid()) - before) / (time.perf_counter() - start)
            figures.append(Figure("idle", f"manager process CPU, {len(names)} idle nodes in {count} processes",
                                  idle, "% of a core", IDLE_GOAL, details={"window_s": window, **shape}))
            began = time.perf_counter()
            baseline = BaselineProcess(path, names)
            timings["baseline_ready_s"] = time.perf_counter() - began
            timings["quiet_after_s"] = _quiet([*pids, baseline.process.pid], DISCOVERY_LIMIT)
            _say(clock, f"baseline ready in {timings['baseline_ready_s']:.1f} s, quiet "
                        f"{timings['quiet_after_s']:.1f} s later")
            figures += _p1_p2(baseline, manager, values, turns, switches, shape, clock)
            baseline.close()
            baseline = None
            killed, others = nodes[0], names[per:]
            processes[0].kill()  # SIGKILL, then waits for the exit (milliseconds)
            detected = wait_for(lambda: not any(manager.observation(n).reachable for n in killed),
                                "vanish detected", 30.0)
            still = sum(manager.observation(n).reachable for n in others)
            figures.append(Figure("idle", f"every node of a killed process (of {count}) reported vanished",
                                  detected, "s", VANISH_GOAL,
                                  details={"nodes_killed": len(killed), "others_still_reachable": still,
                                           "others": len(others)}))
            _say(clock, "idle and vanish measured")
            # The nodes go first: every entity the manager destroys is news to each participant left.
            _stop(processes)
            began = time.perf_counter()
            runtime.close()
            runtime = None
            timings["closed_s"] = time.perf_counter() - began
            _say(clock, f"manager closed in {timings['closed_s']:.1f} s")
            figures.append(Figure("discovery", f"manager constructed and has every node, {len(names)} nodes in "
                                  f"{count} processes", timings["discovered_s"], "s",
                                  details={**shape, **{k: round(v, 2) for k, v in timings.items()}}))
        finally:
            if baseline is not None:
                baseline.close()
            _stop(processes)
            if runtime is not None:
                runtime.close()
    return figures


class _GaveUp(Exception):
    """More than MAX_FAILED turns failed: the turns stop."""


def _p1_p2(baseline: BaselineProcess, manager: ModeManager, values: dict[str, dict[str, dict[str, Any]]],
           turns: int, switches: int, shape: dict[str, int], clock: float) -> list[Figure]:
    """bench/ros.py's turns, with the two requests the plant goals name: bring-up as one
    ``change_mode`` and the whole-system switch. A turn that fails (a request or a raw call failed,
    or the manager did not see what the baseline did) is counted, with its reason, and the nodes
    are brought back through the manager; past ``MAX_FAILED`` the turns stop."""
    steps = Turns(baseline, manager, values, shape["nodes"])
    times, delays = steps.times, steps.delays
    failed: list[str] = []
    count = shape["nodes"]
    manager_one, manager_reset = steps.manager_one, steps.manager_reset

    def failure(error: RuntimeError) -> None:
        failed.append(str(error)[:300])
        _say(clock, f"a turn failed: {str(error)[:300]}")
        if len(failed) > MAX_FAILED:
            raise _GaveUp from error

    def attempt(turn: Callable[[], object], recover: Callable[[], object]) -> None:
        """``turn``; if it fails, ``recover`` (through the manager, from wherever the failure left the
        nodes) until it works: each failure counts."""
        try:
            turn()
            return
        except RuntimeError as error:
            failure(error)
        while True:
            baseline.rest()
            wait_for(lambda: all(manager.observation(n).reachable for n in baseline.nodes),
                     "the manager sees every node again", DISCOVERY_LIMIT)
            try:
                recover()
                return
            except RuntimeError as error:
                failure(error)

    # Each side's turn starts with an untimed bring-up and shutdown of its own (bench/ros.py: either
    # side is slower right after the other made the calls).
    def bring_up_turn() -> None:
        manager_one()
        manager_reset()
        times["one"].append(manager_one())
        manager_reset()
        steps.baseline_bring_ups(1)

    def shut_down() -> None:
        manager_one()
        manager_reset()

    def bring_ups() -> None:
        for _ in range(turns):
            attempt(bring_up_turn, shut_down)
        attempt(manager_one, manager_one)  # the switches start from __DEFAULT__
        _say(clock, f"{turns} bring-up turns done")

    def mode_switches() -> None:
        for _ in range(switches):
            attempt(steps.switch_turn, manager_one)
        _say(clock, f"{switches} switch turns done")

    # Past MAX_FAILED failures the turns stop, and the figures are what was measured until then.
    gave_up = ""
    try:
        bring_ups()
        mode_switches()
    except _GaveUp:
        gave_up = f"gave up after {len(failed)} failures"
        baseline.rest()
    figures = []
    where = f"{count} nodes in {shape['processes']} processes"
    for key, baseline_key, label in (("switch", "switch_baseline", "(a) whole-system mode switch"),
                                     ("one", "bring_baseline", "(c) bring-up as one change_mode")):
        if not times[key] or not times[baseline_key]:
            continue
        mine, base = statistics.median(times[key]), statistics.median(times[baseline_key])
        figures.append(Figure("P1", f"{label}, {where} / raw rclpy", mine / base, "x", P1_GOAL,
                              details={"sm_bt_ms": round(mine * 1e3, 1), "baseline_ms": round(base * 1e3, 1),
                                       "repeats": len(times[key]), **shape,
                                       "sm_bt_all_ms": [round(t * 1e3) for t in times[key]],
                                       "baseline_all_ms": [round(t * 1e3) for t in times[baseline_key]]}))
    figures.append(Figure("P1", f"turns that failed, of {turns + switches}", len(failed), "turns", 0,
                          details={"reasons": failed, "gave_up": gave_up}))
    if not delays:
        return figures
    delays_ms = [d * 1e3 for d in delays]
    figures.append(Figure("P2", f"system mode_event after the last node event, {where}, median",
                          statistics.median(delays_ms), "ms", P2_GOAL_MS,
                          details={"max_ms": round(max(delays_ms), 2), "samples": len(delays)}))
    figures.append(Figure("P2", f"system mode_event after the last node event, {where}, max", max(delays_ms), "ms",
                          P2_GOAL_MS, details={"samples": len(delays),
                                               "all_ms": [round(d, 2) for d in delays_ms]}))
    return figures
