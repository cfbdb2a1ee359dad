"""What the pilot's demo runs on (:class:`Platform`): simulated nodes on a virtual clock, or the
pilot's nodes as rclpy lifecycle nodes managed over ROS 2 (:mod:`sm_bt.trees.pilot.ros_platform`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

import py_trees

from sm_bt.engine.clock import Clock
from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model
from sm_bt.sim import SimulatedSystem
from sm_bt.trees.pilot.world import LaserDevice, World

#: What Nav2's parameter files give the nodes before any mode is applied (the pilot's TB3 set-up).
NAV2_PARAMETERS = {
    "amcl": {"transform_tolerance": 2.0},
    "controller_server": {"FollowPath.max_vel_x": 0.4, "FollowPath.max_speed_xy": 0.4},
}
#: The manager's options on both platforms. One recovery attempt: a laser that fails again at once
#: is then left to the tree.
MANAGER_OPTIONS: dict[str, Any] = {"request_timeout": 10.0, "grace_period": 1.0, "recovery_attempts": 1}


class Platform(Protocol):
    """What the demo runs on: the manager, how time passes between ticks, and the laser's node.

    The demo owns the world and the tree; a platform supplies the manager (whose clock the
    actions measure time with), lets ``tick`` seconds of that clock pass between ticks, and makes
    the laser's node fail by itself while the laser is broken.
    """

    manager: ModeManager
    #: Seconds of the manager's clock between ticks.
    tick: float
    #: "virtual" or "wall": what the manager's clock measures, for the narrative and the summary.
    time_unit: str
    #: What the nodes are, for the narrative ("simulated nodes", ...).
    description: str

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of the manager's clock pass (the nodes act meanwhile)."""

    def break_laser(self) -> None:
        """The laser breaks: ``world.laser_ok`` becomes false and the node fails by itself while it is."""

    def repair_laser(self) -> None:
        """The laser works again (``world.laser_ok``); its node no longer fails."""

    def serve(self, tree: py_trees.trees.BehaviourTree) -> None:
        """Make ``tree`` visible to the platform's tools (on ROS: py_trees_ros snapshot streams)."""

    def close(self) -> None:
        """Release what the platform started; idempotent."""


class SimulatedPlatform:
    """Simulated nodes on a virtual clock, paced to ``speed`` virtual seconds per wall second
    (0: as fast as possible); the laser through :class:`LaserDevice`."""

    time_unit = "virtual"
    description = "simulated nodes"

    def __init__(self, model: Model, world: World, *, tick: float, speed: float) -> None:
        self.system = SimulatedSystem(model, transition_delay=0.2, parameter_delay=0.05,
                                      initial_parameters=NAV2_PARAMETERS, record=False, **MANAGER_OPTIONS)
        self.manager = self.system.manager
        self.laser = LaserDevice(world, self.system.backend)
        self.tick = tick
        self.speed = speed

    @property
    def clock(self) -> Clock:
        return self.system.clock

    def advance(self, seconds: float) -> None:
        self.system.run(seconds)
        self.laser.update()
        if self.speed > 0:
            time.sleep(seconds / self.speed)

    def break_laser(self) -> None:
        self.laser.break_laser()

    def repair_laser(self) -> None:
        self.laser.repair()

    def serve(self, tree: py_trees.trees.BehaviourTree) -> None:
        pass  # no tools to serve without ROS

    def close(self) -> None:
        pass  # nothing runs in the background; the manager stays readable after the run


def ros_platform(model: Model, world: World, say: Callable[[str], None]) -> Platform:
    """The pilot's nodes as rclpy lifecycle nodes in a child process, managed over ROS 2 from here
    (:class:`sm_bt.trees.pilot.ros_platform.RosPlatform`; imported here: it needs the ros extra)."""
    from sm_bt.trees.pilot.ros_platform import RosPlatform

    return RosPlatform(model, str(model.path), world, manager_options=MANAGER_OPTIONS,
                       initial_parameters=NAV2_PARAMETERS, say=say)
