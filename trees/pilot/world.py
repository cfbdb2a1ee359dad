"""A small simulated world for the MROS pilot: a robot on a plane, its battery and its laser.

The robot drives straight toward a waypoint at the speed it is given; the battery drains per
metre as the pilot's battery simulator does (0.7 at start, -0.02 per metre, 1.0 after a
recharge). World time can run faster than the clock that measures it (``time_scale``): the
demo on real ROS nodes lets the mission run many times faster than the mode changes, which take
real time. The laser can break and be repaired; :class:`LaserDevice` makes the simulated
``laser_resender`` node fail by itself while its scans are broken, as the real node does when it
receives all-zero scans (deactivate -> on_deactivate ERROR -> errorprocessing -> unconfigured).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.model.states import State
from sm_bt.sim.backend import NodeStatus, SimBackend

Point = tuple[float, float]

#: The pilot's patrol waypoints and recharge station (x, y in metres; TB3 house coordinates).
PILOT_WAYPOINTS: dict[str, Point] = {
    "wp_1": (1.0, -1.0),
    "wp_2": (-1.0, 1.0),
    "wp_3": (-3.5, 1.0),
    "wp_4": (-6.25, 2.66),
    "wp_5": (-6.40, -2.81),
    "wp_6": (-6.25, 2.66),
    "wp_7": (-1.0, 1.0),
    "recharge_station": (4.0, -3.0),
}
PATROL = tuple(f"wp_{i}" for i in range(1, 8))


@dataclass
class World:
    """Where the robot is, how much battery it has left and whether its laser works.

    ``time_scale`` is how many world seconds pass per second of the clock the actions measure
    time with (the mode manager's): 1 on the simulated backend's virtual clock; more on a wall
    clock, so that a mission of minutes takes seconds while mode changes stay real.
    """

    waypoints: dict[str, Point] = field(default_factory=lambda: dict(PILOT_WAYPOINTS))
    position: Point = (0.0, 0.0)
    battery: float = 0.7
    drain_per_metre: float = 0.02
    laser_ok: bool = True
    odometer: float = 0.0
    time_scale: float = 1.0
    #: Waypoints reached since the patrol round began (:meth:`new_round`).
    visited: set[str] = field(default_factory=set)
    rounds: int = 0

    def __post_init__(self) -> None:
        if not (self.time_scale > 0.0 and math.isfinite(self.time_scale)):
            raise ValueError(f"time_scale must be a finite number > 0, not {self.time_scale!r}")

    def world_seconds(self, clock_seconds: float) -> float:
        """How much world time passes in ``clock_seconds`` of the manager's clock."""
        return clock_seconds * self.time_scale

    def distance_to(self, waypoint: str) -> float:
        x, y = self.waypoints[waypoint]
        return math.hypot(x - self.position[0], y - self.position[1])

    def drive(self, waypoint: str, distance: float) -> bool:
        """Move up to ``distance`` metres toward ``waypoint``; True once there."""
        if waypoint not in self.waypoints:
            raise KeyError(f"unknown waypoint {waypoint!r} (waypoints: {', '.join(self.waypoints)})")
        remaining = self.distance_to(waypoint)
        step = min(max(distance, 0.0), remaining)
        if remaining > 0.0:
            x, y = self.waypoints[waypoint]
            fraction = step / remaining
            self.position = (self.position[0] + (x - self.position[0]) * fraction,
                             self.position[1] + (y - self.position[1]) * fraction)
        self.odometer += step
        self.battery = max(0.0, self.battery - step * self.drain_per_metre)
        if remaining - step <= 1e-9:
            self.visited.add(waypoint)
            return True
        return False

    def new_round(self) -> None:
        """A patrol round is complete: count it, and start the next with no waypoint visited."""
        self.rounds += 1
        self.visited.clear()

    def recharge(self) -> None:
        self.battery = 1.0


class LaserDevice:
    """Couples the world's laser to the simulated laser_resender node: while the laser is broken,
    an active laser_resender fails by itself (its next scans are all zeros)."""

    def __init__(self, world: World, backend: SimBackend, node: str = "laser_resender") -> None:
        self.world = world
        self.backend = backend
        self.node = node
        self.failures = 0

    def break_laser(self) -> None:
        self.world.laser_ok = False
        self.update()

    def repair(self) -> None:
        self.world.laser_ok = True

    def update(self) -> None:
        """Call after every clock step: fail the node if it is active on a broken laser."""
        if self.world.laser_ok or self.backend.status(self.node) is not NodeStatus.RUNNING:
            return
        if self.backend.node(self.node).state is State.ACTIVE:
            self.backend.trigger(self.node, Transition.DEACTIVATE, outcome=Outcome.ERROR)
            self.failures += 1


class PilotWorld:
    """The pilot's world in a scenario (``world: sm_bt.trees.pilot.world:PilotWorld``, see
    :mod:`sm_bt.scenario`): the robot, its battery and its laser, with the event ``laser:
    broken|repaired``. On simulated nodes :class:`LaserDevice` makes laser_resender fail while the
    laser is broken; on ROS 2 its ``sim.broken`` parameter does."""

    events: ClassVar[dict[str, tuple[str, ...]]] = {"laser": ("broken", "repaired")}

    def __init__(self) -> None:
        self.world = World()
        self._device: LaserDevice | None = None
        self._set_broken: Callable[[bool], None] | None = None

    def attach(self, system: Any) -> dict[str, Any]:
        backend = getattr(system, "backend", None)
        if isinstance(backend, SimBackend):
            self._device = LaserDevice(self.world, backend)
        else:
            self._set_broken = lambda broken: system.set_parameter("laser_resender", "sim.broken", broken)
        return {"world": self.world}

    def advance(self) -> None:
        if self._device is not None:
            self._device.update()

    def event(self, name: str, value: str) -> None:
        broken = value == "broken"
        if self._device is not None:
            if broken:
                self._device.break_laser()
            else:
                self._device.repair()
        else:
            self.world.laser_ok = not broken
            if self._set_broken is not None:
                self._set_broken(broken)
