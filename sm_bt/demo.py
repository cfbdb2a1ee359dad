"""``sm-bt demo``: the MROS pilot mission tree on simulated nodes in a small simulated world.

The mission tree (``sm_bt.trees.pilot``, or ``pilot_metacontrol`` with ``--tree metacontrol``)
patrols seven waypoints; the robot drives at the speed controller_server's parameters give it,
the battery drains per metre, and the laser breaks and is repaired at chosen times. Everything
the tree changes goes through mode requests to the embedded manager. The narrative prints the
requests and their confirmations with timings, divergences, recoveries and contingencies, the
tree at key moments and the mode monitor, then a summary. Virtual time runs faster than wall
time (``--speed``).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.common import Status
from rich.console import Console

from sm_bt.arguments import non_negative, positive_int
from sm_bt.bundled import path as bundled_model
from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Origin, Request
from sm_bt.model.loader import load_model
from sm_bt.model.states import State
from sm_bt.model.types import NodePart
from sm_bt.monitor import Monitor, terminal_console
from sm_bt.sim import SimBackend
from sm_bt.sim.world import LaserDevice, World
from sm_bt.trees import pilot, pilot_metacontrol
from sm_bt.trees.pilot_actions import BATTERY_OK, NavigateTo, Recharge

#: What Nav2's parameter files give the nodes before any mode is applied (the pilot's TB3 set-up).
NAV2_PARAMETERS = {
    "amcl": {"transform_tolerance": 2.0},
    "controller_server": {"FollowPath.max_vel_x": 0.4, "FollowPath.max_speed_xy": 0.4},
}
TREES: dict[str, Callable[[int], py_trees.behaviour.Behaviour]] = {
    "pilot": lambda cycles: pilot.create_root(cycles),
    "metacontrol": lambda cycles: pilot_metacontrol.create_root(cycles),
}


@dataclass
class Options:
    laser_failure_at: float | None = 15.0
    laser_repair_at: float | None = 40.0
    cycles: int = 2
    speed: float = 25.0
    quiet: bool = False
    tree: str = "pilot"
    tick: float = 0.1  # virtual seconds between ticks
    limit: float = 1500.0  # virtual seconds before giving up


@dataclass
class Story:
    """What happened, for the summary."""

    requests: list[Request] = field(default_factory=list)
    waypoints: int = 0
    recharges: int = 0
    modes: list[tuple[float, str]] = field(default_factory=list)
    gave_up: list[str] = field(default_factory=list)


class Demo:
    def __init__(self, options: Options, console: Console | None = None) -> None:
        if options.tree not in TREES:
            raise ValueError(f"unknown tree {options.tree!r} (trees: {', '.join(TREES)})")
        self.options = options
        self.console = console or terminal_console()
        self.model = load_model(bundled_model("pilot"))
        self.backend = SimBackend(self.model, transition_delay=0.2, parameter_delay=0.05,
                                  initial_parameters=NAV2_PARAMETERS)
        self.clock = self.backend.clock
        # One recovery attempt: a laser that fails again at once is then left to the tree.
        self.manager = ModeManager(self.model, self.backend, request_timeout=10.0, grace_period=1.0,
                                   recovery_attempts=1)
        self.world = World()
        self.laser = LaserDevice(self.world, self.backend)
        self.root = TREES[options.tree](options.cycles)
        self.tree = py_trees.trees.BehaviourTree(self.root)
        self.snapshot = py_trees.visitors.SnapshotVisitor()
        self.tree.add_visitor(self.snapshot)
        self.tree.setup(manager=self.manager, world=self.world)
        self.monitor = Monitor(self.manager, self.console)
        self.story = Story()
        self._statuses: dict[py_trees.behaviour.Behaviour, Status] = {}
        self._key_moment = ""
        self._shown_modes: set[str] = set()
        self._battery_ok = True
        self.manager.subscribe(self._narrate)

    # -- narrative -----------------------------------------------------------------------------

    def say(self, text: str, style: str = "") -> None:
        if not self.options.quiet:
            self.console.print(f"[{self.clock.now():7.2f} s] {text}", style=style or None, markup=False)

    def _narrate(self, event: Event) -> None:
        request = event.request
        if event.kind is EventKind.REQUEST and request is not None:
            if not request.done:
                self.story.requests.append(request)
                self.say(f"-> {event.message} [{request.origin.value}]", "cyan")
            else:
                self.say(f"<- {event.message}", "green" if request.succeeded else "red")
        elif event.kind is EventKind.FAILED:
            self.story.gave_up.append(event.part)
            self.say(f"!! {event.message}", "bold red")
        elif event.kind is EventKind.RULE:
            self.say(f"!! {event.message}", "magenta")
        elif event.kind is EventKind.DIVERGENCE and event.divergence is not None \
                and event.divergence.cause is Cause.FAULT \
                and isinstance(self.model.parts.get(event.part), NodePart):
            self.say(f"~~ {event.part} left its target: {event.divergence.target} wanted, "
                     f"{event.divergence.actual} reported", "yellow")
        elif event.kind is EventKind.ACTUAL and event.part == pilot.SYSTEM:
            self._pilot_changed(event)

    def _pilot_changed(self, event: Event) -> None:
        actual = event.actual
        if actual is None or actual.state is not State.ACTIVE or not actual.mode:
            return
        if not self.story.modes or self.story.modes[-1][1] != actual.mode:
            self.story.modes.append((event.time, actual.mode))
            self._key_moment = actual.mode

    def _after_tick(self) -> None:
        """Tell what the tree did: waypoints, recharges, battery, contingencies."""
        for behaviour in self.root.iterate():
            old = self._statuses.get(behaviour, Status.INVALID)
            new = behaviour.status
            self._statuses[behaviour] = new
            if new is old or new is not Status.SUCCESS:
                continue
            if isinstance(behaviour, NavigateTo):
                self.story.waypoints += behaviour.waypoint != "recharge_station"
                self.say(f"robot at {behaviour.waypoint} ({self.world.odometer:.1f} m driven, "
                         f"battery {self.world.battery:.2f})")
            elif isinstance(behaviour, Recharge):
                self.story.recharges += 1
                self.say("recharged: battery 1.00")
        # The tree's battery monitor decides when the battery is low or recovered.
        battery_ok = Blackboard.get(BATTERY_OK) if Blackboard.exists(BATTERY_OK) else True
        if battery_ok != self._battery_ok:
            self._battery_ok = battery_ok
            self.say("battery recovered" if battery_ok else f"battery low ({self.world.battery:.2f}): "
                     "contingency", "bold")
        if self._key_moment:
            mode, self._key_moment = self._key_moment, ""
            self.say(f"== pilot is now active.{mode} ==", "bold")
            if mode not in self._shown_modes:  # the table and tree once per mode, to stay readable
                self._shown_modes.add(mode)
                self.show()

    def show(self) -> None:
        """The mode monitor and the part of the tree ticked last."""
        if self.options.quiet:
            return
        self.monitor.print_table()
        self.console.print(py_trees.display.unicode_tree(
            self.root, show_only_visited=True, show_status=True, visited=self.snapshot.visited,
            previously_visited=self.snapshot.previously_visited), markup=False, highlight=False)

    # -- the run -------------------------------------------------------------------------------

    def _world_events(self, now: float) -> None:
        options = self.options
        if options.laser_failure_at is not None and self.world.laser_ok and \
                options.laser_failure_at <= now and (options.laser_repair_at is None or now < options.laser_repair_at):
            self.say("laser failure: all-zero scans; laser_resender deactivates itself "
                     "(on_deactivate ERROR -> errorprocessing -> unconfigured)", "bold")
            self.laser.break_laser()
        elif not self.world.laser_ok and options.laser_repair_at is not None and options.laser_repair_at <= now:
            self.say("laser repaired: scans healthy again", "bold")
            self.laser.repair()

    def run(self) -> int:
        self.say(f"MROS pilot mission ({self.options.tree} tree), {self.options.cycles} patrol cycle(s); "
                 f"robot at {self.world.position}, battery {self.world.battery:.2f}")
        started = time.monotonic()
        while self.root.status is not Status.SUCCESS and self.root.status is not Status.FAILURE:
            now = self.clock.now()
            if now > self.options.limit:
                break
            self._world_events(now)
            self.tree.tick()
            self._after_tick()
            self.clock.advance(self.options.tick)
            self.laser.update()
            if self.options.speed > 0:
                time.sleep(self.options.tick / self.options.speed)
        self.say(f"mission {self.root.status.value}")
        self.show()
        return self.summary(time.monotonic() - started)

    def expected_mode(self) -> str:
        options = self.options
        broken = options.laser_failure_at is not None and options.laser_failure_at <= self.clock.now() and \
            (options.laser_repair_at is None or options.laser_repair_at > self.clock.now())
        return "active.f_degraded_mode" if broken else "active.f_normal_mode"

    def summary(self, wall: float) -> int:
        out = self.console
        out.print()
        out.print("Summary", style="bold")
        out.print(f"  mission {self.root.status.value} after {self.clock.now():.1f} s of virtual time "
                  f"({wall:.1f} s wall); {self.world.odometer:.1f} m driven, {self.story.waypoints} waypoints, "
                  f"{self.story.recharges} recharge(s)", markup=False)
        modes = " -> ".join(f"{mode} ({at:.1f} s)" for at, mode in self.story.modes)
        out.print(f"  pilot modes: {modes}", markup=False)
        by_origin = {origin: [r for r in self.story.requests if r.origin is origin] for origin in Origin}
        for origin, requests in by_origin.items():
            if not requests:
                continue
            ok = [r for r in requests if r.succeeded]
            times = [r.elapsed for r in ok if r.elapsed is not None]
            mean = f", confirmed in {sum(times) / len(times):.2f} s on average" if times else ""
            out.print(f"  {origin.value} requests: {len(ok)} of {len(requests)} succeeded{mean}", markup=False)
            for request in requests:
                if not request.succeeded:
                    out.print(f"    #{request.id} {request.description}: {request.reason}", markup=False)
        if self.story.gave_up:
            out.print(f"  recovery gave up on: {', '.join(self.story.gave_up)} (left to the tree)", markup=False)
        final = str(self.manager.actual(pilot.SYSTEM))
        expected = self.expected_mode()
        good = self.root.status is Status.SUCCESS and final == expected
        verdict = "as expected" if good else f"NOT as expected ({expected} and a successful mission wanted)"
        out.print(f"  pilot ends in {final}; {verdict}", style=None if good else "bold red", markup=False)
        return 0 if good else 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tree", choices=sorted(TREES), default="pilot",
                        help="contingencies in the tree (pilot, default) or chosen by a metacontroller")
    parser.add_argument("--laser-failure-at", type=_time, default=15.0, metavar="SECONDS",
                        help="virtual time the laser breaks; 'never' for no failure (default 15)")
    parser.add_argument("--laser-repair-at", type=_time, default=40.0, metavar="SECONDS",
                        help="virtual time the laser is repaired; 'never' to leave it broken (default 40)")
    parser.add_argument("--cycles", type=positive_int, default=2, help="patrol cycles (default 2)")
    parser.add_argument("--speed", type=non_negative, default=25.0,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 25)")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")


def _time(text: str) -> float | None:
    if text == "never":
        return None
    return non_negative(text)


def run(args: argparse.Namespace) -> int:
    options = Options(laser_failure_at=args.laser_failure_at, laser_repair_at=args.laser_repair_at,
                      cycles=args.cycles, speed=args.speed, quiet=args.quiet, tree=args.tree)
    return Demo(options).run()
