"""Partition/heal cycles at random moments, with the invariants checked after each heal.

Used by ``tests/e2e/test_across_hosts.py`` (a couple of cycles, in ``make test``) and by
``tests/e2e/stress_partitions.py`` (many, in ``make stress``). The pilot's nodes run on the robot side,
``sm-bt manager pilot`` on the brain side (tests/support/hosts.py); each cycle, driven by a seeded random
generator so that a failure can be replayed:

1. maybe asks for a random mode of ``pilot`` (accepted or refused, as the manager answers),
2. cuts the link at a random moment after that (on the robot's side, the brain's, or both),
3. maybe asks for another mode while cut,
4. heals after a random while, and waits until every node is reachable again and the pilot is
   back at its target (recovery restores what a cut interrupted).

Then it checks, as an operator could see it:

* the manager's view of each node (``actual`` on ``/diagnostics``) is the node's true state (its
  last ``transition_event`` as seen on the robot's side);
* the pilot's target is the mode of the last *accepted* request: a refused one changed nothing;
* nothing happens afterwards: no transition on the robot within ``QUIET`` s (a change abandoned
  during the cut is never carried out late).
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field
from typing import Any

from hosts import Hosts, Watch

NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")
MODES = ("f_normal_mode", "f_degraded_mode", "f_performance_mode", "f_energy_saving_mode")
#: After a heal: every node reachable and the pilot at its target within this long.
SETTLE = 20.0
#: The manager's liveness window (RosBackend's default) and the time its verdict takes to reach
#: /diagnostics: a silence that began with the cut may still be told after the heal, rightly.
WINDOW = 0.9 + 0.3
#: With everything settled, no node moves for this long.
QUIET = 1.5


@dataclass
class Cycles:
    """The record of a run: what was asked, what the manager answered, what it looked like."""

    seed: int
    log: list[str] = field(default_factory=list)
    accepted: str | None = None  # the mode of the last accepted request
    refused: int = 0
    settle_times: list[float] = field(default_factory=list)

    def say(self, line: str) -> None:
        self.log.append(f"{time.monotonic():.3f} {line}")

    def history(self) -> str:
        return f"seed {self.seed}:\n" + "\n".join(f"  {line}" for line in self.log)


def latest(diagnostics: Watch, since: float = -math.inf) -> dict[str, dict[str, Any]]:
    """Each part's latest status on ``/diagnostics`` (by ``hardware_id``) among the messages that
    arrived at or after ``since``, values as a dict."""
    found: dict[str, dict[str, Any]] = {}
    for arrived, message in diagnostics.messages:
        if arrived < since:
            continue
        for status in message["status"]:
            values = {pair["key"]: pair["value"] for pair in status["values"]}
            found[status["hardware_id"]] = {"message": status["message"], **values}
    return found


def truth(events: dict[str, Watch], initial: str) -> dict[str, str]:
    """Each node's state by its own latest ``transition_event`` (``initial`` before any)."""
    states = {}
    for node, watch in events.items():
        messages = watch.messages
        states[node] = messages[-1][1]["goal_state"]["label"] if messages else initial
    return states


def run(hosts: Hosts, cycles: int, seed: int) -> Cycles:
    """``cycles`` cycles (see the module's doc); ``AssertionError`` with the history on a broken invariant."""
    rng = random.Random(seed)
    record = Cycles(seed)
    events = {node: hosts.watch(f"/{node}/transition_event", "lifecycle_msgs/msg/TransitionEvent", side="robot")
              for node in NODES}
    diagnostics = hosts.watch("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
    hosts.nodes("pilot", "--state", "inactive")
    for watch in events.values():  # the truth is only as good as the watchers' discovery of the nodes
        watch.wait_for_publishers(1, timeout=15.0)
    manager = hosts.manager("pilot", "--grace-period", "0.5")
    settle(diagnostics, record, since=time.monotonic())
    for cycle in range(cycles):
        record.say(f"cycle {cycle + 1}")
        if rng.random() < 0.7:
            ask(hosts, record, rng.choice(MODES))
            time.sleep(rng.uniform(0.0, 0.6))  # the cut lands anywhere in the change
        side = rng.choice(("both", "brain", "robot"))
        cut = hosts.cut(side=side)
        record.say(f"cut ({side})")
        length = rng.uniform(0.2, 2.5)
        if rng.random() < 0.5:
            time.sleep(rng.uniform(0.0, length))
            ask(hosts, record, rng.choice(MODES))
        time.sleep(max(0.0, cut + length - time.monotonic()))
        healed = hosts.heal()
        record.say("healed")
        settle(diagnostics, record, since=healed, view_from=max(healed, cut + WINDOW))
        check(events, diagnostics, record, manager)
    return record


def ask(hosts: Hosts, record: Cycles, mode: str, system: str = "pilot") -> None:
    code, _, err = hosts.sm_bt("mode", "set", system, mode, "--timeout", "5")
    if code == 0:
        record.accepted = mode
        record.say(f"asked {mode}: accepted")
    else:
        record.refused += 1
        record.say(f"asked {mode}: refused ({err.strip()[-160:]})")


def settle(diagnostics: Watch, record: Cycles, since: float, view_from: float = -math.inf, *,
           system: str = "pilot", nodes: tuple[str, ...] = NODES) -> None:
    """Every node reachable, and the system OK (at its target, nothing running), within SETTLE s of
    ``since``, as told on /diagnostics from ``view_from`` on (an older view may not know yet)."""
    give_up = since + SETTLE
    while True:
        view = latest(diagnostics, view_from)
        pilot = view.get(system, {})
        settled = (all(view.get(node, {}).get("reachable") == "true" for node in nodes)
                   and pilot.get("last_request_outcome") != "running"
                   and (not pilot.get("target") or pilot.get("actual") == pilot.get("target")))
        if settled:
            record.settle_times.append(time.monotonic() - since)
            record.say(f"settled: {system} {pilot.get('actual')}")
            return
        if time.monotonic() > give_up:
            raise AssertionError(f"not settled {SETTLE:g} s after the heal: {view}\n{record.history()}")
        time.sleep(0.1)


def check(events: dict[str, Watch], diagnostics: Watch, record: Cycles, manager: Any) -> None:
    time.sleep(1.1)  # every part's status goes out once a second: the view is whole
    view = latest(diagnostics)
    robot = truth(events, "inactive")
    seen = {node: view[node]["actual"].split(".")[0] for node in NODES}
    assert seen == robot, f"the manager sees {seen}, the robot is {robot}\n{record.history()}\n{manager.stderr[-3000:]}"
    expected = f"active.{record.accepted}" if record.accepted is not None else ""
    assert view["pilot"]["target"] == expected, (
        f"pilot's target {view['pilot']['target']!r}, the last accepted request asked {expected!r}\n"
        f"{record.history()}")
    counts = {node: len(watch.messages) for node, watch in events.items()}
    time.sleep(QUIET)
    moved = {node: len(watch.messages) - counts[node] for node, watch in events.items()
             if len(watch.messages) != counts[node]}
    assert not moved, f"nodes moved with nothing asked: {moved}\n{record.history()}\n{manager.stderr[-3000:]}"
    assert manager.alive, f"the manager exited\n{manager.stderr[-3000:]}"
