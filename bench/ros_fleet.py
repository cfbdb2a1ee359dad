"""A fleet over real ROS 2: a manager of managers, against the robots' own managers asked directly.

N robots (10; ``--quick``: 3), each an ``sm-bt sim-nodes pilot --namespace /robotK`` process (the
pilot's four lifecycle nodes, started inactive) and an ``sm-bt manager pilot --namespace /robotK``
process. The fleet is a model made here (docs/model-format.md, "Remote parts"): a system ``fleet``
whose ``__DEFAULT__`` has every robot ``active`` and whose ``NIGHT`` has every robot
``active.f_energy_saving_mode``, one remote part per robot (``manager: /robotK``, ``system: pilot``).
The fleet manager is embedded here (``RosRuntime(model)``), as an application embeds it.

* Switch: a fleet mode switch NIGHT / ``__DEFAULT__``, from making the request to its done
  callback, against the floor: a plain rclpy client in this process (one node, one executor
  thread) sends every robot's ``/robotK/pilot/change_mode`` at once (all sent before any answer is
  awaited) and is timed until every robot's ``/robotK/pilot/mode_event`` says the new mode and
  every answer has come (the slowest robot's own confirmed change). The fleet's runtime is closed
  while the floor works, and the floor's client is closed while the fleet works; each block starts
  with one untimed switch of its own (discovery, first calls). A round is a block of each side, in
  turns (fleet first, then floor first, ...); the figure is the ratio of medians over all rounds,
  each round's own ratio in the details.
* Cut: one robot's manager process is frozen (SIGSTOP): from the signal to the fleet's manager
  reporting that robot ``unknown`` (an ``ACTUAL`` event of the part). Its manager's last answer
  came at or before the signal, so this bounds "unknown within X of the last answer" from above.
* Heal: the process is resumed (SIGCONT): from the signal until the fleet's view of the robot
  (state, and mode when active) is known and equals what the robot's manager answers
  (``get_state``, ``get_mode``). Cut and heal are repeated (a different robot each time); the
  figures are the maxima.
* Idle: an ``sm-bt manager FLEET.yaml`` process, brought up through ``/fleet/change_mode``, left
  to settle, then its CPU time (``/proc/PID/stat``) over an idle window, the robots running.
"""

from __future__ import annotations

import functools
import os
import signal
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from bench.figures import Figure
from bench.ros import _cpu_seconds
from bench.ros_baseline import confirmed, freeze_garbage
from bench.ros_fleet_client import (
    RESPONSE_PATH_GRACE,
    ROBOT_MODE,
    ROBOT_SYSTEM,
    TIMEOUT,
    RobotsClient,
    wait_for,
)
from bench.ros_fleet_process import FleetAsker, process_switches
from bench.ros_plant import start_one
from sm_bt.model.states import State
from sm_bt.ros.node_process import ManagerProcess, NodesError, NodesProcess

FLEET = "fleet"
SWITCH_GOAL, CUT_GOAL, HEAL_GOAL, IDLE_GOAL = 1.5, 1.0, 2.0, 2.0
#: Seconds to start the robots' processes (all at once, on two cores).
START_LIMIT = 90.0
#: lifecycle_msgs/msg/State's id of active.
ACTIVE = 3
#: Seconds for the domain to calm down after the fleet's process joins or leaves it (every participant
#: hears of its endpoints coming or going) before a block is timed.
CALM = 2.0


def fleet_text(robots: int) -> str:
    """The fleet model over ``/robot1`` ... ``/robot<robots>`` (models/fleet.yaml's shape)."""
    names = [f"robot{k}" for k in range(1, robots + 1)]
    out = [f"{FLEET}:\n  ros__parameters:\n    type: system\n    modes:\n"]
    out.append("      __DEFAULT__:\n" + "".join(f"        {name}: active\n" for name in names))
    out.append("      NIGHT:\n" + "".join(f"        {name}: active.{ROBOT_MODE['NIGHT']}\n" for name in names))
    for name in names:
        out.append(f"\n{name}:\n  ros__parameters:\n    type: remote\n    manager: /{name}\n"
                   f"    system: {ROBOT_SYSTEM}\n    modes: [__DEFAULT__, {ROBOT_MODE['NIGHT']}]\n")
    return "".join(out)


def _say(began: float, what: str) -> None:
    """Progress on stderr (``bench.one`` prints the figures on stdout)."""
    print(f"bench.ros_fleet: {time.perf_counter() - began:6.1f} s  {what}", file=sys.stderr, flush=True)


