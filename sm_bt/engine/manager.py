"""The embedded mode manager: targets top-down, inference bottom-up, rules and recovery.

``ModeManager(model, backend)`` owns the targets of every part, keeps inference up to date from
what the backend reports, carries requests (``change_mode``/``change_state``/``change_to``) out as
confirmed, ordered plans, and reacts to divergences: after a grace period, rules first
(bottom-up), then restoring nodes, within a budget.

It is a façade over the pieces that do the work, each with its own module:

* :mod:`~sm_bt.engine.serialiser`: every entry point, one at a time; the outermost settles, then
  tells the observers;
* :mod:`~sm_bt.engine.ledger`: the targets and actuals, and the events their changes make;
* :mod:`~sm_bt.engine.executions`: requests carried out (the last request wins; a refused request
  changes nothing and is done at once; the semantics docs/manager.md states);
* :mod:`~sm_bt.engine.presence`: what the backend reports of the nodes;
* :mod:`~sm_bt.engine.divergences`, :mod:`~sm_bt.engine.responses` and
  :mod:`~sm_bt.engine.reactions`: divergences, their grace periods, and the rules and recovery
  that answer them.

Nothing here blocks; time comes from the backend's clock. Settling works through the agenda (plans
handing over to their next steps), re-examines the divergences that changed and reacts to faults,
until nothing is left to do. The work per event is proportional to what the event changed.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from typing import cast

from sm_bt.engine.backend import Backend
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.drivers import BackendIO, NodeDriver
from sm_bt.engine.events import Divergence, EventKind, Observer, Subscription
from sm_bt.engine.executions import CLOSED, Executions
from sm_bt.engine.hierarchy import Hierarchy, implied_targets
from sm_bt.engine.holds import Hold, Holds
from sm_bt.engine.inference import Actual, Inference, NodeObservation
from sm_bt.engine.ledger import Ledger
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.presence import NodeReports, NodeReturn
from sm_bt.engine.preview import Configuration, Preview, preview
from sm_bt.engine.reactions import Reactions
from sm_bt.engine.request_checks import check_node, check_part, failure_policy, mode_target, modes_of, state_target
from sm_bt.engine.requests import Origin, Request
from sm_bt.engine.responses import Responses
from sm_bt.engine.serialiser import Serialiser
from sm_bt.engine.settling import Settling
from sm_bt.engine.snapshots import PartSnapshot
from sm_bt.model.errors import RequestError
from sm_bt.model.gc_tuning import gc_paused
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, Model, NodePart

__all__ = ["CLOSED", "REQUEST_TIMEOUT", "ModeManager", "NodeReturn"]

log = logging.getLogger("sm_bt.manager")
#: How long a request may take, by default (seconds of the backend's clock).
REQUEST_TIMEOUT = 30.0

#: The primary state each requestable transition leads to.


class ModeManager:
    """Manage the parts of ``model`` through ``backend``.

    ``request_timeout`` bounds every request (seconds of the backend's clock); ``grace_period``
    is how long a divergence must last, with no request working on it, before rules or recovery
    act. Rules and recovery share a budget per part: ``recovery_attempts`` reactions in a run of
    failures; it is whole again once the part stayed on target for ``recovery_window`` seconds
    (a node that comes back and fails again at once still runs out). After that the part is
    *given up* and its divergence says why. ``rules=False``/``recovery=False`` switch those
    reactions off. ``on_failure`` is what a request that fails by itself leaves behind, unless it
    says otherwise: ``"stay"`` (the nodes stay where the failure left them), ``"rollback"`` (they
    are put back where they were) or ``"mode:<name>"`` (:mod:`~sm_bt.engine.rollback`).
    ``priorities`` (requester -> priority) decide between requesters when a part is held
    (:meth:`hold`, :mod:`~sm_bt.engine.holds`).
    """

    def __init__(self, model: Model, backend: Backend, *, request_timeout: float = REQUEST_TIMEOUT,
                 grace_period: float = 2.0, recovery_attempts: int = 3, recovery_window: float = 60.0,
                 rules: bool = True, recovery: bool = True, on_failure: str = "stay",
                 priorities: Mapping[str, int] | None = None) -> None:
        with gc_paused():  # a manager of 100,000 nodes is millions of objects (sm_bt.model.gc_tuning)
            self.model = model
            self.backend = backend
            self.clock = backend.clock
            self._serial = Serialiser()
            self._lock = self._serial.lock
            self._hierarchy = Hierarchy.of(model)
            self._inference = Inference(model, self._hierarchy)
            self._divergences = Divergences(model, self._hierarchy, self._inference, grace_period)
            self._reactions = Reactions(model, self._hierarchy, attempts=recovery_attempts, window=recovery_window,
                                        rules=rules, recovery=recovery)
            self._ledger = Ledger(model, self._inference, self._divergences, self._serial.outbox, self.clock)
            io = BackendIO(self._inference, self.clock, backend, self._serial)
            self._drivers = {node.name: NodeDriver(node.name, io) for node in model.nodes}
            self._responses = Responses(self._ledger, self._divergences, self._reactions, self._serial, self.clock)
            renew = self._responses.renew_budgets
            self._executions = Executions(self._ledger, self._divergences, self._reactions, self._drivers, self._serial,
                                          self.clock, request_timeout=request_timeout, renew_budgets=renew,
                                          on_failure=on_failure)
            self._executions.holds = Holds(self.clock, priorities, locked=self._entered,
                                           told=lambda hold, text: self._ledger.emit(EventKind.HOLD, hold.part, text))
            self._executions.holds.ended = self._executions.waiting.hold_ended
            self._reports = NodeReports(self._ledger, self._divergences, self._executions, self._hierarchy,
                                        self._drivers, self._serial, self.clock, renew_budgets=renew)
            self._serial.work = Settling(self._serial, self._divergences, self._responses, self._executions, self.clock,
                                         self._inference.actual)
            with self._serial:
                backend.attach([node.name for node in model.nodes], self._reports)

    @property
    def request_timeout(self) -> float:
        return self._executions.request_timeout

    # -- settings ---------------------------------------------------------------------------------

    @property
    def on_failure(self) -> str:
        return self._executions.on_failure

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

    def observe_target(self, part: str, target: StateMode | None) -> None:
        """Take ``target`` as ``part``'s target without asking anything of its nodes: another
        manager, heard on its request topics, works on it. For a manager that only watches (rules
        and recovery off: ``sm-bt monitor --ros`` next to ``sm-bt manager``), so that it shows
        targets and divergences as that manager has them."""
        with self._serial:
            self._check_part(part)
            self._ledger.set_target(part, target)

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
        return modes_of(self.model, part)

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
            return self._executions.requests()

    def observation(self, node: str) -> NodeObservation:
        """What the backend reported about ``node`` (state, parameters)."""
        with self._lock:
            self._check_node(node)
            return self._inference.observation(node)

    def status(self, part: str) -> PartSnapshot:
        """``part`` as the manager knows it now, read at once (:mod:`sm_bt.engine.snapshots`)."""
        with self._lock:
            self._check_part(part)
            return self._status(part)

    def snapshot(self) -> list[PartSnapshot]:
        """Every part, in the model's order, read at one moment."""
        with self._lock:
            return [self._status(part) for part in self.model.parts]

    def _status(self, part: str) -> PartSnapshot:
        spec = self.model.parts[part]
        node = isinstance(spec, NodePart)
        observation = self._inference.observation(part) if node else None
        return PartSnapshot(part, spec.kind, self._inference.actual(part), self._inference.target(part),
                            self._divergences.records.get(part), part in self._reactions.gave_up,
                            observation.reachable if observation is not None else None,
                            observation.gone if observation is not None else "",
                            self._reports.returns.get(part) if node else None,
                            "; ".join(hold.holder() for hold in self._executions.holds.on(part)))

    def last_return(self, node: str) -> NodeReturn | None:
        """How ``node`` came back the last time it had vanished (``None``: it never did)."""
        with self._lock:
            self._check_node(node)
            return self._reports.returns.get(node)

    # -- commands ---------------------------------------------------------------------------------

    def change_mode(self, part: str, mode: str, *, timeout: float | None = None, requester: str = "user",
                    on_failure: str | None = None, priority: int | None = None, queue: bool = False) -> Request:
        """Ask for ``part`` (system or node) to be active in ``mode`` (``__DEFAULT__`` names its
        default mode). Returns at once. :class:`RequestError` for a part or mode the model does not
        have, or an empty mode name. ``requester`` says who asks, for logs and narratives
        (:attr:`Request.requester`: sm_bt's behaviours say ``"tree"``); ``on_failure``: this
        request's failure policy (default: the manager's); ``priority``: against the parts'
        holds (default: the requester's): a part held at a higher one refuses the request, or
        with ``queue`` makes it wait until the hold ends or its ``timeout`` runs out."""
        if not mode:
            raise RequestError(f"change_mode of {part}: the mode name is empty (name a mode, or {DEFAULT_MODE} "
                               "for the default mode)")
        # A request's start is a plan, targets and calls for every node below the part, long-lived
        # objects that the collector's passes would walk again and again meanwhile (sm_bt.model.gc_tuning).
        with gc_paused(), self._serial:
            return self._request(part, StateMode(State.ACTIVE, mode), f"change_mode {part} {mode}", timeout,
                                 requester, on_failure, priority, queue)

    def change_state(self, part: str, transition: Transition | str | int, *,
                     timeout: float | None = None, requester: str = "user", on_failure: str | None = None,
                     priority: int | None = None, queue: bool = False) -> Request:
        """Ask for a lifecycle transition of ``part`` (system or node): ``"configure"``,
        ``"activate"``, ``Transition.DEACTIVATE``, ... Returns at once. A settled part must be in
        a state the transition is valid from (as a lifecycle node requires), or already in its
        goal state (then it succeeds at once); while a request is moving the part, any requestable
        transition is accepted and its goal state becomes the new target. Activation keeps the
        last mode asked for. :class:`RequestError` for a part the model does not have, or a
        transition that does not exist or cannot be requested; one not valid from where the part
        is now is a refused request. ``on_failure``, ``priority``, ``queue``: as :meth:`change_mode`'s."""
        with gc_paused(), self._serial:  # as change_mode's
            self._check_part(part)
            description, target, resolved, refusal = self._change_state_target(
                part, transition, self._inference.actual(part).state, self._moving(part))
            if refusal:
                return self._executions.refuse(part, description, refusal, requester)
            return self._executions.start(part, target, description, Origin.USER, timeout, resolved,
                                          requester=requester, on_failure=failure_policy(self.model, part, on_failure),
                                          priority=priority, queue=queue)

    def preview(self, part: str, mode: str, *, from_: Configuration | None = None) -> Preview:
        """The plan ``change_mode(part, mode)`` would be carried out by now, without doing anything:
        stages, each node's calls and parameter changes, rules that would start or stop firing,
        or why it would be refused (:class:`~sm_bt.engine.preview.Preview`). ``from_``: preview
        from that configuration instead (:func:`~sm_bt.engine.preview.configuration`; offline)."""
        description = f"change_mode {part} {mode}"
        with self._serial:
            target = mode_target(self.model, part, StateMode(State.ACTIVE, mode or DEFAULT_MODE), description)
            return self._preview(part, target, description, "", from_)

    def preview_state(self, part: str, transition: Transition | str | int, *,
                      from_: Configuration | None = None) -> Preview:
        """The plan ``change_state(part, transition)`` would be carried out by now (see :meth:`preview`)."""
        with self._serial:
            self._check_part(part)
            config = from_ or Configuration(self._inference)
            current = config.actual(part).state
            description, target, _, refusal = self._change_state_target(part, transition, current,
                                                                  from_ is None and self._moving(part))
            if target.state is State.ACTIVE and from_ is not None:
                target = StateMode(State.ACTIVE, self.model.parts[part].default_mode)
            return self._preview(part, target, description, refusal, from_)

    def plan_of(self, request: Request) -> Preview | None:
        """The plan ``request`` is carried out by, previewed from where the parts were when it
        started (made when first asked for: a view shows it next to the request); ``None`` for a
        refused request or a rollback."""
        make = request._plan
        return cast(Preview, make()) if make is not None else None

    def _preview(self, part: str, target: StateMode, description: str, refusal: str,
                 from_: Configuration | None) -> Preview:
        return preview(self.model, from_ or Configuration(self._inference), part, target, description, refusal,
                       shapes=self._executions.shapes)

    def change_to(self, part: str, target: StateMode | str, *, timeout: float | None = None,
                  requester: str = "user", on_failure: str | None = None, priority: int | None = None,
                  queue: bool = False) -> Request:
        """Ask for ``part`` to reach ``target`` (``"active.FAST"``, ``"inactive"``, a
        :class:`StateMode`), whatever it is in now: the plan takes every lifecycle step needed.
        Used to put a part back where it was (for instance after holding a mode). Returns at once.
        :class:`RequestError` for a part or mode the model does not have, or a target that is not
        one to ask for."""
        with self._serial:
            try:
                wanted = target if isinstance(target, StateMode) else StateMode.parse(target)
            except ValueError as error:
                raise RequestError(f"change_to {part} {target}: {error}") from None
            description = f"change_to {part} {wanted}"
            if wanted.state not in (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE):
                raise RequestError(f"{description}: {wanted.state.label} is not a state to ask for "
                                   "(unconfigured, inactive or active)")
            return self._request(part, wanted, description, timeout, requester, on_failure, priority, queue)

    def hold(self, part: str, mode: str, *, requester: str = "user", priority: int | None = None,
             lease: float | None = None, timeout: float | None = None) -> Hold:
        """Keep ``part`` active in ``mode`` for ``requester`` at ``priority`` (default: the
        requester's) until :meth:`Hold.release`, or until ``lease`` seconds pass without
        :meth:`Hold.renew`: requests of a lower priority that would change it (or a node below
        it) are refused, naming the holder. The change itself is :attr:`Hold.request`; when it is
        refused (by a higher hold, a node out of reach) the hold is not made (``active`` false,
        ``reason`` says why)."""
        description = f"hold {part} {mode} [{requester}]"
        with self._serial:
            target = mode_target(self.model, part, StateMode(State.ACTIVE, mode or DEFAULT_MODE), description)
            request = self._executions.start(part, target, f"change_mode {part} {mode}", Origin.USER, timeout,
                                             requester=requester, priority=priority)
            holds = self._executions.holds
            level = holds.priority_of(requester, priority)
            if request.refused:
                return Hold(part, target, requester, level, self.clock.now(), lease, {}, active=False,
                            reason=request.reason, request=request)
            made = holds.add(part, target, dict(implied_targets(self.model, part, target)), requester, level, lease)
            made.request = request
            return made

    def holds(self) -> list[Hold]:
        """The holds in force, oldest first."""
        with self._serial:
            return list(self._executions.holds)

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
        with self._serial:
            for execution in self._executions.in_progress():
                self._executions.finish(execution, False, CLOSED)
            self._responses.cancel()
            self._executions.waiting.close(CLOSED)
            self._executions.holds.close()
            self._serial.closed = True
            self.backend.detach()

    # -- requests -----------------------------------------------------------------------------------

    def _request(self, part: str, wanted: StateMode, description: str, timeout: float | None,
                 requester: str, on_failure: str | None = None, priority: int | None = None,
                 queue: bool = False) -> Request:
        """Start a user request for ``wanted`` (an active mode resolved: ``__DEFAULT__`` is the
        default mode); :class:`RequestError` with the part's real names for one it does not have."""
        wanted = mode_target(self.model, part, wanted, description)
        return self._executions.start(part, wanted, description, Origin.USER, timeout, requester=requester,
                                      on_failure=failure_policy(self.model, part, on_failure), priority=priority,
                                      queue=queue)

    def _change_state_target(self, part: str, transition: Transition | str | int, current: State,
                             moving: bool) -> tuple[str, StateMode, Transition, str]:
        return state_target(part, transition, current, moving, self._ledger.mode_for_activation(part))

    def _entered(self, action: Callable[[], None]) -> None:
        with self._serial:
            action()

    # -- reachability ---------------------------------------------------------------------------

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

    def _check_part(self, part: str) -> None:
        check_part(self.model, part)

    def _check_node(self, node: str) -> None:
        check_node(self.model, node)
