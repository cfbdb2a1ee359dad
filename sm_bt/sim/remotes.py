"""Managers of managers without ROS: a fleet model's remote parts, each served by a manager of its own.

:class:`RemoteManagers` is the backend of a model whose nodes are all remote parts (``type:
remote``, :mod:`sm_bt.model.remote_parts`): each is the top system (``system:``) of a robot's own
:class:`~sm_bt.sim.system.SimulatedSystem`, on the fleet's virtual clock. A fleet request reaches a
robot as its manager's ``change_mode``/``change_state`` and ends when that manager's request ends,
so a fleet change takes as long as its robots' own changes; what the robots' managers infer comes
back as the remote parts' state and mode (``REMOTE_MODE``). A robot cut off (:meth:`cut`) is out of
reach for the fleet, whatever its own manager does meanwhile; after :meth:`heal` the fleet reads
its state and mode again::

    fleet = simulated_fleet("fleet.yaml", {"robot1": "pilot", "robot2": "pilot"})
    fleet.finish(fleet.manager.change_mode("fleet", "NIGHT"))

Every report and answer is handed over at the next instant of the clock, never from inside the
robot's manager, so the two managers never call each other re-entrantly.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.events import Event, EventKind, Subscription
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.errors import Error
from sm_bt.model.states import State
from sm_bt.model.types import FLEET_REQUESTER, REMOTE_MODE, Model, ParamValue
from sm_bt.sim.backend import SimBackend
from sm_bt.sim.system import BACKEND_OPTIONS, SimulatedSystem, as_model


class NotAFleet(Error, ValueError):
    """A model given to :class:`RemoteManagers` has local nodes, or robots that do not match it."""


class RemoteManagers:
    """The simulated backend of ``model``'s remote parts: ``robots`` maps each to the system that
    serves it (the robot's manager, on ``clock``)."""

    def __init__(self, model: Model, robots: Mapping[str, SimulatedSystem], clock: VirtualClock) -> None:
        local = [node.name for node in model.nodes if node.remote is None]
        if local:
            raise NotAFleet(f"{model.path}: {', '.join(local[:5])} are nodes; a fleet of simulated managers has "
                            "remote parts only (run local nodes in a robot's own model)")
        missing = sorted({node.name for node in model.nodes} - set(robots))
        if missing or set(robots) - {node.name for node in model.nodes}:
            raise NotAFleet(f"{model.path}: the robots must be the remote parts, {', '.join(sorted(robots))} given, "
                            f"{', '.join(missing) or 'none'} missing")
        self._clock = clock
        self._robots = dict(robots)
        self._system: dict[str, str] = {}
        for node in model.nodes:
            assert node.remote is not None
            robot = robots[node.name]
            if robot.clock is not clock:
                raise NotAFleet(f"robot {node.name}: its system runs on another clock than the fleet's")
            if node.remote.system not in robot.model.parts:
                raise NotAFleet(f"robot {node.name}: its model {robot.model.path} has no part {node.remote.system!r}")
            offered = set(robot.manager.available_modes(node.remote.system))
            unknown = sorted(set(node.modes) - offered)
            if unknown:
                raise NotAFleet(f"robot {node.name}: {node.remote.system} of {robot.model.path} has no mode "
                                f"{', '.join(unknown)} (it offers {', '.join(sorted(offered))})")
            self._system[node.name] = node.remote.system
        self._listener: BackendListener | None = None
        self._subscriptions: list[Subscription] = []
        self._cut: set[str] = set()

    @property
    def clock(self) -> VirtualClock:
        return self._clock

    # -- the backend protocol -----------------------------------------------------------------------

    def attach(self, nodes: Sequence[str], listener: BackendListener) -> None:
        self._listener = listener
        for robot in nodes:
            self._subscriptions.append(self._robots[robot].manager.subscribe(
                self._observer(robot), self._system[robot], kinds=(EventKind.ACTUAL,)))
            self._later(self._appearing(robot))

    def detach(self) -> None:
        for subscription in self._subscriptions:
            subscription.cancel()
        self._subscriptions.clear()
        self._listener = None

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        self._ask(node, lambda manager, system: manager.change_state(system, transition, requester=FLEET_REQUESTER),
                  done)

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        mode = parameters.get(REMOTE_MODE)
        if not isinstance(mode, str) or set(parameters) != {REMOTE_MODE}:
            self._later(lambda: done(CallResult(False, f"{node} is a remote part: only its mode can be asked")))
            return
        self._ask(node, lambda manager, system: manager.change_mode(system, mode, requester=FLEET_REQUESTER), done)

    # -- faults ---------------------------------------------------------------------------------------

    def cut(self, robot: str) -> None:
        """The robot's manager is out of the fleet's reach (a partition): the fleet hears of it as
        out of reach at once (its liveness is not simulated), and of nothing it does until healed."""
        self._cut.add(self._require(robot))
        self._later(lambda: self._listener.node_vanished(robot, f"no answer from the manager of {robot} "
                                                                "(partitioned)") if self._listener else None)

    def heal(self, robot: str) -> None:
        """The robot's manager is reachable again: the fleet reads its state and mode afresh."""
        self._cut.discard(self._require(robot))
        self._later(self._appearing(robot))

    # -- helpers ---------------------------------------------------------------------------------------

    def _ask(self, robot: str, send: Callable[[ModeManager, str], Request], done: Done) -> None:
        self._require(robot)
        if robot in self._cut:  # the request is lost, as over a cut link: the fleet's timeout tells
            return
        request = send(self._robots[robot].manager, self._system[robot])
        request.add_done_callback(lambda finished: self._later(
            lambda: done(CallResult(finished.succeeded, finished.reason, refused=finished.refused))))

    def _appear(self, robot: str) -> None:
        if self._listener is None or robot in self._cut:
            return
        actual = self._robots[robot].manager.actual(self._system[robot])
        if actual.state is State.UNKNOWN:
            self._listener.node_vanished(robot, f"{robot}: {actual.reason or 'unknown to its own manager'}")
            return
        self._listener.node_appeared(robot, NodeReport(actual.state, {REMOTE_MODE: actual.mode or ""}))

    def _actual(self, robot: str, event: Event) -> None:
        if self._listener is None or robot in self._cut or event.actual is None:
            return
        before, now = event.previous, event.actual
        if now.state is State.UNKNOWN:
            self._listener.node_vanished(robot, f"{robot}: {now.reason or 'unknown to its own manager'}")
            return
        if before is None or before.state is State.UNKNOWN:
            self._appear(robot)
            return
        if now.state is not before.state:
            self._listener.node_state(robot, now.state)
        if now.mode is not None and now.mode != before.mode:
            self._listener.node_parameters(robot, {REMOTE_MODE: now.mode})

    def _observer(self, robot: str) -> Callable[[Event], None]:
        return lambda event: self._later(lambda: self._actual(robot, event))

    def _appearing(self, robot: str) -> Callable[[], None]:
        return lambda: self._appear(robot)

    def _later(self, action: Callable[[], None]) -> None:
        self._clock.call_later(0.0, action)

    def _require(self, robot: str) -> str:
        if robot not in self._robots:
            raise ValueError(f"{robot!r} is not a robot of the fleet ({', '.join(sorted(self._robots))})")
        return robot


def simulated_fleet(model: Model | str | os.PathLike[str], robots: Mapping[str, Model | str | os.PathLike[str]],
                    **options: Any) -> tuple[SimulatedSystem, dict[str, SimulatedSystem]]:
    """The fleet's system over its robots' own systems, on one virtual clock: ``robots`` maps each
    remote part to its robot's model (a model, its file or a bundled name). ``options`` named as
    :class:`SimBackend`'s go to the robots' nodes, the others to every manager (the fleet's and
    the robots')."""
    fleet_model = as_model(model)
    clock = VirtualClock()
    nodes = {name: value for name, value in options.items() if name in BACKEND_OPTIONS}
    managers = {name: value for name, value in options.items() if name not in BACKEND_OPTIONS}
    systems = {}
    for name, robot in robots.items():
        robot_model = as_model(robot)
        systems[name] = SimulatedSystem(robot_model, backend=SimBackend(robot_model, clock, **nodes), **managers)
    backend = RemoteManagers(fleet_model, systems, clock)
    # Its faults are the backend's (cut, heal), not SimBackend's that SimulatedSystem delegates to.
    return SimulatedSystem(fleet_model, backend=backend, **managers), systems  # type: ignore[arg-type]
