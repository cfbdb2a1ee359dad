"""Requests and their execution plans.

A :class:`Request` is the caller's handle on a change (``done``, ``succeeded``, ``reason``,
``feedback``); it never blocks. Its plan is a tree of jobs: a :class:`NodeJob` drives one node
to its target (parameters, then the lifecycle path, one step at a time, each step confirmed from
what the node reports); :class:`Sequence` and :class:`Parallel` compose them in the model's
switching order. Jobs are *pumped*: whenever anything happens, the manager calls ``pump()`` on
the root and each job takes its next step if it can.
"""

from __future__ import annotations

import enum
import itertools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Protocol

from sm_bt.engine.backend import CallResult, Done
from sm_bt.engine.clock import TimerHandle
from sm_bt.engine.inference import NodeObservation
from sm_bt.engine.lifecycle import PlanError, Transition, plan
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import NodeMode, ParamValue


class Origin(str, enum.Enum):
    """Who asked for a change."""

    USER = "user"
    RULE = "rule"
    RECOVERY = "recovery"


_ids = itertools.count(1)


class Request:
    """A change in progress. Poll it (``done``, ``succeeded``, ``reason``, ``feedback``) or add a
    done-callback; ``cancel()`` withdraws it."""

    def __init__(self, part: str, target: StateMode, description: str, origin: Origin, created: float,
                 withdraw: Callable[[Request], None] | None = None) -> None:
        self.id = next(_ids)
        self.part = part
        self.target = target
        self.description = description
        self.origin = origin
        self.created = created
        self.finished: float | None = None
        self.done = False
        self.succeeded = False
        self.reason = ""
        self.feedback = "queued"
        self._withdraw = withdraw
        self._callbacks: list[Callable[[Request], None]] = []

    def cancel(self) -> None:
        """Withdraw the request: no further steps are sent, and the parts' previous targets are
        restored (what already changed is then handled like any other divergence)."""
        if not self.done and self._withdraw is not None:
            self._withdraw(self)

    def add_done_callback(self, callback: Callable[[Request], None]) -> None:
        """Call ``callback(request)`` when done (at once if it already is)."""
        if self.done:
            callback(self)
        else:
            self._callbacks.append(callback)

    @property
    def elapsed(self) -> float | None:
        return None if self.finished is None else self.finished - self.created

    def _finish(self, succeeded: bool, reason: str, now: float) -> None:
        if self.done:
            return
        self.done, self.succeeded, self.reason, self.finished = True, succeeded, reason, now
        self.feedback = "succeeded" if succeeded else f"failed: {reason}"
        callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback(self)

    def __repr__(self) -> str:
        status = "running" if not self.done else ("succeeded" if self.succeeded else f"failed ({self.reason})")
        return f"<Request #{self.id} {self.description} [{self.origin.value}]: {status}>"


class NodeIO(Protocol):
    """What a node job needs from the manager: observations and asynchronous calls."""

    def observation(self, node: str) -> NodeObservation: ...

    def send_transition(self, node: str, transition: Transition, done: Done) -> None: ...

    def send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None: ...


class Job:
    """One piece of a plan. ``failure`` is set when it failed; ``finished`` when it succeeded."""

    finished = False
    failure = ""

    def pump(self) -> None:
        raise NotImplementedError

    def cancel(self) -> None:
        raise NotImplementedError

    @property
    def over(self) -> bool:
        return self.finished or bool(self.failure)

    def feedback(self) -> str:
        raise NotImplementedError


class NodeJob(Job):
    """Drives one node to ``target``: full parameter set first (so a node that configures or
    activates reads its new mode), then each lifecycle step, each confirmed by the node's own
    report before the next is sent. A call's response and the node's report may arrive in
    either order, so a step is only over when both are in."""

    def __init__(self, io: NodeIO, node: str, target: StateMode, mode: NodeMode | None) -> None:
        self.io = io
        self.node = node
        self.target = target
        self.mode = mode  # the node mode to reach when the target is active
        self.step = "waiting"
        self._busy = False  # a call is in flight
        self._params_sent = False
        self._left: State | None = None  # the state a transition was sent from, until it is left
        self._cancelled = False

    def feedback(self) -> str:
        return f"{self.node}: {self.step}"

    def cancel(self) -> None:
        self._cancelled = True

    def _call_done(self, what: str) -> Done:
        def done(result: CallResult) -> None:
            if self._cancelled or self.over:
                return
            self._busy = False
            if not result.ok:
                self.failure = f"{self.node}: {what} failed: {result.reason or 'refused'}"
        return done

    def pump(self) -> None:
        if self.over or self._cancelled or self._busy:
            return
        obs = self.io.observation(self.node)
        if obs.gone:
            self.failure = f"{self.node}: {obs.gone}"
            return
        if not obs.seen:
            self.step = "waiting for the node to appear"
            return
        if not obs.state.is_primary:
            self.step = f"waiting while it is {obs.state.label}"
            return
        if self._left is obs.state:
            self.step = f"waiting for its state report (still {obs.state.label})"
            return
        self._left = None
        mode = self.mode if self.target.state is State.ACTIVE else None
        if mode is not None and not mode.matches(obs.parameters):
            if self._params_sent:
                self.step = f"waiting for the parameters of mode {mode.name} to be reported"
                return
            self._params_sent = self._busy = True
            self.step = f"set parameters of mode {mode.name}"
            self.io.send_parameters(self.node, mode.values(), self._call_done(self.step))
            return
        if obs.state is not self.target.state:
            try:
                path = plan(obs.state, self.target.state)
            except PlanError as error:
                self.failure = f"{self.node}: {error}"
                return
            transition = path[0].transition
            self._busy = True
            self._left = obs.state
            more = f" (1 of {len(path)} steps to {self.target.state.label})" if len(path) > 1 else ""
            self.step = transition.label + more
            self.io.send_transition(self.node, transition, self._call_done(transition.label))
            return
        self.step = "done"
        self.finished = True


class _Composite(Job):
    def __init__(self, children: list[Job]) -> None:
        self.children = children

    def cancel(self) -> None:
        for child in self.children:
            child.cancel()


class Sequence(_Composite):
    """Children one after another (the stages of a switching order)."""

    def current(self) -> Job | None:
        return next((c for c in self.children if not c.finished), None)

    def feedback(self) -> str:
        current = self.current()
        if current is None:
            return "done"
        index = self.children.index(current) + 1
        prefix = f"stage {index}/{len(self.children)}: " if len(self.children) > 1 else ""
        return prefix + current.feedback()

    def pump(self) -> None:
        while (current := self.current()) is not None:
            current.pump()
            if current.failure:
                self.failure = current.failure
                return
            if not current.finished:
                return
        self.finished = True


class Parallel(_Composite):
    """Children all at once (one stage)."""

    def feedback(self) -> str:
        busy = [c.feedback() for c in self.children if not c.finished]
        return "; ".join(busy) if busy else "done"

    def pump(self) -> None:
        for child in self.children:
            child.pump()
            if child.failure:
                self.failure = child.failure
                return
        self.finished = all(c.finished for c in self.children)


@dataclass
class Execution:
    """A request with its plan and the bookkeeping the manager needs for it."""

    request: Request
    job: Job
    scope: frozenset[str]  # the nodes the plan touches
    previous_targets: dict[str, StateMode | None]
    timer: TimerHandle | None = None
