"""Requests being carried out: admission (what a request drives, what it preempts, whether it
is refused), one :class:`Execution` per request with its plan, and their ends (confirmed,
failed, withdrawn, timed out).

* **The last request wins.** A request preempts every request in flight that drives one of the
  same nodes (or asks for the same part): those end FAILURE "preempted by request #N (...)".
  The new one starts from where the nodes are heading; what a preempted request asked of the
  nodes the new one does not drive carries on as a *continuation*.
* A request ends SUCCESS once every node reached its goal and the part's inferred actual is the
  target; FAILURE with the reason as soon as one step cannot be taken, or ``timeout`` runs out.
* A user request for a node out of reach (vanished, finalized) is refused as a whole: nothing
  changes.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Iterable, Mapping

from sm_bt.engine.actual import out_of_reach
from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.drivers import NodeDriver
from sm_bt.engine.events import EventKind
from sm_bt.engine.hierarchy import implied_targets
from sm_bt.engine.holds import Hold, Holds
from sm_bt.engine.ledger import Ledger
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.plans import Job, NodeJob, Sequence, Shapes, build_plan
from sm_bt.engine.preview import Configuration, preview
from sm_bt.engine.reactions import Reactions
from sm_bt.engine.requests import Origin, Request
from sm_bt.engine.rollback import MODE_POLICY, Before, check_policy, reverse_plan, snapshot
from sm_bt.engine.serialiser import Serialiser
from sm_bt.engine.waiting import Waiting
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import NodePart

log = logging.getLogger("sm_bt.manager")
#: Why a request fails or is refused once the manager is closed.
CLOSED = "the manager is closed"


class Execution:
    """``request`` in progress: its plan over ``scope`` (the nodes it drives), and the targets it
    replaced (restored if it is withdrawn).

    A *continuation* (``continuation=True``) carries on with the nodes of a preempted request
    that the preempting one does not drive: its plan holds only those nodes, and it is done when
    they reached their goals (the part as a whole is no longer expected to reach the target).
    """

    def __init__(self, executions: Executions, request: Request, scope: frozenset[str],
                 previous_targets: dict[str, tuple[StateMode | None, Origin | None]],
                 continuation: bool = False, rolls_back: Execution | None = None) -> None:
        self.executions = executions
        self.request = request
        self.scope = scope
        self.previous_targets = previous_targets
        self.continuation = continuation
        self.active = True
        self.planned = False  # every step reached its goal; waiting for the part's actual to confirm
        self.timer: TimerHandle | None = None
        self.limit = 0.0  # its timeout, seconds
        #: With the rollback policy: where its nodes were when it began.
        self.before: dict[str, Before] = {}
        #: The failed execution this one puts back (its nodes' goals are where they were).
        self.rolls_back = rolls_back
        self.failure = ""  # why it failed, while it is being rolled back
        self.root: Job
        self.steps: list[NodeJob]
        if rolls_back is not None:
            goals = {name: rolls_back.before[name].goal(name, rolls_back.request.id) for name in scope}
            self.root, self.steps = reverse_plan(self, rolls_back.root, goals)
        else:
            self.root, self.steps = build_plan(executions.model, self, request.part, request.target,
                                               scope if continuation else None, executions.shapes)

    # -- the plan's run (see plans.Run) ---------------------------------------------------------

    def defer(self, action: Callable[[], None]) -> None:
        self.executions.defer(action)

    def driver(self, node: str) -> NodeDriver:
        return self.executions.driver(node)

    def plan_done(self) -> None:
        if self.active:
            self.planned = True
            self.executions.confirm(self)

    def plan_failed(self, reason: str) -> None:
        if self.active:
            self.executions.fail(self, reason)

    # -- life -----------------------------------------------------------------------------------

    def start(self) -> None:
        self.defer(self.root.start)

    def stop(self) -> None:
        """No further steps: the drivers are released (calls in flight still complete)."""
        self.active = False
        if self.timer is not None:
            self.timer.cancel()
        for step in self.steps:
            step.release()

    def dismantle(self) -> None:
        """Over for good (no rollback will read its plan): its plan lets go of it (no cycles left)."""
        self.root.dismantle()
        self.steps = []
        self.timer = None

    # -- what it is doing -----------------------------------------------------------------------

    def _running(self) -> list[NodeJob]:
        return [s for s in self.steps if s.started and not s.done]

    def feedback(self) -> str:
        if self.planned:
            return f"confirming {self.request.part} is {self.request.target}"
        running = self._running()
        text = "; ".join(self.driver(s.node).describe() for s in running) or "starting"
        root = self.root
        if isinstance(root, Sequence) and len(root.children) > 1 and root.index < len(root.children):
            return f"stage {root.index + 1}/{len(root.children)}: {text}"
        return text

    def stall(self) -> str:
        """Why it is not done yet (for a timeout)."""
        running = self._running()
        if not running:
            return self.feedback()
        return "; ".join(self.driver(s.node).stall() for s in running)


class Executions:
    """The requests in progress, carried out on ``drivers`` (one per node) and booked in ``ledger``.
    ``renew_budgets(parts)``: a user asked for ``parts``, so rules and recovery may act on them again."""

    def __init__(self, ledger: Ledger, divergences: Divergences, reactions: Reactions,
                 drivers: Mapping[str, NodeDriver], serialiser: Serialiser, clock: Clock, *,
                 request_timeout: float, renew_budgets: Callable[[Iterable[str]], None],
                 on_failure: str = "stay") -> None:
        self.model = ledger.model
        self.request_timeout = request_timeout
        #: The failure policy of a user request that names none (:mod:`sm_bt.engine.rollback`).
        self.on_failure = check_policy(on_failure)
        #: Plan shapes, shared with the manager's previews.
        self.shapes = Shapes(self.model)
        #: The holds in force (:mod:`sm_bt.engine.holds`); the manager makes them.
        self.holds = Holds(clock)
        #: The requests waiting for holds to end (``queue=True``).
        self.waiting = Waiting(clock, serialiser, self._end)
        self._ledger = ledger
        self._inference = ledger.inference
        self._divergences = divergences
        self._reactions = reactions
        self._drivers = drivers
        self._serialiser = serialiser
        self._clock = clock
        self._renew_budgets = renew_budgets
        self._executions: dict[int, Execution] = {}
        self._confirming: dict[str, set[Execution]] = {}  # part -> executions waiting for its actual
        ledger.reached = self._reached

    # -- what executions need (see Execution) ------------------------------------------------------

    def defer(self, action: Callable[[], None]) -> None:
        self._serialiser.defer(action)

    def driver(self, node: str) -> NodeDriver:
        return self._drivers[node]

    # -- queries -----------------------------------------------------------------------------------

    def requests(self) -> list[Request]:
        return [e.request for e in self._executions.values()]

    def driving(self, node: str) -> list[Execution]:
        """The executions whose plans drive ``node``."""
        return [e for e in self._executions.values() if node in e.scope]

    def in_progress(self) -> list[Execution]:
        return list(self._executions.values())

    # -- admission ---------------------------------------------------------------------------------

    def start(self, part: str, target: StateMode, description: str, origin: Origin,
              timeout: float | None, transition: Transition | None = None, *, requester: str | None = None,
              on_failure: str | None = None, priority: int | None = None, queue: bool = False,
              queued: Request | None = None) -> Request:
        """Carry out a request for ``target`` of ``part`` (an active mode resolved); the request
        that preempts what it overlaps, or a refused one. ``on_failure``: a user request's failure
        policy (default: the manager's); ``priority``: its priority against the holds (default:
        its requester's, :mod:`sm_bt.engine.holds`); ``queue``: held back by a hold, it waits
        (:mod:`sm_bt.engine.waiting`) rather than being refused; ``queued``: such a request, now
        free to start."""
        if self._serialiser.closed:  # detached from the backend: nothing it starts could ever end
            return self.refuse(part, description, CLOSED, requester, queued)
        implied = implied_targets(self.model, part, target)
        scope = frozenset(name for name, _ in implied if isinstance(self.model.parts[name], NodePart))
        overridden: list[Hold] = []
        if origin is not Origin.RECOVERY:  # recovery restores the targets the holds set
            why = ("; ".join(filter(None, (self._out_of_reach(n, t) for n, t in implied if n in scope)))
                   if origin is Origin.USER else "")
            if not why and self.holds:
                level = self.holds.priority_of(requester or origin.value, priority)
                why = self.holds.refusal(dict(implied), level)
                overridden = self.holds.overridden(dict(implied), level)
                if why and queue:
                    request = queued or Request(part, target, description, origin, self._clock.now(),
                                                withdraw=self._withdraw, requester=requester)
                    self.waiting.add(request, why, self.request_timeout if timeout is None else timeout,
                                     lambda: self.holds.refusal(dict(implied), level),
                                     lambda: self.start(part, target, description, origin, timeout, transition,
                                                        requester=requester, on_failure=on_failure,
                                                        priority=priority, queued=request))
                    return request
            if why:  # refused as a whole: nothing is changed
                return self.refuse(part, description, why, requester, queued)
        request = queued or Request(part, target, description, origin, self._clock.now(), withdraw=self._withdraw,
                                    requester=requester)
        # A rule's or recovery's request follows its own log line: the start is detail then.
        (log.info if origin is Origin.USER else log.debug)("request #%d %s started [%s]", request.id, description,
                                                           request.requester)
        for hold in overridden:  # the last request wins at the same or a higher priority, as ever
            self.holds.end(hold, f"superseded by request #{request.id} ({description}) of {request.requester}")
        preempted = [e for e in self._executions.values() if e.scope & scope or e.request.part == part]
        for execution in preempted:
            self.finish(execution, False, f"preempted by request #{request.id} ({description})")
        if origin is Origin.USER:
            request.on_failure = check_policy(on_failure or self.on_failure)
        # Where the parts are now, kept for the request's preview (made only if asked for, once).
        kept = Configuration(self._inference).kept(name for name, _ in implied)
        request._plan = functools.cache(lambda: preview(self.model, kept, part, target, description,
                                                        shapes=self.shapes))
        before = snapshot(self.model, scope, self._inference.observations) if request.on_failure == "rollback" else {}
        previous = self._assign_targets(implied, origin, transition)
        if origin is Origin.USER:
            self._renew_budgets(previous)
        execution = Execution(self, request, scope, previous)
        execution.before = before
        self._run(execution, timeout)
        # The last request wins where it drives; elsewhere what the preempted ones asked for stands.
        for execution in preempted:
            if execution.scope - scope:
                self._continue(execution, execution.scope - scope)
        return request

    def refuse(self, part: str, description: str, reason: str, requester: str | None = None,
               queued: Request | None = None) -> Request:
        now = self._clock.now()
        request = queued or Request(part, StateMode(State.UNKNOWN), description, Origin.USER, now, requester=requester)
        log.warning("request %s refused: %s", description, reason)
        request.refused = True
        request._finish(False, reason, now)
        if part in self.model.parts:  # told, as any request's end (it never started)
            self._ledger.emit(EventKind.REQUEST, part, f"{description} refused: {reason}", request=request)
        return request

    def _out_of_reach(self, node: str, target: StateMode) -> str:
        """Why ``node`` cannot be taken to ``target`` as far as the manager knows ("" if it can)."""
        return out_of_reach(node, self._inference.observation(node), target)

    def _continue(self, preempted: Execution, nodes: frozenset[str]) -> None:
        """Carry on with ``nodes`` of a preempted request: their targets are still what it asked."""
        old = preempted.request
        description = f"continue #{old.id} ({old.description}) for {', '.join(sorted(nodes))}"
        request = Request(old.part, old.target, description, old.origin, self._clock.now(), withdraw=self._withdraw,
                          requester=old.requester, parts=tuple(sorted(nodes)))
        (log.info if old.origin is Origin.USER else log.debug)("request #%d %s started [%s]", request.id,
                                                               description, request.requester)
        self._run(Execution(self, request, nodes, {}, continuation=True), None)

    def _run(self, execution: Execution, timeout: float | None) -> None:
        request = execution.request
        request._progress = lambda: self._serialiser.locked(execution.feedback)
        self._executions[request.id] = execution
        self._divergences.busy(execution.scope, +1)
        limit = self.request_timeout if timeout is None else timeout
        execution.limit = limit
        execution.timer = self._clock.call_later(limit, lambda: self._timed_out(execution, limit))
        self._ledger.emit(EventKind.REQUEST, request.part, f"#{request.id} {request.description} started",
                          request=request)
        execution.start()

    def _assign_targets(self, implied: list[tuple[str, StateMode]], origin: Origin,
                        transition: Transition | None) -> dict[str, tuple[StateMode | None, Origin | None]]:
        """Set the targets (the requested part first, then top-down below it); return what they
        were, with who had chosen them."""
        previous: dict[str, tuple[StateMode | None, Origin | None]] = {}
        for index, (name, value) in enumerate(implied):
            previous[name] = (self._inference.target(name), self._divergences.chosen_by(name))
            self._ledger.set_target(name, value, transition if index == 0 else None)
            if index > 0:
                self._divergences.chosen(name, None)
            elif origin is not Origin.RECOVERY:  # restoring a node keeps who chose its target
                self._divergences.chosen(name, origin)
        return previous

    # -- ends --------------------------------------------------------------------------------------

    def confirm(self, execution: Execution) -> None:
        """The plan is done: succeed once every part the request is about is at its target (the
        request's part at the request's target; a continuation's nodes at theirs)."""
        request = execution.request
        if execution.rolls_back is not None:  # its steps checked each node's state and values
            self.finish(execution, True, "")
            return
        off = []
        for part in request.parts:
            wanted = self._inference.target(part) if execution.continuation else request.target
            if wanted is not None and not self._inference.actual(part).is_(wanted):
                off.append(part)
        if not off:
            self.finish(execution, True, "")
        for part in off:
            self._confirming.setdefault(part, set()).add(execution)
            self._ledger.waiting.add(part)

    def _reached(self, part: str) -> None:
        """``part``'s actual changed (the ledger): the executions waiting on it look again."""
        for execution in list(self._confirming.get(part, ())):
            self.confirm(execution)

    def finish(self, execution: Execution, succeeded: bool, reason: str) -> None:
        if not execution.active:
            return
        self._close(execution)
        if execution.rolls_back is not None:
            self._end(execution.request, succeeded, reason)
            failed = execution.rolls_back
            self._end(failed.request, False, self._rolled_back(failed, succeeded, reason))
            failed.dismantle()
            execution.dismantle()
            return
        self._end(execution.request, succeeded, reason)
        execution.dismantle()

    def fail(self, execution: Execution, reason: str) -> None:
        """``execution``'s request failed by itself (a step, its timeout): what its failure policy
        says happens (:mod:`sm_bt.engine.rollback`)."""
        if not execution.active:
            return
        request = execution.request
        if request.on_failure == "rollback" and execution.before:
            self._roll_back(execution, reason)
        elif request.on_failure.startswith(MODE_POLICY):
            mode = request.on_failure[len(MODE_POLICY):]
            if mode not in self.model.parts[request.part].modes:  # a manager-wide safe mode this part lacks
                self.finish(execution, False, f"{reason}; {request.part} has no mode {mode} (on_failure): left "
                                              "as it is")
                return
            self.finish(execution, False, f"{reason}; {request.part} is asked for mode {mode} (on_failure)")
            self.start(request.part, StateMode(State.ACTIVE, mode), f"change_mode {request.part} {mode} "
                       f"(on_failure of #{request.id})", Origin.USER, None, requester=request.requester,
                       on_failure="stay")
        else:
            self.finish(execution, False, reason)

    def _roll_back(self, execution: Execution, reason: str) -> None:
        """Put back every node ``execution`` moved, in the reverse of its plan's order."""
        self._close(execution)
        for part, (target, chosen_by) in execution.previous_targets.items():
            self._ledger.set_target(part, target)
            self._divergences.chosen(part, chosen_by)
        execution.failure = reason
        observations = self._inference.observations
        # Every node it began to drive (a call may still be in flight: its new owner waits for the
        # outcome), and any other that is not where it was; the ones out of reach cannot be.
        started = {step.node for step in execution.steps if step.started}
        back = frozenset(name for name, before in execution.before.items()
                         if (name in started or not before.holds(observations[name])) and observations[name].reachable)
        if not back:
            self._end(execution.request, False, self._rolled_back(execution, True, ""))
            return
        request = execution.request
        rollback = Request(request.part, request.target, f"roll back #{request.id}", Origin.RECOVERY, self._clock.now(),
                           requester="rollback", parts=tuple(sorted(back)))
        log.info("request #%d %s started [rollback]", rollback.id, rollback.description)
        # As long as the request itself was given.
        self._run(Execution(self, rollback, back, {}, continuation=True, rolls_back=execution), execution.limit)

    def _rolled_back(self, execution: Execution, succeeded: bool, reason: str) -> str:
        """The failed request's reason once its rollback ended."""
        observations = self._inference.observations
        left = sorted(name for name, before in execution.before.items() if not before.holds(observations[name]))
        if succeeded and not left:
            return f"rolled back: {execution.failure}"
        what = reason or f"not back where it was: {', '.join(left)}"
        return f"rollback failed ({what}): {execution.failure}"

    def _close(self, execution: Execution) -> None:
        """``execution`` is over: no further steps, and no longer in progress."""
        execution.stop()
        request = execution.request
        self._executions.pop(request.id, None)
        for part in request.parts:
            waiting = self._confirming.get(part)
            if waiting is not None:
                waiting.discard(execution)
                if not waiting:
                    del self._confirming[part]
                    self._ledger.waiting.discard(part)
        self._divergences.busy(execution.scope, -1)

    def _end(self, request: Request, succeeded: bool, reason: str) -> None:
        now = self._clock.now()
        if request.origin is not Origin.USER and request.requester != "rollback":
            self._reactions.finished(request.part, succeeded, reason)
        outcome = f"succeeded in {now - request.created:.2f} s" if succeeded else f"failed: {reason}"
        (log.info if succeeded else log.warning)("request #%d %s %s", request.id, request.description, outcome)
        self._ledger.emit(EventKind.REQUEST, request.part, f"#{request.id} {request.description} {outcome}",
                          request=request)
        request._finish(succeeded, reason, now)

    def _withdraw(self, request: Request) -> None:
        with self._serialiser:
            if self.waiting.withdraw(request):
                return
            execution = self._executions.get(request.id)
            if execution is None:
                return
            for part, (target, chosen_by) in execution.previous_targets.items():
                self._ledger.set_target(part, target)
                self._divergences.chosen(part, chosen_by)
            self.finish(execution, False, "cancelled")

    def _timed_out(self, execution: Execution, limit: float) -> None:
        with self._serialiser:
            if execution.active:
                self.fail(execution, f"timed out after {limit:g} s ({execution.stall()})")
