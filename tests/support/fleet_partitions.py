"""Partition/heal cycles between a fleet's manager and a robot's, with the invariants checked after each
heal: tests/support/partitions.py's cycles, one level up.

robot1 (the pilot's nodes and its own ``sm-bt manager --namespace /robot1``) runs on the robot side, the
fleet's ``sm-bt manager`` (a model of one remote part, robot1) on the brain side (tests/support/hosts.py).
Each cycle, from a seeded random generator (a failure can be replayed): maybe a fleet mode is asked,
the link is cut at a random moment (on either side or both), maybe another fleet mode is asked while
cut, and the link heals after a random while. Then, as an operator could see it:

* within ``SETTLE`` s of the heal, robot1 is reachable at the fleet and the fleet is at its target
  (/diagnostics); the time from the heal is recorded;
* the fleet's view of robot1 is what robot1's own manager says (its latest ``transition_event`` and
  ``mode_event``, watched on the robot's side);
* the fleet's target is the last accepted request's mode: a refused one changed nothing;
* nothing moves afterwards: robot1's manager sends no event for ``QUIET`` s.
"""

from __future__ import annotations

import random
import time
from pathlib import Path
from typing import Any

from hosts import Hosts, Watch
from partitions import QUIET, WINDOW, Cycles, ask, latest, settle

FLEET = """\
fleet:
  ros__parameters:
    type: system
    modes:
      __DEFAULT__:
        robot1: active
      NIGHT:
        robot1: active.f_energy_saving_mode
      REST:
        robot1: inactive

robot1:
  ros__parameters:
    type: remote
    manager: /robot1
    system: pilot
    modes: [__DEFAULT__, f_energy_saving_mode]
"""
MODES = ("__DEFAULT__", "NIGHT", "REST")


def start(hosts: Hosts, folder: Path) -> tuple[Any, Any, dict[str, Watch], Watch]:
    """robot1 and the fleet, robot1 read by it: (robot1's manager, the fleet's manager, robot1's own
    transition_event and mode_event watched on its side, the fleet's /diagnostics)."""
    model = folder / "fleet.yaml"
    model.write_text(FLEET, encoding="utf-8")
    truth = {"state": hosts.watch("/robot1/pilot/transition_event", "lifecycle_msgs/msg/TransitionEvent",
                                  durability="transient_local", side="robot"),
             "mode": hosts.watch("/robot1/pilot/mode_event", "system_modes_msgs/msg/ModeEvent", side="robot")}
    diagnostics = hosts.watch("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
    hosts.nodes("pilot", "--namespace", "/robot1", "--state", "inactive")
    robot = hosts.manager("pilot", "--namespace", "/robot1", side="robot")
    fleet = hosts.manager(str(model), "--node-name", "fleet_manager", "--grace-period", "0.5")
    return robot, fleet, truth, diagnostics


def run(hosts: Hosts, cycles: int, seed: int, folder: Path) -> Cycles:
    """``cycles`` cycles (see the module's doc); ``AssertionError`` with the history on a broken invariant."""
    rng = random.Random(seed)
    record = Cycles(seed)
    robot, fleet, truth, diagnostics = start(hosts, folder)
    settle(diagnostics, record, since=time.monotonic(), system="fleet", nodes=("robot1",))
    for cycle in range(cycles):
        record.say(f"cycle {cycle + 1}")
        if rng.random() < 0.7:
            ask(hosts, record, rng.choice(MODES), system="fleet")
            time.sleep(rng.uniform(0.0, 0.3))  # the cut lands anywhere in the change
        side = rng.choice(("both", "brain", "robot"))
        cut = hosts.cut(side=side)
        record.say(f"cut ({side})")
        length = rng.uniform(0.2, 2.5)
        if rng.random() < 0.5:
            time.sleep(rng.uniform(0.0, length))
            ask(hosts, record, rng.choice(MODES), system="fleet")
        time.sleep(max(0.0, cut + length - time.monotonic()))
        healed = hosts.heal()
        record.say("healed")
        settle(diagnostics, record, since=healed, view_from=max(healed, cut + WINDOW), system="fleet",
               nodes=("robot1",))
        check(truth, diagnostics, record, robot, fleet)
    return record


def check(truth: dict[str, Watch], diagnostics: Watch, record: Cycles, robot: Any, fleet: Any) -> None:
    time.sleep(1.1)  # every part's status goes out once a second: the view is whole
    view = latest(diagnostics)
    states, modes = truth["state"].messages, truth["mode"].messages
    state = states[-1][1]["goal_state"]["label"] if states else "inactive"
    mode = modes[-1][1]["goal_mode"]["label"] if modes else ""
    own = f"{state}.{mode}" if state == "active" else state
    seen = view["robot1"]["actual"]
    logs = f"{record.history()}\nfleet:\n{fleet.stderr[-2000:]}\nrobot1:\n{robot.stderr[-2000:]}"
    assert seen == own, f"the fleet sees robot1 {seen}, its own manager says {own}\n{logs}"
    expected = "" if record.accepted is None else f"active.{record.accepted}"  # REST too: the fleet's mode
    assert view["fleet"]["target"] == expected, (
        f"the fleet's target {view['fleet']['target']!r}, the last accepted request asked {expected!r}\n{logs}")
    counts = (len(truth["state"].messages), len(truth["mode"].messages))
    time.sleep(QUIET)
    assert (len(truth["state"].messages), len(truth["mode"].messages)) == counts, f"robot1 moved, unasked\n{logs}"
    assert robot.alive and fleet.alive, f"a manager exited\n{logs}"
