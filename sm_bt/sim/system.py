"""SimulatedSystem: a model run by a mode manager over simulated nodes, with time in your hands.

The one way to run a model without ROS: the tests, the demo, ``sm-bt monitor``, the benchmarks and
your own tests all use it. Nothing moves until you let virtual time pass, so a run is
deterministic and seconds of robot time cost microseconds::

    from sm_bt.sim import SimulatedSystem

    robot = SimulatedSystem("docs/examples/robot.yaml")
    request = robot.finish(robot.manager.change_mode("robot", "FAST"))
    assert request.succeeded and str(robot.manager.actual("robot")) == "active.FAST"

    robot.crash("lidar")                   # a fault: the node stops answering
    robot.run(2.0)                         # two seconds pass; the manager notices

Faults are those of :class:`~sm_bt.sim.backend.SimBackend`, which the system delegates to. With
pytest, the ``simulated_system`` fixture of :mod:`sm_bt.testing` makes one and closes it.
"""

from __future__ import annotations

import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt import bundled
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.events import Event, EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.errors import Error
from sm_bt.model.loader import load_model
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim.backend import SimBackend, StartState

#: The keyword arguments of :class:`SimBackend` (the rest go to :class:`ModeManager`).
BACKEND_OPTIONS = frozenset(name for name, parameter in inspect.signature(SimBackend).parameters.items()
                            if parameter.kind is inspect.Parameter.KEYWORD_ONLY)


class NotReached(Error, AssertionError):
    """A condition did not hold within the virtual time it was given (an ``AssertionError``, so that
    pytest shows it as a failed check)."""


@dataclass(frozen=True)
class Tick:
    """What one behaviour showed after one tick of a tree."""

    time: float
    status: Status
    feedback: str


def tick_until(tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *, now: Callable[[], float],
               advance: Callable[[float], None], watch: py_trees.behaviour.Behaviour | None = None,
               step: float = 0.05, timeout: float = 10.0) -> list[Tick]:
    """Tick ``tree`` and ``advance(step)`` after each tick, until ``condition()`` holds right after a
    tick; ``now()`` tells the time (for a tree on real nodes: ``time.monotonic`` and ``time.sleep``).
    What ``watch`` (default: the root) showed at every tick; :class:`NotReached` once ``timeout``
    seconds passed without the condition."""
    watched = watch if watch is not None else tree.root
    start = now()
    trace: list[Tick] = []
    while True:
        tree.tick()
        trace.append(Tick(now(), watched.status, watched.feedback_message))
        if condition():
            return trace
        if now() - start >= timeout:
            raise NotReached(f"condition not met within {timeout:g} s; last tick of {watched.name}: {trace[-1]}")
        advance(step)


def as_model(model: Model | str | os.PathLike[str]) -> Model:
    """``model`` itself, or the model file it names (a path, or a bundled model's name: ``"pilot"``),
    loaded strictly (:class:`~sm_bt.model.errors.ModelError` when it is not valid)."""
    return model if isinstance(model, Model) else load_model(bundled.resolve(model))


