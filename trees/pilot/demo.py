"""``sm-bt demo``: the MROS pilot mission tree on simulated nodes in a small simulated world.

The mission tree (``sm_bt.trees.pilot``, or ``sm_bt.trees.pilot.metacontrol`` with ``--tree
metacontrol``) patrols seven waypoints; the robot drives at the speed controller_server's parameters give it,
the battery drains per metre, and the laser breaks and is repaired at chosen times. Everything
the tree changes goes through mode requests to the embedded manager. The narrative prints the
requests and their confirmations with timings, divergences, recoveries and contingencies, the
tree at key moments and the mode monitor, then a summary. Virtual time runs faster than wall
time (``--speed``).

The same demo runs on two platforms (:mod:`sm_bt.trees.pilot.platforms`): by default simulated nodes
(:class:`SimulatedPlatform`: the simulated backend on a virtual clock, the laser failure through
:class:`~sm_bt.trees.pilot.world.LaserDevice`), and with ``--ros`` real rclpy lifecycle nodes in a child
process (:class:`sm_bt.trees.pilot.ros_platform.RosPlatform`: the manager on ROS 2 and a wall clock, the laser
failure as the node's ``sim.broken`` parameter). On ROS, mode changes, grace periods and timeouts
take real time while the world (driving, recharging, the laser schedule) runs ``--speed`` times
faster (:attr:`World.time_scale <sm_bt.trees.pilot.world.World.time_scale>`).
"""

from __future__ import annotations

import enum
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.common import Status
from rich.console import Console

from sm_bt.bundled import path as bundled_model
from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.requests import Request
from sm_bt.model.loader import load_model
from sm_bt.model.states import State
from sm_bt.model.types import Model, NodePart
from sm_bt.monitor import Monitor, terminal_console
from sm_bt.trees import pilot
from sm_bt.trees.mission_xml import load_tree
from sm_bt.trees.pilot import metacontrol as pilot_metacontrol
from sm_bt.trees.pilot.actions import BATTERY_OK, CompleteRound, NavigateTo, Recharge, comparison
from sm_bt.trees.pilot.platforms import Platform, SimulatedPlatform, ros_platform
from sm_bt.trees.pilot.world import World
from sm_bt.view import View, attach_view

TREES: dict[str, Callable[[int], py_trees.behaviour.Behaviour]] = {
    "pilot": lambda cycles: pilot.create_root(cycles),
    "rules": lambda cycles: pilot.create_root(cycles, rules=True),
    "metacontrol": lambda cycles: pilot_metacontrol.create_root(cycles),
}


def mission_root(tree: str, cycles: int, model: Model) -> py_trees.behaviour.Behaviour:
    """The mission tree ``tree`` names: a shipped tree, or an XML tree file (its ``{cycles}``
    set); ``TreeFileError`` for a tree file with mistakes."""
    if tree in TREES:
        return TREES[tree](cycles)
    return load_tree(tree, model=model, inputs={"cycles": cycles})


#: The default laser repair on simulated nodes (world seconds).
REPAIR_AT = 40.0
#: The node whose scans fail when the laser breaks.
LASER_NODE = "laser_resender"
#: On ROS the default repair comes once the pilot has been in degraded mode this long (world
#: seconds; on simulated nodes it is 22.2 s). A fixed time cannot do it there: handling the failure
#: (two grace periods and a recovery) takes about 2.3 s of real time, i.e. 2.3 x speed seconds of
#: world time, and meanwhile the robot drives on, so the battery could run low in degraded mode.
DEGRADED_FOR = 22.0
#: ... and at the latest REPAIR_AT - failure time (25 s by default) of world time plus this many wall
#: seconds after the failure, in case the tree never switches to degraded mode.
ROS_REPAIR_WALL_MARGIN = 5.0


class Auto(enum.Enum):
    """The default laser repair: at :data:`REPAIR_AT` on simulated nodes; on ROS after
    :data:`DEGRADED_FOR` in degraded mode."""

    AUTO = "auto"


