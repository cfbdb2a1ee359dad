"""``sm-bt demo --fleet``: a fleet's shift over managers of managers, one robot cut off and healed.

The fleet (``models/fleet.yaml``) has two robots, each the pilot's four nodes under a manager of its
own: simulated, all on one virtual clock (:class:`~sm_bt.trees.fleet.platforms.SimulatedFleet`), or
with ``--ros`` real processes (:class:`~sm_bt.trees.fleet.ros_platform.RosFleet`). The mission tree
(:mod:`sm_bt.trees.fleet`) asks the fleet's manager only: the day shift, then it waits for the night,
then ends the shift. Meanwhile robot1 is cut off from the fleet (its own manager and nodes go on):
the fleet sees it unknown, its rule ``robot1_lost`` asks for the night, which cannot reach robot1
yet; at the heal the fleet reads robot1 afresh and restores its target, the night is reached and the
tree ends the shift. The narrative tells the fleet's requests, rules and divergences, and each
robot's own requests under it; the view (``--view``) shows the tree and the fleet's table and
timeline, a band per robot.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import py_trees
from py_trees.common import Status
from rich.console import Console

from sm_bt.engine.events import Event, EventKind, Subscription
from sm_bt.model.types import NodePart
from sm_bt.monitor import terminal_console
from sm_bt.trees.fleet import DEMO_SPEED, FLEET, create_root
from sm_bt.trees.fleet.platforms import CUT_ROBOT, FleetPlatform, SimulatedFleet
from sm_bt.view import View, attach_view

#: Seconds (of the platform's time) between ticks, and the longest the shift may take.
TICK, LIMIT = 0.1, 120.0


def _starts(event: Event) -> bool:
    """A request's first event (read when it is told: a request refused or failed at once is done
    by then, so ``request.done`` cannot say)."""
    return event.text.endswith(" started")


@dataclass
class FleetOptions:
    cut_at: float | None = 3.0  # time robot1 is cut off (None: never)
    heal_at: float | None = 7.0  # ... and healed (None: never)
    speed: float = DEMO_SPEED  # virtual seconds per wall second (simulated); 0: as fast as possible
    quiet: bool = False
    view: int | None = None
    view_host: str = "127.0.0.1"
    record: str | None = None
    linger: bool = False
    ros: bool = False  # real processes (RosFleet) instead of simulated ones


class FleetDemo:
    def __init__(self, options: FleetOptions, console: Console | None = None) -> None:
        self.options = options
        self.console = console or terminal_console()
        self._started = time.monotonic()
        if options.ros:
            from sm_bt.trees.fleet.ros_platform import RosFleet

            self.platform: FleetPlatform = RosFleet(say=self._setting_up)
        else:
            self.platform = SimulatedFleet(options.speed)
        self.manager = self.platform.manager
        self.tree: py_trees.trees.BehaviourTree = py_trees.trees.BehaviourTree(create_root())
        self.tree.setup(manager=self.manager)
        self.view: View | None = None
        if options.view is not None or options.record is not None:
            self.view = attach_view(self.tree, self.manager, port=options.view, host=options.view_host,
                                    record=options.record)
            if self.view.url:
                self._always(f"view: {self.view.url}")
        self._subscriptions: list[Subscription] = [self.manager.subscribe(self._fleet_event)]
        self.platform.follow_robots(self._robot_request)
        self.modes: list[tuple[float, str]] = []
        self.cut_done: bool = False
        self.heal_done: bool = False

    # -- narrative ---------------------------------------------------------------------------------

    def say(self, text: str, style: str = "") -> None:
        if not self.options.quiet:
            self.console.print(f"[{self.platform.now():6.2f} s] {text}", style=style or None, markup=False,
                               soft_wrap=True)

    def _setting_up(self, text: str) -> None:
        if not self.options.quiet:
            self.console.print(f"[set-up {time.monotonic() - self._started:5.1f} s] {text}", markup=False,
                               soft_wrap=True)

    def _always(self, text: str) -> None:
        if self.options.quiet:
            self.console.print(text, markup=False, soft_wrap=True)
        else:
            self.say(text)

    def _fleet_event(self, event: Event) -> None:
        request = event.request
        if event.kind is EventKind.REQUEST and request is not None:
            if _starts(event):
                self.say(f"fleet -> {event.message} [{request.requester}]", "cyan")
            else:
                self.say(f"fleet <- {event.message}", "green" if request.succeeded else "red")
        elif event.kind is EventKind.RULE:
            self.say(f"fleet !! {event.message}", "magenta")
        elif event.kind is EventKind.DIVERGENCE and isinstance(self.manager.model.parts.get(event.part), NodePart):
            divergence = event.divergence
            if divergence is None:
                self.say(f"fleet ~~ {event.message}", "green")
            elif divergence.cause.value == "fault":
                self.say(f"fleet ~~ {event.message}", "yellow")
        elif event.kind is EventKind.ACTUAL and event.part == FLEET and event.actual is not None \
                and event.actual.mode and (not self.modes or self.modes[-1][1] != str(event.actual)):
            self.modes.append((self.platform.now(), str(event.actual)))

    def _robot_request(self, robot: str, text: str, ended: bool | None) -> None:
        if ended is None:
            self.say(f"    {robot}'s manager -> {text}")
        else:
            self.say(f"    {robot}'s manager <- {text}", "" if ended else "red")

    # -- the run -----------------------------------------------------------------------------------

    def _scenario(self, now: float) -> None:
        options = self.options
        if not self.cut_done and options.cut_at is not None and now >= options.cut_at:
            self.cut_done = True
            self.say(self.platform.cut(CUT_ROBOT), "bold")
        if self.cut_done and not self.heal_done and options.heal_at is not None and now >= options.heal_at:
            self.heal_done = True
            self.say(self.platform.heal(CUT_ROBOT), "bold")

    def run(self) -> int:
        """The shift to its end, the summary; the exit code (0: the shift ended as expected)."""
        try:
            return self._run()
        finally:
            self.close()

    def _run(self) -> int:
        platform = self.platform
        self.say(f"fleet shift over {', '.join(platform.robots)} (each the pilot under its own manager), on "
                 f"{platform.description}")
        root = self.tree.root
        while root.status not in (Status.SUCCESS, Status.FAILURE) and platform.now() < LIMIT:
            self._scenario(platform.now())
            self.tree.tick()
            platform.advance(TICK)
        self.say(f"shift {root.status.value}")
        code = self.summary(time.monotonic() - self._started)
        if self.view is not None and self.view.url and self.options.linger:
            self.view.stay(self._always)
        return code

    def summary(self, wall: float) -> int:
        out = self.console
        if not self.options.quiet:
            out.print()
        out.print("Summary", style="bold")
        platform = self.platform
        out.print(f"  shift {self.tree.root.status.value} after {platform.now():.1f} s of {platform.time_unit} time "
                  f"({wall:.1f} s wall, set-up included)", markup=False)
        out.print("  fleet modes: " + " -> ".join(f"{mode} ({at:.1f} s)" for at, mode in self.modes), markup=False,
                  soft_wrap=True)
        robots = {name: platform.robot_view(name) for name in platform.robots}
        seen = {name: str(self.manager.actual(name)) for name in platform.robots}
        out.print("  robots, by their own managers: " + ", ".join(f"{k} {v}" for k, v in robots.items())
                  + "; as the fleet sees them: " + ", ".join(f"{k} {v}" for k, v in seen.items()), markup=False,
                  soft_wrap=True)
        good = self.tree.root.status is Status.SUCCESS and robots == seen == {name: "inactive" for name in robots}
        out.print(f"  {'as expected' if good else 'NOT as expected (the shift ended, every robot inactive, wanted)'}",
                  style=None if good else "bold red", markup=False)
        return 0 if good else 1

    def close(self) -> None:
        for subscription in self._subscriptions:
            subscription.cancel()
        if self.view is not None:
            self.view.close()
        self.platform.close()
