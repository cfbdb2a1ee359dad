"""One way to run a behaviour scenario on either backend.

A scenario (see ``behaviour_scenarios.py``) gets a :class:`Harness`: the manager to set trees up
with, a way to tick a tree while time passes, and the faults it needs, named for what the node
does (a transition's callback fails, parameter sets are rejected, the node fails by itself).
:class:`SimHarness` runs them on simulated nodes and virtual time; the ROS harness
(``ros_harness.py``) on real rclpy lifecycle nodes in another process and wall time. The
scenarios themselves do not know which one they run on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import py_trees
from tree_helpers import Tick

from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.types import Model
from sm_bt.sim import SimBackend

#: Manager options every scenario runs with (no recovery: the scenarios look at what happens).
MANAGER_OPTIONS: dict[str, object] = {"grace_period": 0.5, "request_timeout": 10.0, "recovery": False}


class Harness(Protocol):
    manager: ModeManager

    def now(self) -> float:
        """Seconds on the manager's clock."""

    def tick_until(self, tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *,
                   limit: float = 10.0, step: float = 0.05) -> list[Tick]:
        """Tick every ``step`` s until ``condition()`` holds after a tick; fail after ``limit`` s."""

    def settle(self, request: Request, limit: float = 10.0) -> None:
        """Let a request made on the manager finish; it must succeed."""

    def wait(self, condition: Callable[[], bool], limit: float = 10.0) -> None:
        """Let time pass until ``condition()`` holds; fail after ``limit`` s."""

    def fail_next(self, node: str, transition: Transition) -> None:
        """The next requested ``transition`` of ``node`` fails (its callback returns FAILURE)."""

    def reject_parameters(self, node: str, reason: str) -> None:
        """Every parameter set on ``node`` is rejected with ``reason``."""

    def break_node(self, node: str) -> None:
        """The active ``node`` fails by itself: deactivating -> errorprocessing -> unconfigured."""


def tick_loop(tree: py_trees.trees.BehaviourTree, now: Callable[[], float], advance: Callable[[float], None],
              condition: Callable[[], bool], limit: float, step: float) -> list[Tick]:
    start = now()
    trace: list[Tick] = []
    while True:
        tree.tick()
        trace.append(Tick(now(), tree.root.status, tree.root.feedback_message))
        if condition():
            return trace
        if now() - start >= limit:
            raise AssertionError(f"condition not met within {limit} s; last tick of {tree.root.name}: {trace[-1]}")
        advance(step)


def wait_loop(now: Callable[[], float], advance: Callable[[float], None], condition: Callable[[], bool],
              limit: float, step: float = 0.01) -> None:
    start = now()
    while not condition():
        if now() - start > limit:
            raise AssertionError(f"condition not met within {limit} s")
        advance(step)


class SimHarness:
    """Simulated nodes, virtual time."""

    def __init__(self, model: Model) -> None:
        self.backend = SimBackend(model, transition_delay=0.05, parameter_delay=0.01)
        self.clock = self.backend.clock
        self.manager = ModeManager(model, self.backend, **MANAGER_OPTIONS)  # type: ignore[arg-type]

    def now(self) -> float:
        return self.clock.now()

    def tick_until(self, tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *,
                   limit: float = 10.0, step: float = 0.05) -> list[Tick]:
        return tick_loop(tree, self.now, self.clock.advance, condition, limit, step)

    def settle(self, request: Request, limit: float = 10.0) -> None:
        self.wait(lambda: request.done, limit)
        assert request.succeeded, request.reason

    def wait(self, condition: Callable[[], bool], limit: float = 10.0) -> None:
        wait_loop(self.now, self.clock.advance, condition, limit)

    def fail_next(self, node: str, transition: Transition) -> None:
        self.backend.fail_next(node, transition)

    def reject_parameters(self, node: str, reason: str) -> None:
        self.backend.reject_parameters(node, reason)

    def break_node(self, node: str) -> None:
        self.backend.trigger(node, Transition.DEACTIVATE, Outcome.ERROR)

    def close(self) -> None:
        self.manager.close()
