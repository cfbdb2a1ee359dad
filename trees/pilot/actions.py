"""The pilot's mission actions and sensors, over the simulated world.

``tree.setup(manager=..., world=...)`` hands them the mode manager and the
:class:`~sm_bt.trees.pilot.world.World`. :class:`NavigateTo` is where modes show: the robot drives
at the speed controller_server's parameters give it (as the node reports them to the manager), and it
cannot move without an active controller and an active laser source.
"""

from __future__ import annotations

from typing import Any

import py_trees
from py_trees.common import Access, Status
from py_trees.ports import PortInformation, PortsMixin

from sm_bt.behaviours.manager_access import ManagerBehaviour, flag
from sm_bt.model.states import State
from sm_bt.model.types import Model
from sm_bt.trees.pilot.world import World

#: Blackboard keys the pilot's sensors write (booleans: True = component OK).
BATTERY_LEVEL = "/battery/level"
BATTERY_OK = "/components/battery"
LASER_SCANS_OK = "/components/laser_scans"


def _world(behaviour: py_trees.behaviour.Behaviour, kwargs: dict[str, Any]) -> World:
    world = kwargs.get("world")
    if not isinstance(world, World):
        raise RuntimeError(f"{behaviour.qualified_name}: no world: the pilot's actions drive a simulated robot, "
                           "so its trees run in `sm-bt demo` (or `sm-bt demo --ros`), or set up with "
                           "tree.setup(manager=manager, world=World())")
    return world


class _WorldBehaviour(ManagerBehaviour, register=False):
    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self._world: World | None = None

    def setup(self, **kwargs: Any) -> None:
        super().setup(**kwargs)
        self._world = _world(self, kwargs)

    @property
    def world(self) -> World:
        if self._world is None:
            raise RuntimeError(f"{self.qualified_name}: not set up (tree.setup(manager=..., world=...))")
        return self._world


