"""``make stress``: a fleet of ten robots, each in a network namespace of its own, and the fleet's manager in
the brain's (tests/support/fleet_hosts.py: a switch between them). Each robot is the pilot's four simulated
nodes (``sm-bt sim-nodes pilot --namespace /robotK --state inactive``) and its own ``sm-bt manager pilot
--namespace /robotK``; the fleet is ``sm-bt manager FLEET.yaml`` over bench/ros_fleet.py's fleet model
(``NIGHT``: every robot ``active.f_energy_saving_mode``; ``__DEFAULT__``: every robot ``active``). The brain's
instrument is tests/support/fleet_agent.py. The issue's goals (README, "Fleets"), measured:

* switch (printed with the goal's verdict, not asserted: a performance figure): a fleet mode change,
  confirmed (its ``request_outcome`` succeeded and the fleet's ``mode_event``), within 1.5x the slowest
  robot's own change (every robot's own ``change_mode`` at once from the brain, as bench/ros_fleet.py's
  floor). Rounds of a block of each, in turns (fleet first, then floor first, ...); each block one untimed
  switch, then timed ones; the fleet's manager is stopped during the floor's blocks (it would restore its
  target) and a fresh one starts each fleet block; nothing here watches ``/diagnostics`` meanwhile (every
  manager publishes it). The figure: the ratio of medians; in the details, each fleet change until the
  last robot's own ``mode_event`` of it, as the brain hears it (the rest is the fleet's confirmation).
* cut: one robot's switch port down (its carrier lost): ``unknown`` at the fleet within 1 s of the cut (the
  fleet's ``transition_event``, as tests/e2e/test_across_hosts_fleet.py; its ``/diagnostics`` status of the
  robot, which comes up to 0.1 s later, in the details); a different robot each cycle, the maximum.
* heal: the port up again: from the moment datagrams cross, the fleet's view of every robot equals what
  the robot's own manager answers within 2 s; the maximum.
* idle (printed, as the switch): the fleet's manager process, at NIGHT over the ten idle robots: CPU
  (``/proc/PID/stat``) over 10 s <= 2 % of one core.

Every figure is printed on one ``MEASURED`` line first; the cut and heal goals not met fail the test. Needs
root; ``SM_BT_FLEET_ROBOTS`` sets how many robots (10).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import pytest
from fleet_hosts import BRAIN, FleetHosts, fleet_hosts
from hosts import Helper
from ros_processes import ManagerProcess

from bench.ros import _cpu_seconds
from bench.ros_fleet import fleet_text

pytestmark = [pytest.mark.ros, pytest.mark.netns]

ROBOTS = int(os.environ.get("SM_BT_FLEET_ROBOTS", "10"))
AGENT = Path(__file__).resolve().parents[1] / "support" / "fleet_agent.py"
SWITCH_GOAL, TOLD_GOAL, CONSISTENT_GOAL, IDLE_GOAL = 1.5, 1.0, 2.0, 2.0
#: Rounds of a fleet block and a floor block, timed switches per block, cut/heal cycles.
ROUNDS, SWITCHES, CUTS = 4, 6, 3  # bench/ros_fleet.py: 4 rounds of 6
#: Seconds a robot stays cut off after the fleet said it unknown.
CUT_FOR = 1.5
#: Seconds to settle before the idle window, and the window.
SETTLE, WINDOW = 3.0, 10.0
#: Start-up on two shared cores, 20+ ROS processes: generous (the goals are not).
START_LIMIT = 180.0
#: A command of the agent that is not a measurement's (a bring-up, a discovery).
SLOW = 90.0
#: Seconds for the domain to calm down after the fleet's manager joins or leaves it (every participant
#: hears of its endpoints coming or going) before a block is timed.
CALM = 2.0
#: The managers log warnings and errors only, as in bench/ros_fleet.py.
QUIET = ("--log-level", "warning")
#: SIGINT, then SIGKILL this long after: a manager stopped under load may take seconds to leave, and one
#: killed lingers in DDS discovery for its lease.
STOP_GRACE = 10.0


def ask(agent: Helper, command: str, timeout: float = SLOW) -> list[str]:
    """The agent's answer to ``command``, split in words; ``AssertionError`` on its ``ERROR``."""
    agent.send(command)
    line = agent.expect("", timeout)
    assert not line.startswith("ERROR"), f"{command}: {line}{agent.stderr_suffix()}"
    return line.split()