def _other(mode: str) -> str:
    return "NIGHT" if mode == "__DEFAULT__" else "__DEFAULT__"


# -- the processes ----------------------------------------------------------------------------------------


def _start_all(processes: Sequence[NodesProcess]) -> None:
    """Start every process at once (each bounded by its ``ready_timeout``); the first failure is
    raised once all starts are over."""
    with ThreadPoolExecutor(len(processes)) as pool:
        errors = [error for error in pool.map(start_one, processes) if error is not None]
    for error in errors:  # whole, with the child's stderr; the harness shows only the last line
        print(f"bench.ros_fleet: {error}", file=sys.stderr, flush=True)
    if errors:
        first = str(errors[0]).strip().splitlines()
        raise RuntimeError(f"{len(errors)} of {len(processes)} robot processes did not come up; the first: "
                           f"{first[0] if first else type(errors[0]).__name__}")


def _stop_all(processes: Sequence[NodesProcess]) -> None:
    """SIGCONT (one may be frozen), then SIGINT, grace, SIGKILL (NodesProcess.stop), all at once."""
    for process in processes:
        if process.alive and process.pid is not None:
            os.kill(process.pid, signal.SIGCONT)
    if processes:
        with ThreadPoolExecutor(len(processes)) as pool:
            list(pool.map(lambda process: process.stop(), processes))


# -- the fleet's side --------------------------------------------------------------------------------


def _fleet_runtime(model: Any, robots: Sequence[str]) -> Any:
    """The embedded fleet manager, once it has read every robot (state and mode known)."""
    from sm_bt.ros.runtime import RosRuntime

    runtime = RosRuntime(model, node_name="fleet_manager", manager_options={"request_timeout": TIMEOUT})
    try:
        manager = runtime.manager
        try:
            wait_for(lambda: all(manager.actual(r).known for r in robots), "the fleet reads its robots", TIMEOUT, 0.01)
        except RuntimeError:
            missing = [f"{r} ({manager.observation(r).gone or 'never read'})" for r in robots
                       if not manager.actual(r).known]
            raise RuntimeError(f"the fleet did not read {', '.join(missing)} within {TIMEOUT:g} s") from None
    except BaseException:
        runtime.close()
        raise
    return runtime


def _confirmed(manager: Any, start: Callable[[], Any]) -> float:
    """Seconds from making a request of the fleet's manager to its done callback; it must succeed."""
    return confirmed(manager, start, TIMEOUT + 5.0)


def _fleet_block(model: Any, robots: Sequence[str], at: str, switches: int) -> tuple[list[float], str, float]:
    """A fresh fleet runtime: one untimed switch, then ``switches`` timed ones; their seconds, the
    fleet mode the robots are left in, and the seconds the runtime took to read them."""
    began = time.perf_counter()
    runtime = _fleet_runtime(model, robots)
    try:
        up = time.perf_counter() - began
        manager = runtime.manager
        freeze_garbage()  # as sm-bt manager does once it is up
        at = _other(at)
        _confirmed(manager, lambda: manager.change_mode(FLEET, at))
        times = []
        for _ in range(switches):
            at = _other(at)
            times.append(_confirmed(manager, functools.partial(manager.change_mode, FLEET, at)))
    finally:
        runtime.close()
    return times, at, up


def _floor_block(robots: Sequence[str], at: str, switches: int) -> tuple[list[float], str, float]:
    """The same with a fresh plain client (see :class:`RobotsClient`)."""
    began = time.perf_counter()
    client = RobotsClient(robots, "sm_bt_bench_fleet_floor")
    try:
        client.ready()
        up = time.perf_counter() - began
        freeze_garbage()
        at = _other(at)
        client.switch(at, answers=False)  # untimed: a first call's answer may be lost to discovery
        times = []
        for _ in range(switches):
            at = _other(at)
            times.append(client.switch(at))
    finally:
        client.close()
    return times, at, up


# -- the run ---------------------------------------------------------------------------------------------


