"""The embedded mode manager: targets top-down, inference bottom-up, rules and recovery.

``ModeManager(model, backend)`` owns the targets of every part, keeps inference up to date from
what the backend reports, executes requests (``change_mode``/``change_state``) as confirmed,
ordered plans, and reacts to divergences: after a grace period, rules first (bottom-up), then a
bounded number of attempts to restore the target. Nothing here blocks; time comes from the
backend's clock, and every entry point is serialised by one re-entrant lock, so reports may
arrive from any thread.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager

from sm_bt.engine.backend import Backend, CallResult, Done, NodeReport
from sm_bt.engine.clock import TimerHandle
from sm_bt.engine.events import Cause, Divergence, Event, EventKind, Observer, Subscription
from sm_bt.engine.inference import Actual, Changes, Inference, NodeObservation
from sm_bt.engine.lifecycle import (
    REQUESTABLE,
    PlanError,
    Transition,
    first_transition,
    step_for,
    transition_by_label,
)
from sm_bt.engine.requests import Execution, Job, NodeJob, Origin, Parallel, Request, Sequence
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, Model, NodePart, ParamValue, SystemPart

log = logging.getLogger("sm_bt.manager")

#: Clock slack: a timer set for ``since + grace`` must find the grace period over when it fires.
_EPSILON = 1e-6
#: The primary state each requestable transition leads to.
_GOAL = {step.transition: step.goal for step in REQUESTABLE}


class ModeManager:
    """Manage the parts of ``model`` through ``backend``.

    ``request_timeout`` bounds every request (seconds of the backend's clock), ``grace_period``
    is how long a divergence must last, with no request working on it, before rules or recovery
    act, and ``recovery_attempts`` bounds how often a node is restored within ``recovery_window``
    seconds before it is reported as failed (a node that comes back and fails again at once
    still runs out of attempts; one that stays up for the window has them all again).
    ``rules=False``/``recovery=False`` switch those reactions off.
    """

    def __init__(self, model: Model, backend: Backend, *, request_timeout: float = 30.0,
                 grace_period: float = 2.0, recovery_attempts: int = 3, recovery_window: float = 60.0,
                 rules: bool = True, recovery: bool = True) -> None:
        self.model = model
        self.backend = backend
        self.clock = backend.clock
        self.request_timeout = request_timeout
        self.grace_period = grace_period
        self.recovery_attempts = recovery_attempts
        self.recovery_window = recovery_window
        self.rules_enabled = rules
        self.recovery_enabled = recovery
        self._lock = threading.RLock()
        self._inference = Inference(model)
        # The hierarchy never changes: walk it once, not on every node report.
        self._below = {name: frozenset(model.nodes_under(name)) for name in model.parts}
        self._above = {name: model.ancestors(name) for name in model.parts}
        self._bottom_up = sorted(model.parts, key=model.height)
        self._executions: dict[int, Execution] = {}
        self._divergences: dict[str, Divergence] = {}
        self._since: dict[str, float] = {}
        self._attempts: dict[str, list[float]] = {}  # when recovery last restored each node
        self._failed: set[str] = set()
        self._last_mode: dict[str, str] = {}  # the last active mode asked for, kept over deactivation
        self._subscriptions: list[Subscription] = []
        self._events: list[Event] = []
        self._depth = 0
        self._grace_timer: TimerHandle | None = None
        self._grace_due: float | None = None
        self._closed = False
        with self._entry():
            backend.attach([node.name for node in model.nodes], _Listener(self))

    # -- queries -------------------------------------------------------------------------------

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
            found = list(self._divergences.values())
        return [d for d in found if d.is_error] if errors_only else found

    def divergence(self, part: str) -> Divergence | None:
        with self._lock:
            return self._divergences.get(part)

    def available_modes(self, part: str) -> list[str]:
        """Every mode of ``part``, sorted byte-wise (as the reference's ``get_available_modes``)."""
        return sorted(self.model.part(part).modes)

    def reachable_modes(self, part: str) -> list[str]:
        """The modes of ``part`` that can still be reached with the nodes unavailable now
        (vanished, finalized, or given up by recovery) left as they are."""
        with self._lock:
            return [m for m in self.available_modes(part)
                    if self._reachable(part, StateMode(State.ACTIVE, m))]

    def failed(self) -> list[str]:
        """Nodes that recovery gave up on (they stay so until they reach a target again)."""
        with self._lock:
            return sorted(self._failed)

    def requests(self) -> list[Request]:
        """Requests in progress."""
        with self._lock:
            return [e.request for e in self._executions.values()]

    def observation(self, node: str) -> NodeObservation:
        """What the backend reported about ``node`` (state, parameters)."""
        with self._lock:
            return self._inference.observation(node)

    # -- commands ------------------------------------------------------------------------------

    def change_mode(self, part: str, mode: str, *, timeout: float | None = None) -> Request:
        """Ask for ``part`` (system or node) to be active in ``mode``. Returns at once."""
        if not mode:
            raise ValueError(f"change_mode of {part}: the mode name is empty (name a mode, or {DEFAULT_MODE} "
                             "for the default mode)")
        with self._entry():
            return self._request(part, StateMode(State.ACTIVE, mode), f"change_mode {part} {mode}", timeout)

    def change_state(self, part: str, transition: Transition | str | int, *,
                     timeout: float | None = None) -> Request:
        """Ask for a lifecycle transition of ``part`` (system or node): ``"configure"``,
        ``"activate"``, ``Transition.DEACTIVATE``, ... Returns at once. A part already in the
        transition's goal state succeeds at once."""
        with self._entry():
            name = transition.label if isinstance(transition, Transition) else str(transition)
            description = f"change_state {part} {name}"
            if part not in self.model.parts:
                return self._refuse(part, description, self._unknown_part(part))
            current = self._inference.actual(part).state
            try:
                resolved = self._resolve_transition(transition, current)
                if resolved not in _GOAL:
                    raise PlanError(f"{resolved.label} ({int(resolved)}) cannot be requested")
                goal = _GOAL[resolved]
                if current.is_primary and current is not goal:
                    step_for(current, resolved)  # raises with the valid ones when invalid here
            except (PlanError, ValueError) as error:
                return self._refuse(part, description, str(error))
            mode = self._mode_for_activation(part) if goal is State.ACTIVE else None
            return self._start(part, StateMode(goal, mode), description, Origin.USER, timeout, resolved)

    def change_to(self, part: str, target: StateMode | str, *, timeout: float | None = None) -> Request:
        """Ask for ``part`` to reach ``target`` (``"active.FAST"``, ``"inactive"``, a
        :class:`StateMode`), whatever it is in now: the plan takes every lifecycle step needed.
        Used to put a part back where it was (for instance after holding a mode). Returns at once."""
        with self._entry():
            try:
                wanted = target if isinstance(target, StateMode) else StateMode.parse(target)
            except ValueError as error:
                return self._refuse(part, f"change_to {part} {target}", str(error))
            description = f"change_to {part} {wanted}"
            if wanted.state not in (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE):
                return self._refuse(part, description, f"{wanted.state.label} is not a state to ask for "
                                    "(unconfigured, inactive or active)")
            return self._request(part, wanted, description, timeout)

    def _request(self, part: str, wanted: StateMode, description: str, timeout: float | None) -> Request:
        """Start a user request for ``wanted`` (an active mode resolved: ``None``/``__DEFAULT__``
        is the default mode), or refuse it with the part's real names."""
        if part not in self.model.parts:
            return self._refuse(part, description, self._unknown_part(part))
        if wanted.state is State.ACTIVE:
            resolved = self._resolve_mode(part, wanted.mode or "")
            if resolved is None:
                modes = ", ".join(self.available_modes(part))
                return self._refuse(part, description, f"unknown mode {wanted.mode!r} of {part} (modes: {modes})")
            wanted = StateMode(State.ACTIVE, resolved)
        return self._start(part, wanted, description, Origin.USER, timeout)

    def subscribe(self, callback: Observer, part: str | Iterable[str] | None = None,
                  kinds: Iterable[EventKind] | None = None) -> Subscription:
        """Call ``callback(event)`` for events of ``part`` (one, several, or all) and ``kinds``.

        Callbacks run inside the manager's lock, in the thread that caused the event; they may
        call the manager. Cancel with ``subscription.cancel()``.
        """
        parts = None if part is None else frozenset([part] if isinstance(part, str) else part)
        for name in parts or ():
            self._check_part(name)
        subscription = Subscription(callback, parts, None if kinds is None else frozenset(kinds),
                                    self._unsubscribe)
        with self._lock:
            self._subscriptions.append(subscription)
        return subscription

    def close(self) -> None:
        """Stop: cancel requests in flight and timers, detach from the backend."""
        with self._entry():
            for execution in list(self._executions.values()):
                self._finish(execution, False, "manager closed")
            if self._grace_timer is not None:
                self._grace_timer.cancel()
            self._closed = True
            self.backend.detach()

    # -- node reports (from the backend) -------------------------------------------------------

    def _node_appeared(self, node: str, report: NodeReport) -> None:
        with self._entry():
            self._failed.discard(node)
            self._attempts.pop(node, None)
            self._apply(self._inference.node_appeared(node, report.state, report.parameters, report.lifecycle))

    def _node_state(self, node: str, state: State) -> None:
        with self._entry():
            self._apply(self._inference.node_state(node, state))

    def _node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        with self._entry():
            self._apply(self._inference.node_parameters(node, changed))

    def _node_vanished(self, node: str, reason: str) -> None:
        with self._entry():
            self._apply(self._inference.node_vanished(node, reason))

    # -- calls to nodes (for jobs) --------------------------------------------------------------

    def _send_transition(self, node: str, transition: Transition, done: Done) -> None:
        log.info("  %s: %s", node, transition.label)
        self.backend.change_state(node, transition, self._serialised(done))

    def _send_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        log.info("  %s: set %d parameters", node, len(parameters))
        self.backend.set_parameters(node, parameters, self._serialised(done))

    def _serialised(self, done: Done) -> Done:
        def callback(result: CallResult) -> None:
            with self._entry():
                done(result)
        return callback

    # -- request execution ---------------------------------------------------------------------

    def _start(self, part: str, target: StateMode, description: str, origin: Origin,
               timeout: float | None, transition: Transition | None = None) -> Request:
        now = self.clock.now()
        request = Request(part, target, description, origin, now, withdraw=self._withdraw)
        log.info("-> request #%d %s [%s]", request.id, description, origin.value)
        scope = frozenset(self._nodes_targeted(part, target))
        for execution in list(self._executions.values()):
            if execution.scope & scope or execution.request.part == part:
                self._finish(execution, False, f"preempted by request #{request.id} ({description})")
        previous = self._assign_targets(part, target, transition)
        if origin is Origin.USER:
            for node in scope:
                self._attempts.pop(node, None)
                self._failed.discard(node)
        self._restart_grace(scope)
        # A part already in the target needs no step: its plan finishes in the first pump.
        job = self._plan(part, target)
        execution = Execution(request, job, scope, previous)
        self._executions[request.id] = execution
        limit = self.request_timeout if timeout is None else timeout
        execution.timer = self.clock.call_later(limit, lambda: self._timed_out(request.id, limit))
        self._emit(EventKind.REQUEST, part, f"#{request.id} {description} started", request=request)
        return request

    def _refuse(self, part: str, description: str, reason: str) -> Request:
        now = self.clock.now()
        request = Request(part, StateMode(State.UNKNOWN), description, Origin.USER, now)
        log.error("request %s refused: %s", description, reason)
        request._finish(False, reason, now)
        return request

    def _plan(self, part: str, target: StateMode) -> Job:
        spec = self.model.parts[part]
        if isinstance(spec, NodePart):
            mode = spec.modes.get(target.mode or spec.default_mode) if target.state is State.ACTIVE else None
            return NodeJob(_JobIO(self), part, target, mode)
        if target.state is State.ACTIVE:
            system_mode = spec.modes[target.mode or spec.default_mode]
            stages = [[self._plan(p, e.target) for p in stage
                       if (e := system_mode.entries[p]).target is not None] for stage in system_mode.stages]
        else:
            # Going down: tear down in the reverse of the default mode's bring-up order.
            default_stages = spec.modes[spec.default_mode].stages
            stages = [[self._plan(p, StateMode(target.state)) for p in stage] for stage in reversed(default_stages)]
        return Sequence([Parallel(jobs) for jobs in stages if jobs])

    def _assign_targets(self, part: str, target: StateMode,
                        transition: Transition | None = None) -> dict[str, StateMode | None]:
        """Set the target of ``part`` and, top-down, of every part its target implies."""
        previous: dict[str, StateMode | None] = {}

        def assign(name: str, value: StateMode) -> None:
            previous.setdefault(name, self._inference.target(name))
            self._set_target(name, value, transition if name == part else None)
            spec = self.model.parts[name]
            if isinstance(spec, SystemPart):
                if value.state is State.ACTIVE:
                    for entry in spec.modes[value.mode or spec.default_mode].entries.values():
                        if entry.target is not None:
                            assign(entry.part, entry.target)
                else:
                    for child in spec.parts:
                        assign(child, StateMode(value.state))

        assign(part, target)
        return previous

    def _nodes_targeted(self, part: str, target: StateMode) -> Iterator[str]:
        spec = self.model.parts[part]
        if isinstance(spec, NodePart):
            yield part
        elif target.state is State.ACTIVE:
            for entry in spec.modes[target.mode or spec.default_mode].entries.values():
                if entry.target is not None:
                    yield from self._nodes_targeted(entry.part, entry.target)
        else:
            for child in spec.parts:
                yield from self._nodes_targeted(child, StateMode(target.state))

    def _set_target(self, part: str, target: StateMode | None, transition: Transition | None = None) -> None:
        if target is not None and target.mode is not None:
            self._last_mode[part] = target.mode
        if self._inference.target(part) == target:
            return
        before = self._inference.actual(part)
        if transition is None and target is not None:
            transition = first_transition(before.state, target.state)
        self._emit(EventKind.TARGET, part, f"target {target}", target=target, previous=before, transition=transition)
        self._apply(self._inference.set_target(part, target))

    def _finish(self, execution: Execution, succeeded: bool, reason: str) -> None:
        request = execution.request
        self._executions.pop(request.id, None)
        execution.job.cancel()
        if execution.timer is not None:
            execution.timer.cancel()
        now = self.clock.now()
        request._finish(succeeded, reason, now)
        self._restart_grace(execution.scope)
        outcome = f"succeeded in {now - request.created:.2f} s" if succeeded else f"failed: {reason}"
        (log.info if succeeded else log.warning)("<- request #%d %s %s", request.id, request.description, outcome)
        self._emit(EventKind.REQUEST, request.part, f"#{request.id} {request.description} {outcome}",
                   request=request)

    def _withdraw(self, request: Request) -> None:
        with self._entry():
            execution = self._executions.get(request.id)
            if execution is None:
                return
            for part, target in execution.previous_targets.items():
                self._set_target(part, target)
            self._finish(execution, False, "cancelled")

    def _timed_out(self, request_id: int, limit: float) -> None:
        with self._entry():
            execution = self._executions.get(request_id)
            if execution is not None:
                self._finish(execution, False, f"timed out after {limit:g} s ({execution.request.feedback})")

    def _pump(self) -> None:
        for execution in list(self._executions.values()):
            if execution.request.id not in self._executions:
                continue  # finished by an earlier one's side effects
            job, request = execution.job, execution.request
            job.pump()
            if job.failure:
                self._finish(execution, False, job.failure)
                continue
            actual = self._inference.actual(request.part)
            if job.finished and actual.known and actual.state_mode == request.target:
                self._finish(execution, True, "")
            elif job.finished:
                request.feedback = f"confirming: {request.part} is {actual}, waiting for {request.target}"
            else:
                request.feedback = job.feedback()

    # -- divergences, rules, recovery ----------------------------------------------------------

    def _restart_grace(self, nodes: Iterable[str]) -> None:
        for node in nodes:
            self._since.pop(node, None)
            for above in self._above[node]:
                self._since.pop(above, None)

    def _evaluate(self) -> list[Divergence]:
        """Recompute the divergences, emit their changes, and return those that are faults."""
        now = self.clock.now()
        busy = self._busy_nodes()
        found: dict[str, Divergence] = {}
        for part in self._bottom_up:
            target = self._inference.target(part)
            actual = self._inference.actual(part)
            if target is None or (actual.known and actual.state_mode == target):
                self._since.pop(part, None)
                continue
            since = self._since.setdefault(part, now)
            nodes = self._below[part]
            if busy & nodes:
                cause = Cause.IN_FLIGHT
            elif now - since < self.grace_period - _EPSILON:
                cause = Cause.GRACE
            elif any(self._node_off_target(n) for n in nodes):
                cause = Cause.FAULT
            else:
                cause = Cause.OVERRIDE
            found[part] = Divergence(part, target, actual, since, cause)
        for part in self._divergences:
            if part not in found:
                self._failed.discard(part)
                self._emit(EventKind.DIVERGENCE, part, f"{part} is back on target {self._inference.target(part)}")
        for part, new in found.items():
            old_divergence = self._divergences.get(part)
            if old_divergence is None or (old_divergence.cause, old_divergence.actual) != (new.cause, new.actual):
                if new.is_error and (old_divergence is None or not old_divergence.is_error):
                    log.warning("Deviation detected in system or part '%s': should be %s, but is %s (%s).",
                                part, new.target, new.actual, new.cause.value)
                self._emit(EventKind.DIVERGENCE, part, str(new), divergence=new)
        self._divergences = found
        self._schedule_grace([d for d in found.values() if d.cause is Cause.GRACE])
        return [d for d in found.values() if d.cause is Cause.FAULT]

    def _node_off_target(self, node: str) -> bool:
        target = self._inference.target(node)
        actual = self._inference.actual(node)
        return target is not None and not (actual.known and actual.state_mode == target)

    def _schedule_grace(self, waiting: list[Divergence]) -> None:
        if not waiting:
            return
        due = min(d.since for d in waiting) + self.grace_period
        if self._grace_due is not None and self._grace_due <= due:
            return
        if self._grace_timer is not None:
            self._grace_timer.cancel()
        self._grace_due = due
        self._grace_timer = self.clock.call_later(due - self.clock.now(), self._grace_over)

    def _grace_over(self) -> None:
        with self._entry():
            self._grace_timer = None
            self._grace_due = None

    def _react(self, faults: list[Divergence]) -> None:
        """Rules bottom-up (nodes, then sub-systems, then systems); then restore what no rule covers."""
        fired: set[str] = set()
        if self.rules_enabled:
            for divergence in faults:  # already bottom-up
                owner = divergence.part
                if any(owner in self._above[f] for f in fired):
                    continue  # a lower rule is already correcting this
                for rule in self.model.parts[owner].rules:
                    condition = self._inference.actual(rule.if_part)
                    if rule.if_target == divergence.target and condition.known \
                            and condition.state_mode == rule.if_part_state:
                        log.info("applying rule %s of %s: %s is %s -> %s", rule.name, owner, rule.if_part,
                                 rule.if_part_state, rule.new_target)
                        self._emit(EventKind.RULE, owner,
                                   f"rule {rule.name}: {rule.if_part} is {rule.if_part_state} -> {rule.new_target}")
                        self._start(owner, rule.new_target, f"rule {rule.name} of {owner}", Origin.RULE, None)
                        fired.add(owner)
                        break
        if not self.recovery_enabled:
            return
        for divergence in faults:
            node = divergence.part
            if not isinstance(self.model.parts[node], NodePart) or node in self._failed:
                continue
            if node in fired or any(a in fired for a in self._above[node]):
                continue
            if self._inference.target(node) != divergence.target or node in self._busy_nodes():
                continue  # a rule above has just re-targeted it
            now = self.clock.now()
            recent = [t for t in self._attempts.get(node, []) if now - t < self.recovery_window]
            attempts = len(recent)
            if attempts >= self.recovery_attempts:
                self._failed.add(node)
                message = f"gave up restoring {node} to {divergence.target} after {attempts} attempts"
                log.error(message)
                self._emit(EventKind.FAILED, node, message, divergence=divergence)
                continue
            self._attempts[node] = [*recent, now]
            self._start(node, divergence.target, f"restore {node} to {divergence.target}", Origin.RECOVERY, None)

    def _busy_nodes(self) -> set[str]:
        busy: set[str] = set()
        for execution in self._executions.values():
            busy |= execution.scope
        return busy

    def _reachable(self, part: str, target: StateMode | None) -> bool:
        if target is None:
            return True
        spec = self.model.parts[part]
        if isinstance(spec, NodePart):
            if self._unavailable(part):
                actual = self._inference.actual(part)
                return actual.known and actual.state_mode == target
            return True
        if target.state is State.ACTIVE:
            entries = spec.modes[target.mode or spec.default_mode].entries.values()
            return all(self._reachable(e.part, e.target) for e in entries)
        return all(self._reachable(child, StateMode(target.state)) for child in spec.parts)

    def _unavailable(self, node: str) -> bool:
        obs = self._inference.observation(node)
        return node in self._failed or not obs.reachable or obs.state is State.FINALIZED

    # -- plumbing ------------------------------------------------------------------------------

    @contextmanager
    def _entry(self) -> Iterator[None]:
        """Every entry point: serialise; the outermost one then settles (pump, evaluate, react)
        and notifies observers. Observers may call back in: those calls only queue their effects,
        which the outermost entry settles before it returns."""
        with self._lock:
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
            if self._depth or self._closed:
                return
            self._depth += 1
            try:
                self._settle()
                while self._events:
                    self._notify(self._events.pop(0))
                    self._settle()
            finally:
                self._depth -= 1

    def _settle(self) -> None:
        for _ in range(100):  # reactions start requests, which need pumping; bounded for safety
            before = set(self._executions)
            self._pump()
            faults = self._evaluate()
            if faults:
                self._react(faults)
            if set(self._executions) <= before:
                return

    def _notify(self, event: Event) -> None:
        for subscription in list(self._subscriptions):
            if subscription.wants(event):
                try:
                    subscription.callback(event)
                except Exception:  # an observer's bug must not break the manager
                    log.exception("observer %r failed on %s", subscription.callback, event.kind.value)

    def _emit(self, kind: EventKind, part: str, message: str, *, target: StateMode | None = None,
              divergence: Divergence | None = None, request: Request | None = None,
              previous: Actual | None = None, transition: Transition | None = None) -> None:
        actual = self._inference.actual(part) if part in self.model.parts else None
        self._events.append(Event(kind, part, self.clock.now(), message, actual=actual, target=target,
                                  divergence=divergence, request=request, previous=previous,
                                  transition=transition))

    def _apply(self, changes: Changes) -> None:
        for part, (old, new) in changes.items():
            self._emit(EventKind.ACTUAL, part, f"{part}: {old} -> {new}", previous=old)

    def _unsubscribe(self, subscription: Subscription) -> None:
        with self._lock:
            if subscription in self._subscriptions:
                self._subscriptions.remove(subscription)

    def _check_part(self, part: str) -> None:
        if part not in self.model.parts:
            raise KeyError(self._unknown_part(part))

    def _unknown_part(self, part: str) -> str:
        return f"unknown part {part!r} (parts: {', '.join(self.model.parts)})"

    def _resolve_mode(self, part: str, mode: str) -> str | None:
        spec = self.model.parts[part]
        if mode in spec.modes:
            return mode
        if mode in ("", DEFAULT_MODE):
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


class _JobIO:
    """The manager as jobs see it (``NodeIO``)."""

    def __init__(self, manager: ModeManager) -> None:
        self._manager = manager

    def observation(self, node: str) -> NodeObservation:
        return self._manager._inference.observation(node)

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