class SimulatedSystem:
    """A :class:`~sm_bt.engine.manager.ModeManager` over simulated lifecycle nodes on a virtual clock.

    ``model``: a :class:`Model`, a model file or a bundled model's name. Keyword arguments named as
    :class:`~sm_bt.sim.backend.SimBackend`'s (``transition_delay``, ``initial_state``,
    ``initial_parameters``, ``history``, ...) configure the nodes, unless ``backend`` is given (a
    backend of your own over the same model); the others configure the manager (``grace_period``,
    ``request_timeout``, ``rules``, ``recovery``, ...). Every event the manager emits is kept in
    :attr:`events` unless ``record=False``.
    """

    def __init__(self, model: Model | str | os.PathLike[str], *, backend: SimBackend | None = None,
                 record: bool = True, **options: Any) -> None:
        self.model = as_model(model)
        backend_options = {name: options.pop(name) for name in list(options) if name in BACKEND_OPTIONS}
        if backend is not None and backend_options:
            raise TypeError(f"pass either backend= or options for one ({', '.join(sorted(backend_options))}), "
                            "not both")
        self.backend = backend if backend is not None else SimBackend(self.model, **backend_options)
        self.manager = ModeManager(self.model, self.backend, **options)
        #: Every event the manager emitted, oldest first (empty with ``record=False``).
        self.events: list[Event] = []
        if record:
            self.manager.subscribe(self.events.append)

    @property
    def clock(self) -> VirtualClock:
        return self.backend.clock

    def now(self) -> float:
        """Seconds of virtual time."""
        return self.backend.clock.now()

    # -- time ---------------------------------------------------------------------------------------

    def run(self, seconds: float) -> None:
        """Let ``seconds`` of virtual time pass: everything due on the way happens, in order."""
        self.backend.clock.advance(seconds)

    def run_until(self, condition: Callable[[], bool], timeout: float = 60.0, step: float | None = 0.01) -> float:
        """Let time pass ``step`` by ``step`` until ``condition()`` holds; the virtual seconds it took.
        :class:`NotReached` once ``timeout`` seconds passed without it. With ``step=None`` time jumps
        from one scheduled event to the next (the condition is checked after each), and a system with
        nothing left to do fails at once."""
        clock = self.backend.clock
        start = clock.now()
        while not condition():
            if clock.now() - start > timeout:
                raise NotReached(f"condition not met within {timeout:g} s of virtual time")
            if step is not None:
                clock.advance(step)
                continue
            due = clock.next_due()
            if due is None or due - start > timeout:
                raise NotReached(f"condition not met within {timeout:g} s of virtual time "
                                 f"({'nothing left to happen' if due is None else 'nothing due in time'})")
            clock.run_until(due)
        return clock.now() - start

    def finish(self, request: Request, timeout: float = 60.0) -> Request:
        """Let time pass until ``request`` is done (succeeded or failed); the request.
        :class:`NotReached` if it is still running after ``timeout`` seconds."""
        try:
            self.run_until(lambda: request.done, timeout)
        except NotReached:
            raise NotReached(f"{request.description} not done within {timeout:g} s of virtual time: "
                             f"{request.feedback}") from None
        return request

    def events_of(self, kind: EventKind, part: str | None = None) -> list[Event]:
        """The recorded events of ``kind`` (about ``part`` only, if given)."""
        return [event for event in self.events if event.kind is kind and (part is None or event.part == part)]

    # -- trees --------------------------------------------------------------------------------------

    def tree(self, root: py_trees.behaviour.Behaviour, **setup: Any) -> py_trees.trees.BehaviourTree:
        """A tree around ``root``, set up with this manager and its clock (and ``setup``'s other
        runtime objects)."""
        tree = py_trees.trees.BehaviourTree(root)
        tree.setup(**{"manager": self.manager, "clock": self.clock, **setup})
        return tree

    def tick_until(self, tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *,
                   watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05,
                   timeout: float = 10.0) -> list[Tick]:
        """Tick ``tree``, letting ``step`` seconds pass after each tick, until ``condition()`` holds
        right after a tick. What ``watch`` (default: the root) showed at every tick;
        :class:`NotReached` once ``timeout`` seconds passed without the condition."""
        clock = self.backend.clock
        return tick_until(tree, condition, now=clock.now, advance=clock.advance, watch=watch, step=step,
                          timeout=timeout)

    def tick_until_done(self, tree: py_trees.trees.BehaviourTree, *,
                        watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05,
                        timeout: float = 10.0) -> list[Tick]:
        """Tick until ``watch`` (default: the root) is no longer RUNNING."""
        watched = watch if watch is not None else tree.root
        return self.tick_until(tree, lambda: watched.status is not Status.RUNNING, watch=watched, step=step,
                               timeout=timeout)

    def tick_for(self, tree: py_trees.trees.BehaviourTree, seconds: float, *,
                 watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05) -> list[Tick]:
        """Tick every ``step`` for ``seconds`` of virtual time (both ends included)."""
        end = self.now() + seconds - 1e-9
        return self.tick_until(tree, lambda: self.now() >= end, watch=watch, step=step, timeout=seconds + 1.0)

    # -- faults (SimBackend's, named for what the node does) ----------------------------------------

    def fail_next(self, node: str, transition: Transition, outcome: Outcome = Outcome.FAILURE,
                  on_error: Outcome = Outcome.SUCCESS) -> None:
        """The next requested ``transition`` of ``node`` fails: its callback returns ``outcome``
        (FAILURE, or ERROR: then ``on_error`` returns ``on_error``)."""
        self.backend.fail_next(node, transition, outcome, on_error)

    def hang_next(self, node: str, transition: Transition) -> None:
        """The next requested ``transition`` of ``node`` never ends (no answer until it crashes or restarts)."""
        self.backend.hang_next(node, transition)

    def reject_parameters(self, node: str, reason: str | None) -> None:
        """Every parameter set on ``node`` fails with ``reason`` (``None``: accepted again)."""
        self.backend.reject_parameters(node, reason)

    def set_parameter(self, node: str, name: str, value: ParamValue) -> None:
        """Another client (or the node itself) sets parameter ``name`` of ``node``."""
        self.backend.set_parameter(node, name, value)

    def fail(self, node: str) -> None:
        """The active ``node`` fails by itself: deactivating, error processing, unconfigured."""
        self.backend.trigger(node, Transition.DEACTIVATE, Outcome.ERROR)

    def crash(self, node: str) -> None:
        """``node`` stops answering at once; it is reported gone after the backend's ``vanish_after``."""
        self.backend.crash(node)

    def vanish(self, node: str) -> None:
        """``node``'s process ends (it exits, or is killed): it is reported gone at once."""
        self.backend.vanish(node)

    def restart(self, node: str, state: StartState | None = None, *, unnoticed: bool = False) -> None:
        """A fresh process of ``node`` starts (unconfigured unless ``state``) with its initial parameters
        (``unnoticed``: seen as a change of the old one's state, see :meth:`SimBackend.restart`)."""
        self.backend.restart(node, state, unnoticed=unnoticed)

    def clear_faults(self, node: str | None = None) -> None:
        """Disarm what :meth:`fail_next`, :meth:`hang_next` and :meth:`reject_parameters` armed."""
        self.backend.clear_faults(node)

    # -- life ---------------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the manager (idempotent); what it knows stays readable."""
        self.manager.close()

    def __enter__(self) -> SimulatedSystem:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()


__all__ = ["BACKEND_OPTIONS", "NotReached", "SimulatedSystem", "Tick", "as_model", "tick_until"]