def run(quick: bool) -> list[Figure]:
    from sm_bt.ros.environment import prepare, require_ros

    prepare(own_domain=True)
    require_ros()
    from sm_bt.model.loader import load_model

    count, rounds, switches, cycles, settle, window = (3, 3, 2, 2, 2.0, 5.0) if quick else (10, 4, 6, 5, 3.0, 10.0)
    robots = [f"robot{k}" for k in range(1, count + 1)]
    clock = time.perf_counter()
    figures: list[Figure] = []
    with tempfile.TemporaryDirectory(prefix="sm_bt-bench-ros-fleet-") as tmp:
        path = Path(tmp) / "fleet.yaml"
        path.write_text(fleet_text(count))
        model = load_model(path)
        managers = [ManagerProcess(ROBOT_SYSTEM, "--namespace", f"/{r}", "--log-level", "warning",
                                   ready_timeout=START_LIMIT) for r in robots]
        nodes = [NodesProcess(ROBOT_SYSTEM, "--namespace", f"/{r}", "--state", "inactive", ready_timeout=START_LIMIT)
                 for r in robots]
        fleet_process: ManagerProcess | None = None
        runtime: Any = None
        client: RobotsClient | None = None
        try:
            began = time.perf_counter()
            _start_all([*managers, *nodes])
            _say(clock, f"{count} robots started ({2 * count} processes) in {time.perf_counter() - began:.1f} s")

            # Bring-up, as tests/ros/test_ros_fleet.py: every robot read (inactive), then __DEFAULT__.
            runtime = _fleet_runtime(model, robots)
            up = _confirmed(runtime.manager, lambda: runtime.manager.change_mode(FLEET, "__DEFAULT__"))
            runtime.close()
            runtime = None
            _say(clock, f"fleet brought up to __DEFAULT__ in {up:.2f} s")

            switched, _ = _switches(model, robots, "__DEFAULT__", rounds, switches, clock)
            figures.append(switched)

            # Cut and heal, with a fresh fleet runtime whose target is NIGHT.
            runtime = _fleet_runtime(model, robots)
            client = RobotsClient(robots, "sm_bt_bench_fleet_checker")
            client.ready(events=False)
            _confirmed(runtime.manager, lambda: runtime.manager.change_mode(FLEET, "NIGHT"))
            figures += _cuts(runtime.manager, client, managers, robots, cycles, clock)
            runtime.close()
            runtime = None

            # Idle: the fleet as a process of its own; then its switches, asked by a client.
            fleet_process = ManagerProcess(str(path), "--node-name", "fleet_manager", "--log-level", "warning",
                                           ready_timeout=START_LIMIT)
            figures.append(_idle(fleet_process, client, robots, managers, settle, window, clock))
            figures.append(_process_switches(fleet_process, client, rounds, switches, clock))
        finally:
            if client is not None:
                client.close()
            if runtime is not None:
                runtime.close()
            _stop_all([*([fleet_process] if fleet_process is not None else []), *managers, *nodes])
    _say(clock, "done")
    return figures


def _switches(model: Any, robots: Sequence[str], at: str, rounds: int, switches: int,
              clock: float) -> tuple[Figure, str]:
    """Row 1: blocks of fleet switches and of the floor's, in turns (see the module's doc)."""
    fleet: list[float] = []
    floor: list[float] = []
    by_round: list[float] = []
    start_up: dict[str, list[float]] = {"fleet": [], "floor": []}
    for index in range(rounds):
        got: dict[str, list[float]] = {}
        for side in ("fleet", "floor") if index % 2 == 0 else ("floor", "fleet"):
            times, at, up = (_fleet_block(model, robots, at, switches) if side == "fleet"
                             else _floor_block(robots, at, switches))
            got[side] = times
            start_up[side].append(round(up, 2))
        fleet += got["fleet"]
        floor += got["floor"]
        by_round.append(round(statistics.median(got["fleet"]) / statistics.median(got["floor"]), 2))
        _say(clock, f"round {index + 1}/{rounds}: fleet {statistics.median(got['fleet']) * 1e3:.0f} ms, "
                    f"floor {statistics.median(got['floor']) * 1e3:.0f} ms (medians of {switches})")
    ours, base = statistics.median(fleet), statistics.median(floor)
    return Figure("fleet", f"fleet mode switch, {len(robots)} robots / every robot's own change_mode at once",
                  ours / base, "x", SWITCH_GOAL,
                  details={"fleet_ms": round(ours * 1e3, 1), "floor_ms": round(base * 1e3, 1),
                           "switches": len(fleet), "rounds": rounds, "robots": len(robots),
                           "round_ratios": by_round, "fleet_all_ms": [round(t * 1e3, 1) for t in fleet],
                           "floor_all_ms": [round(t * 1e3, 1) for t in floor],
                           "block_start_up_s": start_up}), at



