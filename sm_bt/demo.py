"""``sm-bt demo``: the MROS pilot through a scripted mode sequence on simulated nodes.

The robot is configured, put in normal mode, asked for performance mode while the controller
rejects those parameters (the request fails with the node's reason), loses its laser (the
model's rule switches to degraded mode once the grace period is over), gets the laser back,
runs low on battery (energy saving), recharges and returns to normal mode. Every request is
confirmed from what the nodes report; the narrative prints requests, divergences, rules and the
mode monitor, on a virtual clock that runs faster than wall time.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass

from sm_bt.bundled import path as bundled_model
from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.loader import load_model
from sm_bt.monitor import render_text, snapshot
from sm_bt.sim import SimBackend

#: What Nav2's parameter files give the nodes before any mode is applied (the pilot's TB3 set-up).
NAV2_PARAMETERS = {
    "amcl": {"transform_tolerance": 2.0},
    "controller_server": {"FollowPath.max_vel_x": 0.4, "FollowPath.max_speed_xy": 0.4},
}
STEP = 0.05  # virtual seconds per clock advance


@dataclass
class Options:
    laser_failure_at: float
    battery_low_at: float
    speed: float
    quiet: bool


class Demo:
    def __init__(self, options: Options, out: Callable[[str], None] = print) -> None:
        self.options = options
        self.out = out
        self.model = load_model(bundled_model("pilot_rules"))
        self.backend = SimBackend(self.model, transition_delay=0.2, parameter_delay=0.05,
                                  initial_parameters=NAV2_PARAMETERS)
        self.clock = self.backend.clock
        self.manager = ModeManager(self.model, self.backend, request_timeout=10.0, grace_period=2.0,
                                   recovery_attempts=2)
        self.manager.subscribe(self._narrate)
        self.outcomes: list[Request] = []
        self._told: Cause | None = None  # the pilot divergence last narrated

    # -- narrative -----------------------------------------------------------------------------

    def say(self, text: str) -> None:
        if not self.options.quiet:
            self.out(f"[{self.clock.now():7.2f} s] {text}")

    def _narrate(self, event: Event) -> None:
        if event.kind is EventKind.REQUEST and event.request is not None:
            self.say(("->" if event.message.endswith(" started") else "  ") + " " + event.message)
        elif event.kind in (EventKind.RULE, EventKind.FAILED):
            self.say(f"!! {event.message}")
        elif event.kind is EventKind.DIVERGENCE and event.part == "pilot":
            # Tell a divergence when it starts, when it becomes an error, and when it ends.
            cause = event.divergence.cause if event.divergence else None
            if cause is not self._told and (cause is None or cause is not Cause.IN_FLIGHT or self._told):
                if cause is not Cause.IN_FLIGHT:
                    self.say(f"~~ {event.message}")
                self._told = cause

    def table(self) -> None:
        if not self.options.quiet:
            self.out(render_text(snapshot(self.manager)))

    # -- time ----------------------------------------------------------------------------------

    def advance(self, seconds: float) -> None:
        end = self.clock.now() + seconds
        while self.clock.now() < end - 1e-9:
            dt = min(STEP, end - self.clock.now())
            self.clock.advance(dt)
            if self.options.speed > 0:
                time.sleep(dt / self.options.speed)

    def until(self, condition: Callable[[], bool], limit: float) -> bool:
        end = self.clock.now() + limit
        while not condition() and self.clock.now() < end:
            self.advance(STEP)
        return condition()

    def request(self, make: Callable[[], Request]) -> Request:
        request = make()
        self.until(lambda: request.done, 30.0)
        self.outcomes.append(request)
        return request

    def at(self, when: float) -> None:
        if self.clock.now() < when:
            self.advance(when - self.clock.now())

    # -- the story -----------------------------------------------------------------------------

    def run(self) -> int:
        m = self.manager
        self.say("Pilot model loaded: system 'pilot' with amcl, controller_server, pointcloud_to_laser, "
                 "laser_resender (all unconfigured)")
        self.request(lambda: m.change_state("pilot", "configure"))
        self.request(lambda: m.change_mode("pilot", "f_normal_mode"))
        self.table()

        self.say("Mission asks for performance; controller_server refuses the FAST parameters")
        self.backend.reject_parameters("controller_server", "FollowPath.max_vel_x above the robot's limit")
        failed = self.request(lambda: m.change_mode("pilot", "f_performance_mode"))
        self.backend.reject_parameters("controller_server", None)
        self.say(f"   -> the tree learns why: {failed.reason}")
        self.request(lambda: m.change_mode("pilot", "f_normal_mode"))

        self.at(self.options.laser_failure_at)
        self.say("Laser failure: laser_resender sees all-zero scans and deactivates itself "
                 "(on_deactivate ERROR -> errorprocessing -> unconfigured)")
        self.backend.trigger("laser_resender", Transition.DEACTIVATE, outcome=Outcome.ERROR)
        self.until(lambda: str(m.actual("pilot")) == "active.f_degraded_mode", 15.0)
        self.table()

        self.advance(3.0)
        self.say("The laser is repaired: laser_resender is restarted")
        self.backend.restart("laser_resender")
        self.advance(0.5)
        self.request(lambda: m.change_mode("pilot", "f_normal_mode"))

        self.at(max(self.options.battery_low_at, self.clock.now()))
        self.say("Battery below 0.5: energy saving")
        self.request(lambda: m.change_mode("pilot", "f_energy_saving_mode"))
        self.table()
        self.say("Recharging for 10 s")
        self.advance(10.0)
        self.say("Battery recovered: back to normal")
        self.request(lambda: m.change_mode("pilot", "f_normal_mode"))
        self.table()
        return self.summary(failed)

    def summary(self, expected_failure: Request) -> int:
        self.out("")
        self.out("Summary")
        for request in self.outcomes:
            result = "ok    " if request.succeeded else "FAILED"
            took = f"{request.elapsed:5.2f} s" if request.elapsed is not None else "   -   "
            why = "" if request.succeeded else f" ({request.reason})"
            self.out(f"  {result} {took}  {request.description}{why}")
        final = str(self.manager.actual("pilot"))
        others_ok = all(r.succeeded for r in self.outcomes if r is not expected_failure)
        good = final == "active.f_normal_mode" and others_ok and not expected_failure.succeeded
        self.out(f"  pilot ends in {final}; {'as expected' if good else 'NOT as expected'}")
        return 0 if good else 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--laser-failure-at", type=float, default=12.0, metavar="SECONDS",
                        help="virtual time of the laser failure (default 12)")
    parser.add_argument("--battery-low-at", type=float, default=30.0, metavar="SECONDS",
                        help="virtual time the battery runs low (default 30)")
    parser.add_argument("--speed", type=float, default=20.0,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 20)")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")


def run(args: argparse.Namespace) -> int:
    options = Options(args.laser_failure_at, args.battery_low_at, args.speed, args.quiet)
    return Demo(options).run()