class NavigateTo(_WorldBehaviour):
    """Drive to ``waypoint``.

    * ``initialise``: start measuring time (the manager's clock)
    * ``update``: advance the robot by speed x elapsed world time (the clock's, times the
      world's ``time_scale``); RUNNING on the way (feedback:
      distance and speed, or why it is stopped), SUCCESS on arrival. Never FAILURE: a robot
      without laser or controller waits, as Nav2 does, for the mode to give them back.

    Speed is ``speed_parameter`` of ``controller`` as that node reports it, while the controller
    and at least one of ``lasers`` are active; otherwise the robot stands still.
    """

    def __init__(self, name: str, waypoint: str, controller: str = "controller_server",
                 speed_parameter: str = "FollowPath.max_vel_x",
                 lasers: tuple[str, ...] = ("laser_resender", "pointcloud_to_laser"), **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.waypoint = waypoint
        self.controller = controller
        self.speed_parameter = speed_parameter
        self.lasers = lasers
        self._last = 0.0

    def check_model(self, model: Model) -> None:
        for part in (self.controller, *self.lasers):
            self._check_part(model, part)

    def setup(self, **kwargs: Any) -> None:
        super().setup(**kwargs)
        if self.waypoint not in self.world.waypoints:
            raise ValueError(f"{self.qualified_name}: unknown waypoint {self.waypoint!r} "
                             f"(waypoints: {', '.join(self.world.waypoints)})")

    def speed(self) -> tuple[float, str]:
        """The speed the robot can drive at now, and why it is zero when it is."""
        manager = self.manager
        if manager.actual(self.controller).state is not State.ACTIVE:
            return 0.0, f"{self.controller} is {manager.actual(self.controller)}"
        if not any(manager.actual(laser).state is State.ACTIVE for laser in self.lasers):
            return 0.0, "no laser scan (" + ", ".join(f"{n} {manager.actual(n)}" for n in self.lasers) + ")"
        value = manager.observation(self.controller).parameters.get(self.speed_parameter)
        if not isinstance(value, int | float) or isinstance(value, bool):
            return 0.0, f"{self.controller} has no {self.speed_parameter}"
        return float(value), ""

    def initialise(self) -> None:
        self._last = self.manager.clock.now()

    def update(self) -> Status:
        now = self.manager.clock.now()
        elapsed, self._last = self.world.world_seconds(now - self._last), now
        speed, why = self.speed()
        if self.world.drive(self.waypoint, speed * elapsed):
            self.feedback_message = f"at {self.waypoint}"
            return Status.SUCCESS
        distance = self.world.distance_to(self.waypoint)
        self.feedback_message = (f"{distance:.1f} m to {self.waypoint} at {speed:g} m/s" if speed
                                 else f"stopped {distance:.1f} m before {self.waypoint}: {why}")
        return Status.RUNNING


class Visited(_WorldBehaviour):
    """Has the robot reached ``waypoint`` in this patrol round? SUCCESS if it has, FAILURE if
    not; never RUNNING. Before a :class:`NavigateTo`, it lets a patrol interrupted by a recharge
    carry on where it was."""

    def __init__(self, name: str, waypoint: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.waypoint = waypoint

    def update(self) -> Status:
        if self.waypoint in self.world.visited:
            self.feedback_message = f"{self.waypoint} visited"
            return Status.SUCCESS
        self.feedback_message = f"{self.waypoint} not visited yet"
        return Status.FAILURE


class CompleteRound(_WorldBehaviour):
    """The end of a patrol round: count it and forget the waypoints visited. Always SUCCESS."""

    def update(self) -> Status:
        self.world.new_round()
        self.feedback_message = f"round {self.world.rounds} complete"
        return Status.SUCCESS


class Recharge(_WorldBehaviour):
    """Charge for ``duration`` seconds of world time (the pilot's 10 s), then the battery is full.

    RUNNING while charging, SUCCESS when done.
    """

    def __init__(self, name: str, duration: float = 10.0, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.duration = duration
        self._started = 0.0

    def initialise(self) -> None:
        self._started = self.manager.clock.now()

    def update(self) -> Status:
        elapsed = self.world.world_seconds(self.manager.clock.now() - self._started)
        if elapsed >= self.duration:
            self.world.recharge()
            self.feedback_message = "battery full"
            return Status.SUCCESS
        self.feedback_message = f"charging: {self.duration - elapsed:.1f} s left"
        return Status.RUNNING


class BatteryToBlackboard(_WorldBehaviour):
    """The pilot's battery monitor: the level, and the component status with hysteresis
    (failed below ``low``, recovered above ``recovered``), on the blackboard. Always SUCCESS."""

    def __init__(self, name: str = "Battery to Blackboard", low: float = 0.5, recovered: float = 0.8,
                 **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.low = low
        self.recovered = recovered
        self.blackboard = self.attach_blackboard_client(name)
        self.blackboard.register_key(BATTERY_LEVEL, access=Access.WRITE)
        self.blackboard.register_key(BATTERY_OK, access=Access.WRITE)
        self._ok: bool | None = None

    def update(self) -> Status:
        level = self.world.battery
        if self._ok is None:
            self._ok = level >= self.low
        elif self._ok and level < self.low:
            self._ok = False
        elif not self._ok and level > self.recovered:
            self._ok = True
        self.blackboard.set(BATTERY_LEVEL, level)
        self.blackboard.set(BATTERY_OK, self._ok)
        self.feedback_message = f"battery {level:.2f} ({'OK' if self._ok else 'LOW'})"
        return Status.SUCCESS


class ScansToBlackboard(_WorldBehaviour):
    """Whether the laser's scans are healthy (the world's laser works), on the blackboard.
    Always SUCCESS."""

    def __init__(self, name: str = "Scans to Blackboard", **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.blackboard = self.attach_blackboard_client(name)
        self.blackboard.register_key(LASER_SCANS_OK, access=Access.WRITE)

    def update(self) -> Status:
        self.blackboard.set(LASER_SCANS_OK, self.world.laser_ok)
        self.feedback_message = "scans OK" if self.world.laser_ok else "scans all zero"
        return Status.SUCCESS


def comparison(value: float, threshold: float) -> str:
    """``0.61 ≥ 0.5`` or ``0.497 < 0.5``: two decimals, or as many as the comparison needs to
    read true (0.4996 is not ``0.50 < 0.5``)."""
    sign = "≥" if value >= threshold else "<"
    for digits in range(2, 7):
        text = f"{value:.{digits}f}"
        if (float(text) >= threshold) == (value >= threshold):
            break
    return f"{text} {sign} {threshold:g}"


def _words(key: str) -> str:
    """A blackboard key as a reader says it: ``/battery/level`` -> ``battery level``."""
    return key.strip("/").replace("/", " ").replace("_", " ")


class _BlackboardCheck(PortsMixin, py_trees.behaviour.Behaviour, register=False):
    """A check of one blackboard variable, ``key`` (read only); no ports."""

    INPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012

    def __init__(self, name: str, key: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.key = key
        self.blackboard = self.attach_blackboard_client(name)
        self.blackboard.register_key(key, access=Access.READ)

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        if port_remappings:
            raise KeyError(f"{self.name}: no ports (given: {', '.join(port_remappings)})")
        self._subtree_namespace = subtree_namespace

    def _current(self) -> Any:
        """The value at ``key``, ``None`` while nothing was written."""
        return self.blackboard.get(self.key) if self.blackboard.exists(self.key) else None


class LevelAtLeast(_BlackboardCheck):
    """Is the number at blackboard ``key`` at least ``threshold``? SUCCESS if it is, FAILURE if
    it is below (or nothing was written yet); never RUNNING. The feedback is the comparison as a
    person reads it (``battery level 0.48 < 0.5``). In XML
    ``<LevelAtLeast name="Battery OK?" key="/battery/level" threshold="0.5"/>``."""

    def __init__(self, name: str, key: str, threshold: float | str, **kwargs: Any) -> None:
        try:
            self.threshold = float(threshold)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: threshold must be a number, not {threshold!r}") from None
        super().__init__(name, key, **kwargs)

    def update(self) -> Status:
        """SUCCESS when the value is at least the threshold, FAILURE otherwise."""
        value = self._current()
        if not isinstance(value, int | float) or isinstance(value, bool):
            self.feedback_message = f"no {_words(self.key)} yet"
            return Status.FAILURE
        self.feedback_message = f"{_words(self.key)} {comparison(value, self.threshold)}"
        return Status.SUCCESS if value >= self.threshold else Status.FAILURE


class FlagIs(_BlackboardCheck):
    """Does the boolean blackboard variable ``key`` hold ``value``? SUCCESS if it does,
    FAILURE if not (or if nothing was written yet); never RUNNING. In XML
    ``<FlagIs name="Battery low?" key="/components/battery" value="false"/>``."""

    def __init__(self, name: str, key: str, value: bool | str = True, **kwargs: Any) -> None:
        self.value = flag(name, value, "value")
        super().__init__(name, key, **kwargs)

    def update(self) -> Status:
        """SUCCESS when ``key`` is ``value``, FAILURE otherwise."""
        current = self._current()
        if current is None:
            self.feedback_message = f"no {_words(self.key)} yet"
        elif self.key.startswith("/components/") and isinstance(current, bool):  # True = component OK
            self.feedback_message = f"{_words(self.key[len('/components/'):])} {'OK' if current else 'failed'}"
        else:
            self.feedback_message = f"{_words(self.key)} is {current}"
        return Status.SUCCESS if current is self.value else Status.FAILURE
