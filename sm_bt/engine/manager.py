"""The embedded mode manager: targets top-down, inference bottom-up, rules and recovery.

``ModeManager(model, backend)`` owns the targets of every part, keeps inference up to date from
what the backend reports, carries requests (``change_mode``/``change_state``/``change_to``) out as
confirmed, ordered plans, and reacts to divergences: after a grace period, rules first
(bottom-up), then restoring nodes, within a budget.

How requests interact (the semantics the README states):

* **The last request wins.** A request preempts every request in flight that drives one of the
  same nodes (or asks for the same part): those end FAILURE "preempted by request #N (...)".
  The new one starts from where the nodes are heading: a call already in flight on a node is
  never contradicted; its node's driver waits for the outcome and goes on from there.
* A request ends SUCCESS once every node reached its goal and the part's inferred actual is the
  target; FAILURE with the reason (naming the node and why) as soon as one step cannot be
  taken, a node that reached its goal leaves it again, or ``timeout`` runs out.
* A request that is refused (unknown part or mode, a transition invalid where the part is or is
  heading) changes nothing and is done at once.

Nothing here blocks; time comes from the backend's clock. Every entry point is serialised
(:mod:`sm_bt.engine.serialiser`): the outermost entry settles, working through the agenda (plans
handing over to their next steps), re-examining the divergences that changed and reacting to
faults until nothing is left to do, and only then tells the observers. The work per event is
proportional to what the event changed.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from sm_bt.engine.backend import Backend, Done, NodeReport
from sm_bt.engine.clock import TimerHandle
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.drivers import NodeDriver
from sm_bt.engine.events import Divergence, Event, EventKind, Observer, Subscription
from sm_bt.engine.executions import Execution
from sm_bt.engine.hierarchy import Hierarchy, child_targets, implied_targets
from sm_bt.engine.inference import Actual, Changes, Inference, NodeObservation
from sm_bt.engine.lifecycle import (
    REQUESTABLE,
    REQUESTABLE_LABELS,
    PlanError,
    Transition,
    first_transition,
    step_for,
    transition_by_label,
)
from sm_bt.engine.reactions import FireRule, GiveUp, Reactions, Restore
from sm_bt.engine.requests import Origin, Request
from sm_bt.engine.serialiser import Serialiser
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, Model, NodePart, ParamValue, SystemPart

log = logging.getLogger("sm_bt.manager")
#: How long a request may take, by default (seconds of the backend's clock).
REQUEST_TIMEOUT = 30.0
#: Why a request fails or is refused once the manager is closed.
CLOSED = "the manager is closed"

#: The primary state each requestable transition leads to.
_GOAL = {step.transition: step.goal for step in REQUESTABLE}
#: Settling passes before the manager reports that it could not settle (a bug, not a model).
_MAX_PASSES = 100_000


class ModeManager:
    """Manage the parts of ``model`` through ``backend``.

    ``request_timeout`` bounds every request (seconds of the backend's clock); ``grace_period``
    is how long a divergence must last, with no request working on it, before rules or recovery
    act. Rules and recovery share a budget per part: ``recovery_attempts`` reactions in a run of
    failures; it is whole again once the part stayed on target for ``recovery_window`` seconds
    (a node that comes back and fails again at once still runs out). After that the part is
    *given up* and its divergence says why. ``rules=False``/``recovery=False`` switch those
    reactions off.
    """

    def __init__(self, model: Model, backend: Backend, *, request_timeout: float = REQUEST_TIMEOUT,
                 grace_period: float = 2.0, recovery_attempts: int = 3, recovery_window: float = 60.0,
                 rules: bool = True, recovery: bool = True) -> None:
        self.model = model
        self.backend = backend
        self.clock = backend.clock
        self.request_timeout = request_timeout
        self._serial = Serialiser(self._settle, lambda: self._divergences.pending)
        self._lock = self._serial.lock
        self._hierarchy = Hierarchy.of(model)
        self._inference = Inference(model, self._hierarchy)
        self._divergences = Divergences(model, self._hierarchy, self._inference, grace_period)
        self._reactions = Reactions(model, self._hierarchy, attempts=recovery_attempts, window=recovery_window,
                                    rules=rules, recovery=recovery)
        self._drivers = {node.name: NodeDriver(node.name, _DriverIO(self)) for node in model.nodes}
        # The parts whose rules look at each part: a change of it may make one of them apply.
        self._watchers: dict[str, list[str]] = {}
        for spec in model.parts.values():
            for rule in spec.rules:
                self._watchers.setdefault(rule.if_part, []).append(rule.system)
        self._executions: dict[int, Execution] = {}
        self._confirming: dict[str, set[Execution]] = {}  # part -> executions waiting for its actual
        self._last_mode: dict[str, str] = {}  # the last active mode asked for, kept over deactivation
        self._reported: set[str] = set()  # divergences already logged as errors
        self._away: dict[str, tuple[float, StateMode]] = {}  # vanished nodes: since when, and as they were
        self._returns: dict[str, Return] = {}  # the last time each node came back
        self._outbox = self._serial.outbox
        self._grace_timer: TimerHandle | None = None
        self._grace_due: float | None = None
        with self._entry():
            backend.attach([node.name for node in model.nodes], _Listener(self))

    # -- settings ---------------------------------------------------------------------------------

    @property
    def grace_period(self) -> float:
        return self._divergences.grace_period

    @property
    def recovery_attempts(self) -> int:
        return self._reactions.attempts

    @property
    def recovery_window(self) -> float:
        return self._reactions.window

    @property
    def rules_enabled(self) -> bool:
        return self._reactions.rules_enabled

    @property
    def recovery_enabled(self) -> bool:
        return self._reactions.recovery_enabled

    # -- queries ----------------------------------------------------------------------------------

    @property
    def lock(self) -> threading.RLock:
        """The lock serialising the manager. Hold it to read several values consistently, or to
        subscribe and read the current values with no event slipping in between."""
        return self._lock

    def actual(self, part: str) -> Actual:
        """The inferred actual state and mode of ``part`` (see :class:`Actual` for the flags)."""
        with self._lock:
            self._check_part(part)
            return self._inference.actual(part)

    def target(self, part: str) -> StateMode | None:
        """The state and mode ``part`` should be in, or ``None`` if nobody asked for one yet."""
        with self._lock:
            self._check_part(part)
            return self._inference.target(part)

    def divergences(self, *, errors_only: bool = False) -> list[Divergence]:
        """Parts whose actual differs from their target, bottom-up. ``errors_only`` keeps those
        beyond the grace period that no request explains."""
        with self._lock:
            height = self._hierarchy.height
            found = sorted(self._divergences.records.values(), key=lambda d: height[d.part])
        return [d for d in found if d.is_error] if errors_only else found

    def divergence(self, part: str) -> Divergence | None:
        with self._lock:
            self._check_part(part)
            return self._divergences.records.get(part)

    def available_modes(self, part: str) -> list[str]:
        """Every mode of ``part``, sorted byte-wise (as the reference's ``get_available_modes``)."""
        self._check_part(part)
        return sorted(self.model.parts[part].modes)

    def reachable_modes(self, part: str) -> list[str]:
        """The modes of ``part`` that can still be reached with the nodes unavailable now
        (vanished, finalized, or given up by recovery) left as they are."""
        with self._lock:
            return [m for m in self.available_modes(part)
                    if self._reachable(part, StateMode(State.ACTIVE, m))]

    def failed(self) -> list[str]:
        """Parts that rules and recovery gave up on (until they are back on target, or a user
        request or a restart of the node makes their budget whole again)."""
        with self._lock:
            return sorted(self._reactions.gave_up)

    def requests(self) -> list[Request]:
        """Requests in progress."""
        with self._lock:
            return [e.request for e in self._executions.values()]

    def observation(self, node: str) -> NodeObservation:
        """What the backend reported about ``node`` (state, parameters)."""
        with self._lock:
            self._check_node(node)
            return self._inference.observation(node)

    def last_return(self, node: str) -> Return | None:
        """How ``node`` came back the last time it had vanished (``None``: it never did)."""
        with self._lock:
            self._check_node(node)
            return self._returns.get(node)

    # -- commands ---------------------------------------------------------------------------------

    def change_mode(self, part: str, mode: str, *, timeout: float | None = None, requester: str = "user") -> Request:
        """Ask for ``part`` (system or node) to be active in ``mode`` (``__DEFAULT__`` names its
        default mode). Returns at once. :class:`RequestError` for a part or mode the model does not
        have, or an empty mode name. ``requester`` says who asks, for logs and narratives
        (:attr:`Request.requester`: sm_bt's behaviours say ``"tree"``)."""
        if not mode:
            raise RequestError(f"change_mode of {part}: the mode name is empty (name a mode, or {DEFAULT_MODE} "
                               "for the default mode)")
        with self._entry():
            return self._request(part, StateMode(State.ACTIVE, mode), f"change_mode {part} {mode}", timeout,
                                 requester)

    def change_state(self, part: str, transition: Transition | str | int, *,
                     timeout: float | None = None, requester: str = "user") -> Request:
        """Ask for a lifecycle transition of ``part`` (system or node): ``"configure"``,
        ``"activate"``, ``Transition.DEACTIVATE``, ... Returns at once. A settled part must be in
        a state the transition is valid from (as a lifecycle node requires), or already in its
        goal state (then it succeeds at once); while a request is moving the part, any requestable
        transition is accepted and its goal state becomes the new target. Activation keeps the
        last mode asked for. :class:`RequestError` for a part the model does not have, or a
        transition that does not exist or cannot be requested; one not valid from where the part
        is now is a refused request."""
        with self._entry():
            name = transition.label if isinstance(transition, Transition) else str(transition)
            description = f"change_state {part} {name}"
            self._check_part(part)
            current = self._inference.actual(part).state
            try:
                resolved = self._resolve_transition(transition, current)
            except ValueError as error:
                raise RequestError(f"{description}: {error} (transitions: {', '.join(REQUESTABLE_LABELS)})"
                                   f"{did_you_mean(name, REQUESTABLE_LABELS)}") from None
            if resolved not in _GOAL:
                raise RequestError(f"{description}: {resolved.label} ({int(resolved)}) cannot be requested "
                                   f"(transitions: {', '.join(REQUESTABLE_LABELS)})")
            goal = _GOAL[resolved]
            try:
                if current.is_primary and goal is not current and not self._moving(part):
                    step_for(current, resolved)  # raises with the valid ones when invalid here
            except PlanError as error:
                return self._refuse(part, description, f"{part}: {error}", requester)
            mode = self._mode_for_activation(part) if goal is State.ACTIVE else None
            return self._start(part, StateMode(goal, mode), description, Origin.USER, timeout, resolved,
                               requester=requester)

    def change_to(self, part: str, target: StateMode | str, *, timeout: float | None = None,
                  requester: str = "user") -> Request:
        """Ask for ``part`` to reach ``target`` (``"active.FAST"``, ``"inactive"``, a
        :class:`StateMode`), whatever it is in now: the plan takes every lifecycle step needed.
        Used to put a part back where it was (for instance after holding a mode). Returns at once.
        :class:`RequestError` for a part or mode the model does not have, or a target that is not
        one to ask for."""
        with self._entry():
            try:
                wanted = target if isinstance(target, StateMode) else StateMode.parse(target)
            except ValueError as error:
                raise RequestError(f"change_to {part} {target}: {error}") from None
            description = f"change_to {part} {wanted}"
            if wanted.state not in (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE):
                raise RequestError(f"{description}: {wanted.state.label} is not a state to ask for "
                                   "(unconfigured, inactive or active)")
            return self._request(part, wanted, description, timeout, requester)

    def subscribe(self, callback: Observer, part: str | Iterable[str] | None = None,
                  kinds: Iterable[EventKind] | None = None) -> Subscription:
        """Call ``callback(event)`` for events of ``part`` (one, several, or all) and ``kinds``.

        Callbacks run inside the manager's lock, in the thread that caused the event, after the
        manager settled; they may call the manager. Cancel with ``subscription.cancel()``.
        """
        parts = None if part is None else frozenset([part] if isinstance(part, str) else part)
        for name in parts or ():
            self._check_part(name)
        return self._serial.subscribe(callback, parts, kinds)

    def close(self) -> None:
        """Stop: cancel requests in flight and timers, detach from the backend."""
        with self._entry():
            for execution in list(self._executions.values()):
                self.finish(execution, False, CLOSED)
            if self._grace_timer is not None:
                self._grace_timer.cancel()
            self._serial.closed = True
            self.backend.detach()

    # -- node reports (from the backend) ----------------------------------------------------------

    def _node_appeared(self, node: str, report: NodeReport) -> None:
        with self._entry():
            away = self._away.pop(node, None)
            if away is None:
                log.info("node %s appeared: %s%s", node, report.state.label,
                         "" if report.lifecycle else " (parameters only)")
            self._renew_budgets([node])
            self._drivers[node].node_appeared(report.state)
            self._apply(self._inference.node_appeared(node, report.state, report.parameters, report.lifecycle))
            self._new_life(node, report.state)
            if away is not None:  # what changed while it was out of reach (recovery logs what it does)
                since, before = away
                after = self._inference.actual(node).state_mode
                back = Return(node, self.clock.now() - since, before, after)
                self._returns[node] = back
                log.info("node %s appeared: %s", node, back.describe())
            self._drivers[node].advance()

    def _new_life(self, node: str, state: State) -> None:
        """A node whose target is ``finalized`` appeared alive: it was restarted, and starts a new
        life. Its target becomes what its system's target needs of it (the first parent with a
        target that asks something of it, unless that is ``finalized`` too), else the state it came
        back in; from then on it is a node like any other (requests include it, recovery restores
        it). Without this, the manager would shut every new process of it down again."""
        target = self._inference.target(node)
        if target is None or target.state is not State.FINALIZED or state is State.FINALIZED:
            return
        wanted: StateMode | None = StateMode(state) if state.is_primary else None
        why = "the state it came back in"
        for parent in self._hierarchy.parents[node]:
            parent_target = self._inference.target(parent)
            spec = self.model.parts[parent]
            if parent_target is None or not isinstance(spec, SystemPart):
                continue
            asked = dict(child_targets(spec, parent_target)).get(node)
            if asked is not None and asked.state is not State.FINALIZED:
                wanted, why = asked, f"what {parent}'s target {parent_target} needs"
                break
        log.info("node %s came back after being finalized: a new life, its target now %s (%s)", node,
                 wanted if wanted is not None else "none", why)
        self._set_target(node, wanted)
        self._divergences.chosen(node, None)

    def _node_state(self, node: str, state: State) -> None:
        with self._entry():
            # Nothing leaves finalized: a finalized node heard in another state is a new process
            # (restarted too quickly to be seen gone in between).
            reborn = self._inference.observation(node).state is State.FINALIZED and state is not State.FINALIZED
            self._apply(self._inference.node_state(node, state))
            if reborn:
                self._renew_budgets([node])
                self._new_life(node, state)
            self._drivers[node].state_reported(state)
            self._drivers[node].advance()

    def _node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        with self._entry():
            self._apply(self._inference.node_parameters(node, changed))
            self._drivers[node].parameters_reported()
            self._drivers[node].advance()

    def _node_vanished(self, node: str, reason: str) -> None:
        with self._entry():
            log.warning("node %s vanished: %s", node, reason)
            self._away.setdefault(node, (self.clock.now(), self._inference.actual(node).state_mode))
            self._apply(self._inference.node_vanished(node, reason))
            # A request that needs it cannot complete while it is out of reach: it ends now, not
            # when one of its calls times out (a node that waits for its turn has none in flight).
            for execution in [e for e in self._executions.values() if node in e.scope]:
                self.finish(execution, False, f"{node} is not reachable ({reason})")
            self._drivers[node].advance()

    # -- what drivers need ------------------------------------------------------------------------

    def driver(self, node: str) -> NodeDriver:
        return self._drivers[node]

    def _send_transition(self, node: str, transition: Transition, done: Done) -> None:
        log.debug("  %s: %s", node, transition.label)
        self.backend.change_state(node, transition, self._serial.serialised(done))

    def _send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        log.debug("  %s: set %d parameters", node, len(parameters))
        self.backend.set_parameters(node, parameters, self._serial.serialised(done))

    # -- executions -------------------------------------------------------------------------------

    def _request(self, part: str, wanted: StateMode, description: str, timeout: float | None,
                 requester: str) -> Request:
        """Start a user request for ``wanted`` (an active mode resolved: ``__DEFAULT__`` is the
        default mode); :class:`RequestError` with the part's real names for one it does not have."""
        self._check_part(part)
        if wanted.state is State.ACTIVE:
            resolved = self._resolve_mode(part, wanted.mode or DEFAULT_MODE)
            if resolved is None:
                modes = self.available_modes(part)
                raise RequestError(f"{description}: unknown mode {wanted.mode!r} of {part}"
                                   f"{did_you_mean(wanted.mode or '', modes)} (modes: {', '.join(modes)})")
            wanted = StateMode(State.ACTIVE, resolved)
        return self._start(part, wanted, description, Origin.USER, timeout, requester=requester)

    def _start(self, part: str, target: StateMode, description: str, origin: Origin,
               timeout: float | None, transition: Transition | None = None, *, requester: str | None = None) -> Request:
        if self._serial.closed:  # detached from the backend: nothing it starts could ever end
            return self._refuse(part, description, CLOSED, requester)
        implied = implied_targets(self.model, part, target)
        scope = frozenset(name for name, _ in implied if isinstance(self.model.parts[name], NodePart))
        if origin is Origin.USER:
            why = "; ".join(filter(None, (self._out_of_reach(n, t) for n, t in implied if n in scope)))
            if why:  # refused as a whole: nothing is changed
                return self._refuse(part, description, why, requester)
        request = Request(part, target, description, origin, self.clock.now(), withdraw=self._withdraw,
                          requester=requester)
        # A rule's or recovery's request follows its own log line: the start is detail then.
        (log.info if origin is Origin.USER else log.debug)("request #%d %s started [%s]", request.id, description,
                                                           request.requester)
        preempted = [e for e in self._executions.values() if e.scope & scope or e.request.part == part]
        for execution in preempted:
            self.finish(execution, False, f"preempted by request #{request.id} ({description})")
        previous = self._assign_targets(implied, origin, transition)
        if origin is Origin.USER:
            self._renew_budgets(previous)
        self._run(Execution(self, request, scope, previous), timeout)
        # The last request wins where it drives; elsewhere what the preempted ones asked for stands.
        for execution in preempted:
            if execution.scope - scope:
                self._continue(execution, execution.scope - scope)
        return request

    def _out_of_reach(self, node: str, target: StateMode) -> str:
        """Why ``node`` cannot be taken to ``target`` as far as the manager knows ("" if it can)."""
        obs = self._inference.observation(node)
        if obs.gone:
            return f"{node} is not reachable ({obs.gone})"
        if obs.state is State.FINALIZED and target.state is not State.FINALIZED:
            return f"{node} is finalized (it must be restarted)"
        return ""

    def _continue(self, preempted: Execution, nodes: frozenset[str]) -> None:
        """Carry on with ``nodes`` of a preempted request: their targets are still what it asked."""
        old = preempted.request
        description = f"continue #{old.id} ({old.description}) for {', '.join(sorted(nodes))}"
        request = Request(old.part, old.target, description, old.origin, self.clock.now(), withdraw=self._withdraw,
                          requester=old.requester, parts=tuple(sorted(nodes)))
        (log.info if old.origin is Origin.USER else log.debug)("request #%d %s started [%s]", request.id,
                                                               description, request.requester)
        self._run(Execution(self, request, nodes, {}, continuation=True), None)

    def _run(self, execution: Execution, timeout: float | None) -> None:
        request = execution.request
        request._progress = lambda: self._serial.locked(execution.feedback)
        self._executions[request.id] = execution
        self._divergences.busy(execution.scope, +1)
        limit = self.request_timeout if timeout is None else timeout
        execution.timer = self.clock.call_later(limit, lambda: self._timed_out(execution, limit))
        self._emit(EventKind.REQUEST, request.part, f"#{request.id} {request.description} started", request=request)
        execution.start()

    def _refuse(self, part: str, description: str, reason: str, requester: str | None = None) -> Request:
        now = self.clock.now()
        request = Request(part, StateMode(State.UNKNOWN), description, Origin.USER, now, requester=requester)
        log.warning("request %s refused: %s", description, reason)
        request.refused = True
        request._finish(False, reason, now)
        return request

    def _assign_targets(self, implied: list[tuple[str, StateMode]], origin: Origin,
                        transition: Transition | None) -> dict[str, tuple[StateMode | None, Origin | None]]:
        """Set the targets (the requested part first, then top-down below it); return what they
        were, with who had chosen them."""
        previous: dict[str, tuple[StateMode | None, Origin | None]] = {}
        for index, (name, value) in enumerate(implied):
            previous[name] = (self._inference.target(name), self._divergences.chosen_by(name))
            self._set_target(name, value, transition if index == 0 else None)
            if index > 0:
                self._divergences.chosen(name, None)
            elif origin is not Origin.RECOVERY:  # restoring a node keeps who chose its target
                self._divergences.chosen(name, origin)
        return previous

    def _set_target(self, part: str, target: StateMode | None, transition: Transition | None = None) -> None:
        if target is not None and target.mode is not None:
            self._last_mode[part] = target.mode
        if self._inference.target(part) == target:
            return
        before = self._inference.actual(part)
        if transition is None and target is not None:
            transition = first_transition(before.state, target.state)
        self._emit(EventKind.TARGET, part, target=target, previous=before, transition=transition)
        self._divergences.touch(part)
        self._apply(self._inference.set_target(part, target))

    def confirm(self, execution: Execution) -> None:
        """The plan is done: succeed once every part the request is about is at its target (the
        request's part at the request's target; a continuation's nodes at theirs)."""
        request = execution.request
        off = []
        for part in request.parts:
            wanted = self._inference.target(part) if execution.continuation else request.target
            if wanted is not None and not self._inference.actual(part).is_(wanted):
                off.append(part)
        if not off:
            self.finish(execution, True, "")
        for part in off:
            self._confirming.setdefault(part, set()).add(execution)

    def finish(self, execution: Execution, succeeded: bool, reason: str) -> None:
        if not execution.active:
            return
        execution.stop()
        request = execution.request
        self._executions.pop(request.id, None)
        for part in request.parts:
            waiting = self._confirming.get(part)
            if waiting is not None:
                waiting.discard(execution)
        self._divergences.busy(execution.scope, -1)
        now = self.clock.now()
        if request.origin is not Origin.USER:
            self._reactions.finished(request.part, succeeded, reason)
        outcome = f"succeeded in {now - request.created:.2f} s" if succeeded else f"failed: {reason}"
        (log.info if succeeded else log.warning)("request #%d %s %s", request.id, request.description, outcome)
        self._emit(EventKind.REQUEST, request.part, f"#{request.id} {request.description} {outcome}",
                   request=request)
        request._finish(succeeded, reason, now)

    def _withdraw(self, request: Request) -> None:
        with self._entry():
            execution = self._executions.get(request.id)
            if execution is None:
                return
            for part, (target, chosen_by) in execution.previous_targets.items():
                self._set_target(part, target)
                self._divergences.chosen(part, chosen_by)
            self.finish(execution, False, "cancelled")

    def _timed_out(self, execution: Execution, limit: float) -> None:
        with self._entry():
            if execution.active:
                self.finish(execution, False, f"timed out after {limit:g} s ({execution.stall()})")

    def later(self, action: Callable[[], None]) -> None:
        self._serial.later(action)

    # -- reactions --------------------------------------------------------------------------------

    def _react(self, faults: list[Divergence]) -> None:
        for action in self._reactions.decide(faults, _ReactionView(self)):
            if isinstance(action, FireRule):
                rule = action.rule
                message = f"rule {rule.name}: {rule.if_part} is {rule.if_part_state} -> {rule.new_target}"
                log.info("%s: %s (attempt %d of %d)", rule.system, message, action.attempt, self.recovery_attempts)
                self._emit(EventKind.RULE, rule.system, message)
                self._start(rule.system, rule.new_target, f"rule {rule.name} of {rule.system}", Origin.RULE, None)
            elif isinstance(action, Restore):
                log.warning("restoring %s to %s (attempt %d of %d)", action.node, action.target, action.attempt,
                            self.recovery_attempts)
                self._start(action.node, action.target, f"restore {action.node} to {action.target}",
                            Origin.RECOVERY, None)
            elif isinstance(action, GiveUp):
                part = action.divergence.part
                log.error("%s", action.message)
                self._divergences.note(part, action.message)
                self._emit(EventKind.FAILED, part, action.message, divergence=action.divergence)

    def _renew_budgets(self, parts: Iterable[str]) -> None:
        """Rules and recovery may act on ``parts`` again (a user asked for them, or a node restarted)."""
        for part in parts:
            if part in self._reactions.gave_up:
                self._divergences.note(part, None)
        self._reactions.reset(parts)

    def _moving(self, part: str) -> bool:
        """A request in flight is working on ``part`` (or on a node below it)."""
        return self._divergences.is_busy(part)

    def _reachable(self, part: str, target: StateMode | None) -> bool:
        if target is None:
            return True
        for name, value in implied_targets(self.model, part, target):
            if isinstance(self.model.parts[name], NodePart) and self._unavailable(name):
                actual = self._inference.actual(name)
                if not actual.is_(value):
                    return False
        return True

    def _unavailable(self, node: str) -> bool:
        obs = self._inference.observation(node)
        return node in self._reactions.gave_up or not obs.reachable or obs.state is State.FINALIZED

    # -- plumbing ---------------------------------------------------------------------------------

    def _entry(self) -> Serialiser:
        """Every entry point: serialised; the outermost one then settles and notifies observers
        (:mod:`sm_bt.engine.serialiser`)."""
        return self._serial

    def _settle(self) -> None:
        """Work until nothing is left: the agenda, then the divergences that changed and the
        reactions to faults (which may put more on the agenda)."""
        for _ in range(_MAX_PASSES):
            self._serial.run_agenda()
            if not self._divergences.pending:
                self._schedule_grace()
                return
            now = self.clock.now()
            changes, faults = self._divergences.evaluate(now)
            for change in changes:
                self._divergence_changed(change.part, change.old, change.new, now)
            if faults:
                self._react(faults)
        log.error("the manager did not settle after %d passes; stopped to stay responsive", _MAX_PASSES)

    def _divergence_changed(self, part: str, old: Divergence | None, new: Divergence | None, now: float) -> None:
        if new is None:
            self._reported.discard(part)
            self._reactions.back_on_target(part, now)
            self._outbox.put(Event(EventKind.DIVERGENCE, part, now, "", self._inference.actual(part),
                                   self._inference.target(part)))
            return
        if new.is_error and part not in self._reported:  # once per divergence, not per attempt
            self._reported.add(part)
            why = f": {new.reason}" if new.reason else ""
            log.warning("Deviation detected in system or part '%s': should be %s, but is %s (%s%s).",
                        part, new.target, new.actual, new.cause.value, why)
        self._outbox.put(Event(EventKind.DIVERGENCE, part, now, "", new.actual, None, new))

    def _schedule_grace(self) -> None:
        """One timer, for the earliest grace period still running (a timer that fires for a grace
        period that ended early leaves the next one to be scheduled here, after settling)."""
        due = self._divergences.next_due()
        if due is None or (self._grace_due is not None and self._grace_due <= due):
            return
        if self._grace_timer is not None:
            self._grace_timer.cancel()
        self._grace_due = due
        self._grace_timer = self.clock.call_later(due - self.clock.now(), self._grace_over)

    def _grace_over(self) -> None:
        with self._entry():
            self._grace_timer = None
            self._grace_due = None
            self._divergences.grace_over(self.clock.now())

    def _emit(self, kind: EventKind, part: str, text: str = "", *, target: StateMode | None = None,
              divergence: Divergence | None = None, request: Request | None = None,
              previous: Actual | None = None, transition: Transition | None = None) -> None:
        actual = self._inference.actual(part) if part in self.model.parts else None
        self._outbox.put(Event(kind, part, self.clock.now(), text, actual, target, divergence, request, previous,
                               transition))

    def _apply(self, changes: Changes) -> None:
        now = self.clock.now()
        outbox, touch, watchers, confirming = (self._outbox, self._divergences.touch, self._watchers,
                                               self._confirming)
        for part, (old, new) in changes.items():
            outbox.actual(Event(EventKind.ACTUAL, part, now, "", new, None, None, None, old))
            touch(part)
            for watcher in watchers.get(part, ()):
                touch(watcher)
            if part in confirming:
                for execution in list(confirming[part]):
                    self.confirm(execution)

    def _check_part(self, part: str) -> None:
        if part not in self.model.parts:
            raise RequestError(f"unknown part {part!r}{did_you_mean(part, self.model.parts)} "
                               f"(parts: {', '.join(self.model.parts)})")

    def _check_node(self, node: str) -> None:
        self._check_part(node)
        if not isinstance(self.model.parts[node], NodePart):
            raise RequestError(f"{node} is a system, not a node (nodes: {', '.join(n.name for n in self.model.nodes)})")

    def _resolve_mode(self, part: str, mode: str) -> str | None:
        spec = self.model.parts[part]
        if mode in spec.modes:
            return mode
        if mode == DEFAULT_MODE:
            return spec.default_mode
        return None

    @staticmethod
    def _resolve_transition(transition: Transition | str | int, current: State) -> Transition:
        if isinstance(transition, Transition):
            return transition
        if isinstance(transition, int):
            return Transition(transition)
        return transition_by_label(transition, current)

    def _mode_for_activation(self, part: str) -> str:
        """Activation keeps the mode last asked for (the reference falls back to the default)."""
        return self._last_mode.get(part, self.model.parts[part].default_mode)


class _ReactionView:
    """The manager as rules and recovery see it."""

    def __init__(self, manager: ModeManager) -> None:
        self.actual = manager._inference.actual
        self.target = manager._inference.target
        self.observation = manager._inference.observation
        self.chosen_by = manager._divergences.chosen_by


class _DriverIO:
    """The manager as node drivers see it."""

    def __init__(self, manager: ModeManager) -> None:
        self._manager = manager

    def observation(self, node: str) -> NodeObservation:
        return self._manager._inference.observation(node)

    def now(self) -> float:
        return self._manager.clock.now()

    def send_transition(self, node: str, transition: Transition, done: Done) -> None:
        self._manager._send_transition(node, transition, done)

    def send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        self._manager._send_parameters(node, parameters, done)


class _Listener:
    """Adapts backend reports to the manager (kept out of the manager's public surface)."""

    def __init__(self, manager: ModeManager) -> None:
        self._manager = manager

    def node_appeared(self, node: str, report: NodeReport) -> None:
        self._manager._node_appeared(node, report)

    def node_state(self, node: str, state: State) -> None:
        self._manager._node_state(node, state)

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        self._manager._node_parameters(node, changed)

    def node_vanished(self, node: str, reason: str) -> None:
        self._manager._node_vanished(node, reason)


@dataclass(frozen=True)
class Return:
    """A node that had vanished, back: how long it was away, and its state and mode before and after."""

    node: str
    away: float  # seconds
    before: StateMode
    after: StateMode

    @property
    def changed(self) -> bool:
        return self.before != self.after

    def describe(self) -> str:
        """``unconfigured (back after 4.2 s; was active.f_normal)``, or ``... (back after 4.2 s, as before)``."""
        if self.changed:
            return f"{self.after} (back after {self.away:.1f} s; was {self.before})"
        return f"{self.after} (back after {self.away:.1f} s, as before)"