def _process_switches(process: ManagerProcess, client: RobotsClient, rounds: int, switches: int,
                      clock: float) -> Figure:
    """Row 5: the fleet's switch across processes (bench/ros_fleet_process.py), from __DEFAULT__."""
    client.ready()
    asker = FleetAsker(client.node, FLEET)
    try:
        asker.ready()
        freeze_garbage()

        def stop() -> None:
            process.stop()
            time.sleep(CALM)

        def start() -> None:
            process.start()
            time.sleep(CALM)

        return process_switches(asker, start, stop, client.switch, "__DEFAULT__", rounds, switches, SWITCH_GOAL,
                                lambda what: _say(clock, what))
    finally:
        asker.close()


def _cuts(manager: Any, client: RobotsClient, managers: Sequence[ManagerProcess], robots: Sequence[str], cycles: int,
          clock: float) -> list[Figure]:
    """Rows 2 and 3: a robot's manager frozen until the fleet says unknown, then resumed until the
    fleet agrees with it again; a different robot each cycle."""
    from sm_bt.engine.events import EventKind

    cut: list[float] = []
    heal: list[float] = []
    reasons: list[str] = []
    views: list[str] = []
    relapses: list[str] = []
    for cycle in range(cycles):
        index = cycle % len(robots)
        robot, pid = robots[index], managers[index].pid
        if pid is None or not managers[index].alive:
            raise RuntimeError(f"the manager of {robot} is not running: {managers[index].stderr[-1000:]}")
        seen: list[float] = []
        unknown = threading.Event()

        def told(event: Any, seen: list[float] = seen, unknown: threading.Event = unknown) -> None:
            if event.actual is not None and event.actual.state is State.UNKNOWN and not seen:
                seen.append(time.perf_counter())
                unknown.set()

        wait_for(functools.partial(_agree, manager, client, robot), f"the fleet agrees with {robot} before the cut")
        with manager.lock:  # subscribed and checked with no event in between
            if not manager.actual(robot).known:
                raise RuntimeError(f"{robot} unknown at the fleet before its cut: {manager.actual(robot)}")
            subscription = manager.subscribe(told, part=robot, kinds=[EventKind.ACTUAL])
        try:
            os.kill(pid, signal.SIGSTOP)
            stopped = time.perf_counter()
            try:
                if not unknown.wait(10.0):
                    raise RuntimeError(f"{robot} not unknown at the fleet 10 s after its manager froze: "
                                       f"{manager.actual(robot)}")
                cut.append(seen[0] - stopped)
                reasons.append(manager.observation(robot).gone)
            finally:
                os.kill(pid, signal.SIGCONT)
                resumed = time.perf_counter()
        finally:
            subscription.cancel()
        wait_for(functools.partial(_agree, manager, client, robot), f"the fleet agrees with {robot} after the heal",
                 15.0)
        heal.append(time.perf_counter() - resumed)
        views.append(str(manager.actual(robot)))
        # Still agreed a second later? (The robot's own manager was frozen too: its own liveness
        # verdicts on its nodes fall due late.) Counted in the details, not in the figure.
        watch_end = time.perf_counter() + 1.0
        while time.perf_counter() < watch_end:
            if not _agree(manager, client, robot):
                when, fleet_view = time.perf_counter() - resumed, manager.actual(robot)
                try:
                    own = str(client.robot_view(robot))
                except RuntimeError as error:
                    own = str(error)
                relapses.append(f"cycle {cycle + 1} ({robot}) {when:.2f} s after SIGCONT: fleet {fleet_view}, "
                                f"robot {own}")
                break
            time.sleep(0.05)
        _say(clock, f"cut {cycle + 1}/{cycles} ({robot}): unknown after {cut[-1]:.2f} s, "
                    f"agreed again {heal[-1]:.2f} s after SIGCONT ({views[-1]})")
    # What the robots' own managers said meanwhile (they log warnings and errors only).
    said = [f"{robot}: {line[:200]}" for robot, process in zip(robots, managers, strict=True)
            for line in process.stderr.splitlines() if "[WARN]" in line or "[ERROR]" in line]
    return [Figure("fleet", "robot's manager frozen (SIGSTOP) to the fleet reporting it unknown, max", max(cut), "s",
                   CUT_GOAL, details={"all_s": [round(t, 3) for t in cut], "cycles": cycles,
                                      "reason": reasons[0] if reasons else "",
                                      "robot_manager_warnings": len(said), "first_warnings": said[:6]}),
            Figure("fleet", "robot's manager resumed (SIGCONT) to the fleet agreeing with it, max", max(heal), "s",
                   HEAL_GOAL, details={"all_s": [round(t, 3) for t in heal], "cycles": cycles,
                                       "views": views, "relapses_within_1s": relapses})]


