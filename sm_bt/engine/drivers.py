"""Node drivers: one per node, the only part of the engine that sends calls to a node.

A driver takes its node towards the goal of the plan step that owns it, one confirmed step at a
time: the mode's full parameter set first (so a node that configures or activates reads its new
mode), then each lifecycle transition on the planned path. Requests come and go (a newer one
preempts an older one), but the driver stays, and with it what is in flight on the node: a
lifecycle transition cannot be taken back in the middle of its callback, so a new owner waits for
the outcome of the call in flight and goes on from the state the node is then in. No call is ever
sent that conflicts with one of the manager's own calls still in flight.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

from sm_bt.engine.backend import Backend, CallResult, Done
from sm_bt.engine.clock import Clock
from sm_bt.engine.inference import Inference, NodeObservation
from sm_bt.engine.lifecycle import PlanError, Transition, TransitionEdge, plan
from sm_bt.engine.serialiser import Serialiser
from sm_bt.model.states import State
from sm_bt.model.types import NodeMode, ParamValue

log = logging.getLogger("sm_bt.manager")


@dataclass(frozen=True)
class Goal:
    """What a plan step asks of a node: a lifecycle state and, for ``active``, a node mode (a
    rollback also gives the values a node had in another state: they are set whatever the state)."""

    state: State
    mode: NodeMode | None = None

    def __str__(self) -> str:
        return self.state.label if self.mode is None or self.state is not State.ACTIVE else \
            f"{self.state.label}.{self.mode.name}"


class Owner(Protocol):
    """The plan step a driver works for."""

    @property
    def goal(self) -> Goal: ...

    @property
    def reached_goal(self) -> bool:
        """True once :meth:`reached` was called (the step then only watches its node)."""

    def reached(self) -> None:
        """The node is in the goal (state and parameters confirmed by the node's reports)."""

    def failed(self, reason: str) -> None:
        """The node cannot be taken to the goal, or left it again while the request was running."""


class DriverIO(Protocol):
    """What a driver needs from the manager."""

    def observation(self, node: str) -> NodeObservation: ...

    def now(self) -> float: ...

    def send_transition(self, node: str, transition: Transition, done: Done) -> None: ...

    def send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None: ...


@dataclass(slots=True, eq=False)
class _DriverCall:
    """A call of a driver's in flight; its bound :meth:`answered` is the backend's ``done`` (one
    object per call: every node of a bring-up has one in flight at once)."""

    driver: NodeDriver
    label: str  # what was asked, as the feedback shows it
    sent: float
    owner: Owner | None  # who it was sent for (it may have been preempted since)
    transition: Transition | None = None  # None for a parameter set
    goal: State = State.UNKNOWN  # where a transition leads on success
    mode: str | None = None  # the mode whose values a parameter set sends
    goal_reported: bool = False  # the node reported that goal (or, for a set, parameters) meanwhile
    any_report: bool = False  # the node reported a state meanwhile

    @property
    def what(self) -> str:
        """The call itself (``activate``), without the feedback's progress."""
        return self.label if self.transition is None else self.transition.label

    def answered(self, result: CallResult) -> None:
        self.driver._call_answered(self, result)


#: Parameter sets sent for one plan step before it fails: the node keeps reporting other values.
_MAX_SETS = 3
#: Transitions refused for one plan step (the node was not where its reports said) before it fails.
_MAX_REFUSALS = 3
#: Times a node that reached its step's goal is taken back there before the step fails.
_MAX_RELAPSES = 2


class NodeDriver:
    """Drives ``node`` for whichever plan step owns it (``assign``/``release``)."""

    def __init__(self, node: str, io: DriverIO) -> None:
        self.node = node
        self.io = io
        self.owner: Owner | None = None
        self.call: _DriverCall | None = None
        # After a transition answered with success before the node reported its goal state: that
        # goal, until it is reported. The answer and the reports may come in either order, and
        # reports of an earlier transition (one the node made by itself) may still be on their
        # way: none of them says where the node is until our transition's own goal report.
        self._awaiting: State | None = None
        # A parameter set answered with success before the node reported parameters: its mode,
        # until a report comes (the answer may come before the parameter events, which alone say
        # what the node holds).
        self._parameters_set: str | None = None
        self._sets = 0  # parameter sets sent for the current owner (a node that keeps other values)
        # A transition was refused: the reported state was out of date; wait for the next report.
        self._outdated = False
        self._refusals = 0  # for the current owner
        self._relapses = 0  # times the node left the current owner's goal after reaching it
        self._back_to_goal = False  # taking it back there

    # -- ownership ------------------------------------------------------------------------------

    def assign(self, owner: Owner) -> None:
        self.owner = owner
        self._sets = self._refusals = self._relapses = 0
        self._back_to_goal = False
        self.advance()

    def release(self, owner: Owner) -> None:
        if self.owner is owner:
            self.owner = None

    def node_appeared(self, state: State) -> None:
        """A (new) process of the node was reported, with its state and every parameter: nothing
        reported before is awaited any more (a call in flight now has its answer's news too)."""
        self._awaiting = None
        self._parameters_set = None
        self._outdated = False
        call = self.call
        if call is not None:
            call.any_report = True
            call.goal_reported = call.transition is None or state is call.goal

    def parameters_reported(self) -> None:
        """The node reported parameter values: a set answered earlier is no longer awaited (if
        the values are not the mode's, for instance an earlier set's late report, the next step
        sends the mode's set again)."""
        self._parameters_set = None
        if self.call is not None and self.call.transition is None:
            self.call.goal_reported = True

    def state_reported(self, state: State) -> None:
        """The node reported ``state`` (kept whether or not a step owns the node: a later owner
        must not wait for a report that came under an earlier one)."""
        call = self.call
        if call is not None and call.transition is not None:
            call.any_report = True
            call.goal_reported = call.goal_reported or state is call.goal
        if state is self._awaiting:
            self._awaiting = None
        self._outdated = False

    # -- progress -------------------------------------------------------------------------------

    def advance(self) -> None:
        """Take the next step if one can be taken now; call after anything about the node changed."""
        owner = self.owner
        if owner is None or self.call is not None:
            return
        obs = self.io.observation(self.node)
        if owner.reached_goal and self._at(owner.goal, obs):
            return
        if owner.reached_goal and not self._back_to_goal:
            # It left the goal while the request runs (by itself, or its move was reported late):
            # take it back, a bounded number of times.
            self._relapses += 1
            if self._relapses > _MAX_RELAPSES or obs.gone:
                owner.failed(f"{self.node} left {owner.goal} while the request was in progress "
                             f"({self._now(owner.goal, obs)})")
                return
            self._back_to_goal = True
        if obs.gone:
            owner.failed(f"{self.node}: {obs.gone}")
            return
        if not obs.seen or not obs.state.is_primary or self._awaiting is not None \
                or self._parameters_set is not None or self._outdated:
            return
        goal = owner.goal
        mode = goal.mode
        if mode is not None and not mode.matches(obs.parameters):
            if self._sets >= _MAX_SETS:
                owner.failed(f"{self.node}: the parameters of mode {mode.name} were set {self._sets} times, "
                             f"but the node reports other values")
            else:
                self._send_parameters(owner, mode)
            return
        if obs.state is not goal.state:
            try:
                path = plan(obs.state, goal.state)
            except PlanError as error:
                owner.failed(f"{self.node}: {error}")
                return
            more = f" (1 of {len(path)} steps to {goal.state.label})" if len(path) > 1 else ""
            self._send_transition(owner, path[0], more)
            return
        self._back_to_goal = False
        owner.reached()

    def describe(self) -> str:
        """The step in progress, for a request's feedback."""
        obs = self.io.observation(self.node)
        if self.call is not None:
            return f"{self.node}: {self.call.label}"
        owner = self.owner
        if owner is not None and owner.reached_goal and not self._back_to_goal:
            return f"{self.node}: done"
        if obs.gone:
            return f"{self.node}: {obs.gone}"
        if not obs.seen:
            return f"{self.node}: waiting for the node to appear"
        if not obs.state.is_primary:
            return f"{self.node}: waiting while it is {obs.state.label}"
        if self._awaiting is not None:
            return f"{self.node}: waiting for it to report {self._awaiting.label}"
        if self._parameters_set is not None:
            return f"{self.node}: waiting for the parameters of mode {self._parameters_set} to be reported"
        if self._outdated:
            return f"{self.node}: waiting for its state report (it was not {obs.state.label} any more)"
        return f"{self.node}: next step towards {owner.goal if owner else 'nothing'}"

    def stall(self) -> str:
        """Why the node is not there yet, for a request that ran out of time."""
        obs = self.io.observation(self.node)
        if self.call is not None:
            waited = self.io.now() - self.call.sent
            if self.call.transition is not None and not obs.state.is_primary:
                return f"{self.node} hung in {obs.state.label} for {waited:.3g} s"
            return f"no answer from {self.node} to {self.call.what} for {waited:.3g} s"
        return self.describe()

    # -- calls ----------------------------------------------------------------------------------

    def _send_parameters(self, owner: Owner, mode: NodeMode) -> None:
        values = mode.values()
        call = _DriverCall(self, mode.set_label, self.io.now(), owner, mode=mode.name)
        self.call = call
        self._sets += 1
        self.io.send_parameters(self.node, values, call.answered)

    def _send_transition(self, owner: Owner, step: TransitionEdge, more: str) -> None:
        call = _DriverCall(self, step.transition.label + more, self.io.now(), owner, step.transition, step.goal)
        self.call = call
        self.io.send_transition(self.node, step.transition, call.answered)

    def _call_answered(self, call: _DriverCall, result: CallResult) -> None:
        if self.call is not call:
            return  # superseded: what it did is reported by the node
        self.call = None
        if call.transition is None:
            self._parameters_set = call.mode if result.ok and not call.goal_reported else None
        elif result.ok and not call.goal_reported:
            self._awaiting = call.goal
        self._answered(call, result)

    def _answered(self, call: _DriverCall, result: CallResult) -> None:
        owner = self.owner
        if result.refused and owner is not None and self._refusals < _MAX_REFUSALS:
            # Planned from a report that was out of date: plan again from the next one.
            if owner is call.owner:
                self._refusals += 1
            self._outdated = not call.any_report
            self.advance()
            return
        if not result.ok and owner is not None and owner is call.owner:
            owner.failed(f"{self.node}: {call.what} failed: {result.reason or 'refused'}")
            return
        # A failure of a call made for an earlier (preempted) owner is not the new owner's: it
        # goes on from wherever the node now is.
        self.advance()

    # -- helpers --------------------------------------------------------------------------------

    @staticmethod
    def _at(goal: Goal, obs: NodeObservation) -> bool:
        if obs.state is not goal.state:
            return False
        return goal.mode is None or goal.mode.matches(obs.parameters)

    @staticmethod
    def _now(goal: Goal, obs: NodeObservation) -> str:
        if obs.gone:
            return obs.gone
        if obs.state is goal.state and goal.mode is not None:
            return f"its parameters no longer match mode {goal.mode.name}"
        return f"now {obs.state.label}"


class BackendIO:
    """What node drivers do through the backend (:class:`DriverIO`): calls whose answers come back
    serialised (inside an entry of the manager's, whatever thread the backend answers on)."""

    def __init__(self, inference: Inference, clock: Clock, backend: Backend, serialiser: Serialiser) -> None:
        self.observation = inference.observation
        self.now = clock.now
        self._backend = backend
        self._serialiser = serialiser

    def send_transition(self, node: str, transition: Transition, done: Done) -> None:
        log.debug("  %s: %s", node, transition.label)
        self._backend.change_state(node, transition, self._serialiser.serialised(done))

    def send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        log.debug("  %s: set %d parameters", node, len(parameters))
        self._backend.set_parameters(node, parameters, self._serialiser.serialised(done))