def start_fleet(hosts: FleetHosts, model: Path, agent: Helper, *, agree: bool = False) -> ManagerProcess:
    """A fresh ``sm-bt manager FLEET.yaml`` in the brain's namespace, once it knows every robot (``agree``:
    and its view of each is what the robot's manager answers)."""
    began = time.monotonic()
    fleet = hosts.manager(str(model), "--node-name", "fleet_manager", *QUIET, side=BRAIN, ready_timeout=START_LIMIT)
    ask(agent, f"fleet-ready {began:.6f}")
    if agree:
        ask(agent, f"agree {SLOW}")
    time.sleep(CALM)
    return fleet


def seconds(values: list[float], unit: str = " s") -> str:
    return ", ".join(f"{value:.2f}" for value in values) + unit


def milliseconds(values: list[float]) -> str:
    return " ".join(f"{value * 1e3:.0f}" for value in values)


def other(mode: str) -> str:
    return "NIGHT" if mode == "__DEFAULT__" else "__DEFAULT__"


def test_a_fleet_of_ten_robots_in_network_namespaces_meets_the_goals(tmp_path: Path) -> None:
    model = tmp_path / "fleet.yaml"
    model.write_text(fleet_text(ROBOTS), encoding="utf-8")
    with fleet_hosts(ROBOTS) as hosts:
        began = time.monotonic()
        robots = hosts.robots_up("pilot", state="inactive", manager_args=QUIET, ready_timeout=START_LIMIT)
        started = time.monotonic() - began
        agent = hosts.helper("fleet agent", sys.executable, str(AGENT), str(ROBOTS))
        agent.expect("READY", SLOW)
        fleet: ManagerProcess | None = start_fleet(hosts, model, agent)
        ask(agent, "fleet __DEFAULT__")  # bring-up: every robot inactive -> active
        up = time.monotonic() - began

        # -- switch: fleet blocks and floor blocks, in turns ----------------------------------------------
        at = "__DEFAULT__"
        times: dict[str, list[float]] = {"fleet": [], "floor": []}
        by_round: list[float] = []
        outcomes: list[float] = []  # each fleet change until its request_outcome alone
        killed = 0  # fleet managers that needed SIGKILL
        robots_done: list[float] = []  # each fleet change until the last robot's own mode_event
        for index in range(ROUNDS):
            got: dict[str, list[float]] = {}
            for side in ("fleet", "floor") if index % 2 == 0 else ("floor", "fleet"):
                if side == "fleet":
                    if fleet is None:
                        fleet = start_fleet(hosts, model, agent)
                    at = other(at)
                    ask(agent, f"fleet {at}")  # untimed: a first request after discovery
                    got[side] = []
                    for _ in range(SWITCHES):
                        at = other(at)
                        answer = ask(agent, f"fleet {at}", 30.0)
                        got[side].append(float(answer[1]))
                        outcomes.append(float(answer[2]))
                        robots_done.append(float(answer[5]))
                    killed += fleet.stop(STOP_GRACE) == -9
                    fleet = None
                    time.sleep(CALM)
                else:
                    at = other(at)
                    ask(agent, f"floor {at} untimed")
                    got[side] = []
                    for _ in range(SWITCHES):
                        at = other(at)
                        got[side].append(float(ask(agent, f"floor {at}", 30.0)[1]))
                times[side] += got[side]
            by_round.append(statistics.median(got["fleet"]) / statistics.median(got["floor"]))
        ratio = statistics.median(times["fleet"]) / statistics.median(times["floor"])
        by_outcome = statistics.median(outcomes) / statistics.median(times["floor"])

        # -- idle: a fleet at NIGHT over its idle robots --------------------------------------------------
        ask(agent, "diagnostics")
        fleet = start_fleet(hosts, model, agent, agree=True)
        if at != "NIGHT":
            ask(agent, "fleet NIGHT")
        ask(agent, f"agree {SLOW}")
        time.sleep(SETTLE)
        assert fleet.pid is not None
        pids = [fleet.pid, *(robot.pid for robot in robots if robot.pid is not None)]
        before, window_began = [_cpu_seconds(pid) for pid in pids], time.monotonic()
        time.sleep(WINDOW)
        elapsed = time.monotonic() - window_began
        used = [100 * (_cpu_seconds(pid) - cpu) / elapsed for pid, cpu in zip(pids, before, strict=True)]
        idle, robot_idle = used[0], statistics.median(used[1:])
        load = os.getloadavg()[0]

        # -- cut and heal: a different robot each cycle ---------------------------------------------------
        told: list[float] = []
        in_status: list[float] = []
        consistent: list[float] = []
        from_links: list[float] = []
        for cycle in range(CUTS):
            robot = hosts.robots[(3 + 4 * cycle) % ROBOTS]
            ask(agent, f"agree {SLOW}")
            cut = hosts.cut(robot)
            answer = ask(agent, f"unknown {robot} {cut:.6f} 10")
            status, event = float(answer[1]), float(answer[2])
            # The fleet's own event when its state turns unknown (only this robot is cut off, as in
            # tests/e2e/test_across_hosts_fleet.py); its /diagnostics status of the robot comes within 0.1 s.
            told.append((event if 0 < event <= status else status) - cut)
            in_status.append(status - cut)
            time.sleep(max(0.0, status + CUT_FOR - time.monotonic()))
            plugged = time.monotonic()
            healed = hosts.heal()
            agreed = float(ask(agent, "agree 20")[1])
            consistent.append(agreed - healed)
            from_links.append(agreed - plugged)
        assert fleet.alive, fleet.stderr[-3000:]
        views = ask(agent, "views")

        print(f"MEASURED fleet across hosts, {ROBOTS} robots in namespaces of their own: "
              f"switch {ratio:.2f}x (fleet {statistics.median(times['fleet']) * 1e3:.0f} ms / floor "
              f"{statistics.median(times['floor']) * 1e3:.0f} ms, medians of {len(times['fleet'])}; rounds "
              f"{seconds(by_round, 'x')}; fleet ms {milliseconds(times['fleet'])}; floor ms "
              f"{milliseconds(times['floor'])}; the fleet's request_outcome alone {by_outcome:.2f}x, median "
              f"{statistics.median(outcomes) * 1e3:.0f} ms; the last robot's own mode_event of a fleet change after "
              f"{statistics.median(robots_done) * 1e3:.0f} ms, median); cut: unknown at the fleet after "
              f"{seconds(told)} (max {max(told):.2f} s; "
              f"the robot's /diagnostics status after {seconds(in_status)}); heal: consistent {seconds(consistent)} "
              f"after datagrams crossed (max {max(consistent):.2f} s; after the port came up: "
              f"{seconds(from_links)}); idle: fleet manager {idle:.2f} % of a core over {elapsed:.1f} s (robots' "
              f"managers median {robot_idle:.2f} %, load average {load:.1f}); start-up: robots {started:.1f} s, "
              f"fleet at __DEFAULT__ {up:.1f} s; {killed} of {ROUNDS} fleet managers stopped with "
              f"SIGKILL")
        print(f"fleet and robots at the end: {' '.join(views[1:])}")
        # The switch and idle figures are performance goals: printed here, judged by bench/ros_fleet.py's rows
        # (make bench's rule: ratios measured in one run, never asserted by a test). The verdicts are asserted.
        report = [what for what, figure, goal in (
            (f"unknown {max(told):.2f} s after a cut > {TOLD_GOAL} s", max(told), TOLD_GOAL),
            (f"consistent {max(consistent):.2f} s after a heal > {CONSISTENT_GOAL} s", max(consistent),
             CONSISTENT_GOAL)) if figure > goal]
        print(f"GOALS switch {ratio:.2f}x ({'met' if ratio <= SWITCH_GOAL else 'NOT met'}: {SWITCH_GOAL}x), idle "
              f"{idle:.2f} % ({'met' if idle <= IDLE_GOAL else 'NOT met'}: {IDLE_GOAL} %)")
    print(f"fleet hosts closed in {hosts.close_seconds:.1f} s; stopped with SIGKILL: {hosts.killed or 'none'}")
    assert not report, "goals not met: " + "; ".join(report)