def _agree(manager: Any, client: RobotsClient, robot: str) -> bool:
    """The fleet knows ``robot`` and its view equals what the robot's own manager answers (state, and
    mode when active), unchanged while the robot was asked."""
    view = manager.actual(robot)
    if not view.known:
        return False
    try:
        state, mode = client.robot_view(robot)
    except RuntimeError:  # no answer in time: not yet
        return False
    return (state is view.state and (state is not State.ACTIVE or mode == view.mode)
            and manager.actual(robot) == view)


def _idle(process: ManagerProcess, client: RobotsClient, robots: Sequence[str], managers: Sequence[ManagerProcess],
          settle: float, window: float, clock: float) -> Figure:
    """Row 4: ``sm-bt manager FLEET.yaml`` brought up through ``/fleet/change_mode``, then idle. The
    robots' own managers are measured over the same window, for comparison (each answers the
    fleet's liveness probes)."""
    from lifecycle_msgs.srv import GetState
    from system_modes_msgs.srv import ChangeMode, GetMode

    began = time.perf_counter()
    try:
        process.start()
    except NodesError as error:
        print(f"bench.ros_fleet: {error}", file=sys.stderr, flush=True)
        raise RuntimeError(f"the fleet manager process did not come up: {str(error).splitlines()[0]}") from None
    pid = process.pid
    assert pid is not None
    get_state = client.node.create_client(GetState, f"/{FLEET}/get_state")
    get_mode = client.node.create_client(GetMode, f"/{FLEET}/get_mode")
    change_mode = client.node.create_client(ChangeMode, f"/{FLEET}/change_mode")
    wait_for(lambda: all(c.service_is_ready() for c in (get_state, get_mode, change_mode)),
          "the fleet manager process's services discovered", TIMEOUT, 0.02)

    def fleet_view() -> tuple[int, str]:
        try:
            return (int(client.call(get_state, GetState.Request()).current_state.id),
                    str(client.call(get_mode, GetMode.Request()).current_mode))
        except RuntimeError:
            return 0, ""

    wait_for(lambda: fleet_view()[0] != 0, "the fleet manager process reads its robots", TIMEOUT, 0.05)
    time.sleep(RESPONSE_PATH_GRACE)
    answer = client.call(change_mode, ChangeMode.Request(mode_name="__DEFAULT__"), 5.0)
    if not answer.success:
        raise RuntimeError("the fleet manager process refused change_mode __DEFAULT__")
    wait_for(lambda: fleet_view() == (ACTIVE, "__DEFAULT__"), "the fleet manager process reaches __DEFAULT__", TIMEOUT,
          0.05)
    modes = {robot: client.robot_view(robot) for robot in robots}
    wrong = {robot: view for robot, view in modes.items() if view != (State.ACTIVE, "__DEFAULT__")}
    if wrong:
        raise RuntimeError(f"the fleet process says __DEFAULT__, but the robots say otherwise: {wrong}")
    up = time.perf_counter() - began
    _say(clock, f"fleet manager process up and in __DEFAULT__ after {up:.1f} s; settling {settle:g} s, then "
                f"{window:g} s idle")
    time.sleep(settle)
    pids = [pid, *(m.pid for m in managers if m.pid is not None)]
    before, start = [_cpu_seconds(p) for p in pids], time.perf_counter()
    time.sleep(window)
    if not process.alive:
        raise RuntimeError(f"the fleet manager process exited: {process.stderr[-1000:]}")
    elapsed = time.perf_counter() - start
    used = [100 * (_cpu_seconds(p) - b) / elapsed for p, b in zip(pids, before, strict=True)]
    return Figure("idle", f"fleet manager process CPU, {len(robots)} idle robots", used[0], "% of a core", IDLE_GOAL,
                  details={"window_s": window, "settle_s": settle, "up_s": round(up, 2), "robots": len(robots),
                           "robot_manager_pct_median": round(statistics.median(used[1:]), 2),
                           "robot_manager_pct_max": round(max(used[1:]), 2),
                           "load_average_1min": round(os.getloadavg()[0], 1)})