@dataclass
class Options:
    laser_failure_at: float | None = 15.0  # world seconds
    laser_repair_at: float | Auto | None = Auto.AUTO  # world seconds, never, or the default (Auto)
    cycles: int = 2
    speed: float = 35.0  # world seconds per wall second (simulated: 0 = as fast as possible)
    quiet: bool = False
    tree: str = "pilot"
    tick: float = 0.1  # virtual seconds between ticks (simulated platform)
    limit: float = 1500.0  # world seconds before giving up
    ros: bool = False  # real rclpy lifecycle nodes in a child process instead of simulated ones
    rules: bool = False  # the model with the laser rule (pilot_rules): the manager degrades, and holds it
    view: int | None = None  # serve the web view on this port (0: any free port)
    view_host: str = "127.0.0.1"
    record: str | None = None  # write the view's frames to this .jsonl file
    linger: bool = False  # keep serving the view after the run until Ctrl-C


@dataclass
class RunTally:
    """What happened, for the summary."""

    requests: list[Request] = field(default_factory=list)
    waypoints: int = 0
    rounds: int = 0
    recharges: int = 0
    modes: list[tuple[float, str]] = field(default_factory=list)
    gave_up: list[str] = field(default_factory=list)


class Demo:
    def __init__(self, options: Options, console: Console | None = None) -> None:
        if options.tree not in TREES and not options.tree.endswith(".xml"):
            raise ValueError(f"unknown tree {options.tree!r} (trees: {', '.join(TREES)}, or a .xml tree file)")
        if options.ros and not options.speed > 0:
            raise ValueError("--speed must be more than 0 with --ros (world seconds per wall second)")
        self.options = options
        self.console = console or terminal_console()
        self.model = load_model(bundled_model("pilot_rules" if options.rules else "pilot"))
        # On ROS the world runs --speed times faster than the manager's wall clock; on the
        # simulated platform both run on the virtual clock, and --speed only paces it.
        self.world = World(time_scale=options.speed if options.ros else 1.0)
        self._started = 0.0  # the manager's clock when the run starts
        self._wall_started = time.monotonic()
        self._lock = threading.Lock()  # on ROS, manager events come from its executors' and clock's threads
        # Manager events during a tick wait until the tree's own news of that tick (a waypoint,
        # the battery) is told: that news is what made the tree ask.
        self._held: list[tuple[str, str]] | None = None
        self._diverged: set[str] = set()  # nodes told to have left their target, until back
        self._laser_state = State.UNKNOWN
        self.platform: Platform = ros_platform(self.model, self.world, self.note) if options.ros \
            else SimulatedPlatform(self.model, self.world, tick=options.tick, speed=options.speed)
        try:
            self.manager = self.platform.manager
            self.clock = self.manager.clock
            self.root = mission_root(options.tree, options.cycles, self.model)
            self.tree = py_trees.trees.BehaviourTree(self.root)
            self.snapshot = py_trees.visitors.SnapshotVisitor()
            self.tree.add_visitor(self.snapshot)
            self.tree.setup(manager=self.manager, world=self.world)
            self.platform.serve(self.tree)
            self.view: View | None = None
            if options.view is not None or options.record is not None:
                self.view = attach_view(self.tree, self.manager, port=options.view, host=options.view_host,
                                        record=options.record)
                if self.view.url:  # with --quiet too: without it the page cannot be found
                    self._always(f"view: {self.view.url}")
            # Times from the start: a wall clock's raw (monotonic) reading means nothing to a reader.
            self.monitor = Monitor(self.manager, self.console, epoch=self.clock.now())
            self.tally = RunTally()
            self.final_mode = ""
            # The behaviours whose success is told, found once: walking the whole tree after every
            # tick cost a tenth of the run.
            self._statuses: dict[py_trees.behaviour.Behaviour, Status] = {
                behaviour: Status.INVALID for behaviour in self.root.iterate()
                if isinstance(behaviour, (NavigateTo, CompleteRound, Recharge))}
            self._key_moment = ""
            self._shown_modes: set[str] = set()
            self._battery_ok = True
            self._broken_at: float | None = None  # world time the laser broke
            self._started = self.clock.now()
            self._subscription = self.manager.subscribe(self._narrate)
        except BaseException:
            if getattr(self, "view", None) is not None:
                self.view.close()  # type: ignore[union-attr]
            self.platform.close()
            raise

    def close(self) -> None:
        """Stop narrating and release the platform (on ROS: the runtime and the node process)."""
        self._subscription.cancel()
        try:
            if self.view is not None:
                self.view.close()
        finally:
            self.platform.close()

    # -- time ----------------------------------------------------------------------------------

    @property
    def on_wall_clock(self) -> bool:
        return self.platform.time_unit == "wall"

    def elapsed(self, at: float | None = None) -> float:
        """Seconds of the manager's clock since the run started (virtual, or wall on ROS)."""
        return (self.clock.now() if at is None else at) - self._started

    def world_now(self) -> float:
        """World time since the run started: what the laser schedule and the limit are in."""
        return self.world.world_seconds(self.elapsed())

    def stamp(self) -> str:
        if self.on_wall_clock:
            return f"[{self.elapsed():6.2f} s wall |{self.world_now():7.1f} s world]"
        return f"[{self.clock.now():7.2f} s]"

    # -- narrative -----------------------------------------------------------------------------

    def say(self, text: str, style: str = "") -> None:
        if self.options.quiet:
            return
        line = f"{self.stamp()} {text}"
        with self._lock:
            if self._held is not None:
                self._held.append((line, style))
                return
        self.console.print(line, style=style or None, markup=False, soft_wrap=True)

    def _always(self, text: str) -> None:
        """``say`` even with --quiet (the view's address, and why the command has not ended)."""
        if self.options.quiet:
            self.console.print(text, markup=False, soft_wrap=True)
        else:
            self.say(text)

    def _hold(self) -> None:
        with self._lock:
            self._held = []

    def _release(self) -> None:
        with self._lock:
            held, self._held = self._held or [], None
        for line, style in held:
            self.console.print(line, style=style or None, markup=False, soft_wrap=True)

    def note(self, text: str) -> None:
        """A line about setting the platform up (before the run's clock starts)."""
        if not self.options.quiet:
            self.console.print(f"[{time.monotonic() - self._wall_started:6.2f} s wall] {text}", markup=False,
                               soft_wrap=True)

    def _narrate(self, event: Event) -> None:
        request = event.request
        if event.kind is EventKind.REQUEST and request is not None:
            if not request.done:
                self.tally.requests.append(request)
                self.say(f"-> {event.message} [{request.requester}]", "cyan")
            else:
                self.say(f"<- {event.message}", "green" if request.succeeded else "red")
        elif event.kind is EventKind.FAILED:
            self.tally.gave_up.append(event.part)
            self.say(f"!! {event.message}", "bold red")
        elif event.kind is EventKind.RULE:
            self.say(f"!! {event.message}", "magenta")
        elif event.kind is EventKind.HOLD:
            self.say(f"## {event.message}", "magenta")
        elif event.kind is EventKind.DIVERGENCE and isinstance(self.model.parts.get(event.part), NodePart):
            divergence = event.divergence
            if divergence is None:
                self._diverged.discard(event.part)
            elif divergence.cause is Cause.FAULT and event.part not in self._diverged:
                self._diverged.add(event.part)  # told once per departure, not per change of its reason
                self.say(f"~~ {event.part} left its target: {divergence.target} wanted, "
                         f"{divergence.actual} reported", "yellow")
        elif event.kind is EventKind.ACTUAL and event.part == pilot.SYSTEM:
            self._pilot_changed(event)
        elif event.kind is EventKind.ACTUAL and event.part == LASER_NODE and event.actual is not None:
            self._laser_node_changed(event.actual.state)

    def _laser_node_changed(self, state: State) -> None:
        """Tell when the laser's node falls out of active by itself: the cause of what follows."""
        was, self._laser_state = self._laser_state, state
        target = self.manager.target(LASER_NODE)
        if was is State.ACTIVE and state is not State.ACTIVE and target is not None \
                and target.state is State.ACTIVE:  # not a change the manager is making
            self.say(f"{LASER_NODE} fails by itself: no longer active ({state.label})", "bold")

    def _pilot_changed(self, event: Event) -> None:
        actual = event.actual
        if actual is None or actual.state is not State.ACTIVE or not actual.mode:
            return
        with self._lock:
            if not self.tally.modes or self.tally.modes[-1][1] != actual.mode:
                self.tally.modes.append((self.elapsed(event.time), actual.mode))
                self._key_moment = actual.mode

    def _after_tick(self) -> None:
        """Tell what the tree saw and did (waypoints, recharges, battery), then what it asked of
        the manager meanwhile, then the mode reached."""
        for behaviour, old in self._statuses.items():
            new = behaviour.status
            self._statuses[behaviour] = new
            if new is old or new is not Status.SUCCESS:
                continue
            if isinstance(behaviour, NavigateTo):
                self.tally.waypoints += behaviour.waypoint != "recharge_station"
                self._tell(f"robot at {behaviour.waypoint} ({self.world.odometer:.1f} m driven, "
                           f"battery {self.world.battery:.2f})")
            elif isinstance(behaviour, CompleteRound):
                self.tally.rounds = self.world.rounds
                self._tell(f"patrol round {self.world.rounds} of {self.options.cycles} complete")
            elif isinstance(behaviour, Recharge):
                self.tally.recharges += 1
                self._tell("recharged: battery 1.00")
        # The tree's battery monitor says when the battery is low (below 0.5) or recovered.
        battery_ok = Blackboard.get(BATTERY_OK) if Blackboard.exists(BATTERY_OK) else True
        if battery_ok != self._battery_ok:
            self._battery_ok = battery_ok
            self._tell("battery recovered" if battery_ok else
                       f"battery low ({comparison(self.world.battery, pilot.BATTERY_LOW)})", "bold")
        # Under the manager's lock: on ROS its events are told from another thread, and the change
        # that reached a mode is told with the rest of its events (the request's end among them)
        # before the mode is announced, never in between.
        with self.manager.lock:
            self._release()
            with self._lock:
                mode, self._key_moment = self._key_moment, ""
            if mode:
                self.say(f"== pilot is now active.{mode} ==", "bold")
                if mode not in self._shown_modes:  # the table and tree once per mode, to stay readable
                    self._shown_modes.add(mode)
                    self.show()

    def _tell(self, text: str, style: str = "") -> None:
        """Say ``text`` ahead of the manager events held during the tick."""
        if not self.options.quiet:
            self.console.print(f"{self.stamp()} {text}", style=style or None, markup=False, soft_wrap=True)

    def show(self) -> None:
        """The mode monitor and the part of the tree ticked last."""
        if self.options.quiet:
            return
        self.monitor.print_table()
        # Status and feedback for what this tick visited only: a finished behaviour's last
        # feedback is history, not news (py_trees marks a subtree left while running, without it).
        self.console.print(py_trees.display.unicode_tree(
            self.root, show_only_visited=True, show_status=False, visited=self.snapshot.visited,
            previously_visited=self.snapshot.previously_visited), markup=False, highlight=False)

    # -- the run -------------------------------------------------------------------------------

    def _repair_due(self, now: float) -> bool:
        """Whether the laser is to be repaired by world time ``now`` (``Options.laser_repair_at``)."""
        repair_at = self.options.laser_repair_at
        if repair_at is None:
            return False
        if not isinstance(repair_at, Auto):
            return repair_at <= now
        if not self.options.ros:
            return now >= REPAIR_AT
        if self._broken_at is None:
            return False
        with self._lock:
            last = self.tally.modes[-1] if self.tally.modes else None
        if last is not None and last[1] == pilot.DEGRADED and \
                now - self.world.world_seconds(last[0]) >= DEGRADED_FOR:
            return True
        broken_for = max(REPAIR_AT - (self.options.laser_failure_at or 0.0), 0.0)
        return now >= self._broken_at + broken_for + self.world.world_seconds(ROS_REPAIR_WALL_MARGIN)

    def _world_events(self, now: float) -> None:
        options = self.options
        if self._broken_at is None and options.laser_failure_at is not None and options.laser_failure_at <= now \
                and not self._repair_due(now):
            self._broken_at = now
            self.say("laser failure: the scans are all zero (laser_resender deactivates itself: on_deactivate "
                     "ERROR -> errorprocessing -> unconfigured)", "bold")
            self.platform.break_laser()
        elif not self.world.laser_ok and self._repair_due(now):
            self.say("laser repaired: scans healthy again", "bold")
            self.platform.repair_laser()

    def run(self) -> int:
        """Run the mission to its end, tell the summary and release the platform; the exit code."""
        try:
            return self._run()
        finally:
            self.close()

    def _run(self) -> int:
        where = f" on {self.platform.description}" + \
            (f", world time {self.world.time_scale:g}x the wall clock" if self.on_wall_clock else "")
        started = time.monotonic()
        self._started = self.clock.now()
        self.say(f"MROS pilot mission ({self.options.tree} tree){where}, {self.options.cycles} patrol round(s); "
                 f"robot at {self.world.position}, battery {self.world.battery:.2f}")
        while self.root.status is not Status.SUCCESS and self.root.status is not Status.FAILURE:
            now = self.world_now()
            if now > self.options.limit:
                break
            self._world_events(now)
            self._hold()
            try:
                self.tree.tick()
            finally:
                self._after_tick()
            self.platform.advance(self.platform.tick)
        self.say(f"mission {self.root.status.value}")
        self.final_mode = str(self.manager.actual(pilot.SYSTEM))
        self.show()
        code = self.summary(time.monotonic() - started)
        if self.view is not None and self.view.url and self.options.linger:
            self.view.stay(self._always)
        return code

    def expected_mode(self) -> str:
        """Degraded while the laser is broken, normal otherwise."""
        return f"active.{pilot.DEGRADED if not self.world.laser_ok else pilot.NORMAL}"

    def summary(self, wall: float) -> int:
        out = self.console
        unit = " wall" if self.on_wall_clock else ""  # the manager's clock: the requests' times
        if not self.options.quiet:
            out.print()
        out.print("Summary", style="bold")
        if self.on_wall_clock:
            duration = f"{self.world_now():.1f} s of world time ({wall:.1f} s wall, world {self.world.time_scale:g}x)"
        else:
            duration = f"{self.clock.now():.1f} s of virtual time ({wall:.1f} s wall)"
        out.print(f"  mission {self.root.status.value} after {duration}; {self.world.odometer:.1f} m driven, "
                  f"{self.tally.rounds} patrol round(s) ({self.tally.waypoints} waypoints), "
                  f"{self.tally.recharges} recharge(s)", markup=False, soft_wrap=True)
        modes = " -> ".join(f"{mode} ({at:.1f} s{unit})" for at, mode in self.tally.modes)
        out.print(f"  pilot modes: {modes}", markup=False, soft_wrap=True)
        by_requester: dict[str, list[Request]] = {}  # in the order each first asked
        for request in self.tally.requests:
            by_requester.setdefault(request.requester, []).append(request)
        for requester, requests in by_requester.items():
            ok = [r for r in requests if r.succeeded]
            times = [r.elapsed for r in ok if r.elapsed is not None]
            mean = f", confirmed in {sum(times) / len(times):.2f} s{unit} on average" if times else ""
            out.print(f"  {requester} requests: {len(ok)} of {len(requests)} succeeded{mean}", markup=False,
                      soft_wrap=True)
            for request in requests:
                if not request.succeeded:
                    out.print(f"    #{request.id} {request.description}: {request.reason}", markup=False,
                              soft_wrap=True)
        if self.tally.gave_up:
            out.print(f"  recovery gave up on: {', '.join(self.tally.gave_up)} (left to the tree)", markup=False,
                      soft_wrap=True)
        final = self.final_mode or str(self.manager.actual(pilot.SYSTEM))
        expected = self.expected_mode()
        good = self.root.status is Status.SUCCESS and final == expected
        verdict = "as expected" if good else f"NOT as expected ({expected} and a successful mission wanted)"
        out.print(f"  pilot ends in {final}; {verdict}", style=None if good else "bold red", markup=False,
                  soft_wrap=True)
        return 0 if good else 1
