"""One way to run a behaviour scenario on either backend.

A scenario (see ``behaviour_scenarios.py``) gets a :class:`Harness`: the manager to set trees up
with, a way to tick a tree while time passes, and the faults it needs, named for what the node
does (a transition's callback fails, parameter sets are rejected, the node fails by itself).
:func:`sim_harness` runs them on simulated nodes and virtual time (a
:class:`~sm_bt.sim.SimulatedSystem`, whose names the protocol takes); the ROS harness
(``ros_harness.py``) on real rclpy lifecycle nodes in another process and wall time. The scenarios
themselves do not know which one they run on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import py_trees

from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.types import Model
from sm_bt.sim import SimulatedSystem, Tick

#: Manager options every scenario runs with (no recovery: the scenarios look at what happens).
MANAGER_OPTIONS: dict[str, object] = {"grace_period": 0.5, "request_timeout": 10.0, "recovery": False}


class Harness(Protocol):
    manager: ModeManager

    def now(self) -> float:
        """Seconds on the manager's clock."""

    def tree(self, root: py_trees.behaviour.Behaviour) -> py_trees.trees.BehaviourTree:
        """A tree around ``root``, set up with the manager."""

    def tick_until(self, tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *,
                   step: float = 0.05, timeout: float = 10.0) -> list[Tick]:
        """Tick every ``step`` s until ``condition()`` holds after a tick; fail after ``timeout`` s."""

    def run_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> float:
        """Let time pass until ``condition()`` holds; fail after ``timeout`` s."""

    def finish(self, request: Request, timeout: float = 10.0) -> Request:
        """Let time pass until ``request`` is done."""

    def fail_next(self, node: str, transition: Transition) -> None:
        """The next requested ``transition`` of ``node`` fails (its callback returns FAILURE)."""

    def reject_parameters(self, node: str, reason: str) -> None:
        """Every parameter set on ``node`` is rejected with ``reason``."""

    def fail(self, node: str) -> None:
        """The active ``node`` fails by itself: deactivating -> errorprocessing -> unconfigured."""


def sim_harness(model: Model) -> SimulatedSystem:
    """Simulated nodes, virtual time."""
    return SimulatedSystem(model, transition_delay=0.05, parameter_delay=0.01, **MANAGER_OPTIONS)


def settle(harness: Harness, request: Request, timeout: float = 10.0) -> Request:
    """Let a request made directly on the manager finish; it must succeed."""
    harness.finish(request, timeout)
    assert request.succeeded, request.reason
    return request
