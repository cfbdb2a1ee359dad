"""What ``sm-bt demo --fleet`` runs on: the fleet's manager over two robots, and how a robot is cut off.

:class:`FleetPlatform` is what :class:`~sm_bt.trees.fleet.demo.FleetDemo` needs of it. :class:`SimulatedFleet`
is the default: the robots' managers and nodes simulated, all on one virtual clock, and a cut a
partition of the simulated network. :class:`~sm_bt.trees.fleet.ros_platform.RosFleet` (``--ros``) runs
real processes instead.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Protocol

from sm_bt.bundled import path as bundled_model
from sm_bt.engine.events import Event, EventKind, Subscription
from sm_bt.engine.manager import ModeManager
from sm_bt.sim.remotes import RemoteManagers, simulated_fleet

#: Each robot's model (bundled), the robots, and the robot the demo cuts off.
ROBOT_MODEL, ROBOTS, CUT_ROBOT = "pilot", ("robot1", "robot2"), "robot1"
#: How long each of the simulated robots' node transitions takes (virtual seconds).
TRANSITION_DELAY = 0.3

#: ``tell(robot, text, ended)``: a robot's own request, as its manager tells it (``ended``: None when
#: it starts, else whether it succeeded).
RobotTeller = Callable[[str, str, bool | None], None]


class FleetPlatform(Protocol):
    """The fleet's manager (``manager``, over the bundled ``fleet`` model) and its robots."""

    #: What the robots are, for the narrative.
    description: str
    #: The unit of :meth:`now`: "virtual" or "wall".
    time_unit: str
    manager: ModeManager
    robots: list[str]

    def now(self) -> float:
        """Seconds since the platform started, in its :attr:`time_unit`."""

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of the platform's time pass."""

    def follow_robots(self, tell: RobotTeller) -> None:
        """Tell each robot's own requests from now on."""

    def cut(self, robot: str) -> str:
        """Cut ``robot`` off from the fleet; what happened, for the narrative."""

    def heal(self, robot: str) -> str:
        """Undo :meth:`cut`; what happened."""

    def robot_view(self, robot: str) -> str:
        """``robot``'s system as its own manager says it (``active.MODE``, a state, or why not known)."""

    def close(self) -> None:
        """Stop everything it started; idempotent."""


class SimulatedFleet:
    """Simulated managers of managers (:func:`sm_bt.sim.remotes.simulated_fleet`), paced to ``speed``
    virtual seconds per wall second (0: as fast as possible)."""

    description = "simulated managers of managers"
    time_unit = "virtual"

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self.fleet, self.systems = simulated_fleet(bundled_model("fleet"), {name: ROBOT_MODEL for name in ROBOTS},
                                                   transition_delay=TRANSITION_DELAY)
        self.manager = self.fleet.manager
        backend = self.fleet.backend
        assert isinstance(backend, RemoteManagers)
        self._backend: RemoteManagers = backend
        self.robots = list(self.systems)
        self._subscriptions: list[Subscription] = []

    def now(self) -> float:
        return self.fleet.now()

    def advance(self, seconds: float) -> None:
        self.fleet.run(seconds)
        if self.speed > 0:
            time.sleep(seconds / self.speed)

    def follow_robots(self, tell: RobotTeller) -> None:
        def told(robot: str, event: Event) -> None:
            request = event.request
            if request is not None:
                ended = None if event.text.endswith(" started") else request.succeeded
                tell(robot, f"{event.message} [{request.requester}]" if ended is None else event.message, ended)

        for name, system in self.systems.items():
            self._subscriptions.append(system.manager.subscribe(functools.partial(told, name),
                                                                kinds=(EventKind.REQUEST,)))

    def cut(self, robot: str) -> str:
        self._backend.cut(robot)
        return f"{robot} is cut off from the fleet (its own manager and nodes go on)"

    def heal(self, robot: str) -> str:
        self._backend.heal(robot)
        return f"{robot} is reachable again"

    def robot_view(self, robot: str) -> str:
        return str(self.systems[robot].manager.actual(ROBOT_MODEL))

    def close(self) -> None:
        for subscription in self._subscriptions:
            subscription.cancel()
        self._subscriptions = []
        self.fleet.close()
        for system in self.systems.values():
            system.close()
