"""How the manager answers divergences: each logged once and told as an event, a timer for the
earliest grace period still running, and the rules and recovery that :mod:`sm_bt.engine.reactions`
decides on, turned into requests (started by the manager) or a give-up.

Rules and recovery share a budget per part (:class:`~sm_bt.engine.reactions.Reactions`); it is
whole again when a user asks for the part or its node starts a new process
(:meth:`Responses.renew_budgets`).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass

from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.divergences import Change, Divergences
from sm_bt.engine.events import Divergence, Event, EventKind
from sm_bt.engine.inference import Inference
from sm_bt.engine.ledger import Ledger
from sm_bt.engine.reactions import FireRule, GiveUp, Reactions, Restore
from sm_bt.engine.requests import Origin
from sm_bt.engine.serialiser import Serialiser
from sm_bt.model.states import StateMode

log = logging.getLogger("sm_bt.manager")


@dataclass(frozen=True)
class Reaction:
    """A request a rule or recovery asks for."""

    part: str
    target: StateMode
    description: str
    origin: Origin
    #: A rule's: who asks (``rule NAME``), and the condition its hold lasts for (part, state).
    requester: str | None = None
    condition: tuple[str, StateMode] | None = None


_DIVERGENCE = EventKind.DIVERGENCE  # read once: an enum's member is slow to look up


class Responses:
    """Answers the divergences ``divergences`` finds, booked in ``ledger``; its grace timer runs
    inside ``serialiser``'s entries."""

    def __init__(self, ledger: Ledger, divergences: Divergences, reactions: Reactions, serialiser: Serialiser,
                 clock: Clock) -> None:
        self._ledger = ledger
        self._inference = ledger.inference
        self._divergences = divergences
        self._reactions = reactions
        self._serialiser = serialiser
        self._clock = clock
        self._view = _ReactionView(ledger.inference, divergences)
        self._reported: set[str] = set()  # divergences already logged as errors
        self._grace_timer: TimerHandle | None = None
        self._grace_due: float | None = None

    def changed(self, changes: Iterable[Change], now: float) -> None:
        """Divergences that started, changed or ended (back on target): each logged once, told."""
        wanting = self._ledger.wanting(_DIVERGENCE)
        reported, back_on_target, put = self._reported, self._reactions.back_on_target, self._ledger.put
        for part, _, new in changes:
            if new is None:
                reported.discard(part)
                back_on_target(part, now)
                if wanting is None or part in wanting:
                    put(Event(_DIVERGENCE, part, now, "", self._inference.actual(part), self._inference.target(part)))
                continue
            if new.is_error and part not in reported:  # once per divergence, not per attempt
                reported.add(part)
                why = f": {new.reason}" if new.reason else ""
                log.warning("Deviation detected in system or part '%s': should be %s, but is %s (%s%s).",
                            part, new.target, new.actual, new.cause.value, why)
            if wanting is None or part in wanting:
                put(Event(_DIVERGENCE, part, now, "", new.actual, None, new))

    def react(self, faults: list[Divergence]) -> list[Reaction]:
        """The requests rules and recovery ask for, given ``faults`` (a give-up is noted and told here)."""
        started: list[Reaction] = []
        attempts = self._reactions.attempts
        for action in self._reactions.decide(faults, self._view):
            if isinstance(action, FireRule):
                rule = action.rule
                message = f"rule {rule.name}: {rule.if_part} is {rule.if_part_state} -> {rule.new_target}"
                log.info("%s: %s (attempt %d of %d)", rule.system, message, action.attempt, attempts)
                self._ledger.emit(EventKind.RULE, rule.system, message)
                started.append(Reaction(rule.system, rule.new_target, f"rule {rule.name} of {rule.system}",
                                        Origin.RULE, f"rule {rule.name}", (rule.if_part, rule.if_part_state)))
            elif isinstance(action, Restore):
                log.warning("restoring %s to %s (attempt %d of %d)", action.node, action.target, action.attempt,
                            attempts)
                started.append(Reaction(action.node, action.target, f"restore {action.node} to {action.target}",
                                        Origin.RECOVERY))
            elif isinstance(action, GiveUp):
                part = action.divergence.part
                log.error("%s", action.message)
                self._divergences.note(part, action.message)
                self._ledger.emit(EventKind.FAILED, part, action.message, divergence=action.divergence)
        return started

    def renew_budgets(self, parts: Iterable[str]) -> None:
        """Rules and recovery may act on ``parts`` again (a user asked for them, or a node restarted)."""
        for part in parts:
            if part in self._reactions.gave_up:
                self._divergences.note(part, None)
        self._reactions.reset(parts)

    def schedule_grace(self) -> None:
        """One timer, for the earliest grace period still running (a timer that fires for a grace
        period that ended early leaves the next one to be scheduled here, after settling)."""
        due = self._divergences.next_due()
        if due is None or (self._grace_due is not None and self._grace_due <= due):
            return
        if self._grace_timer is not None:
            self._grace_timer.cancel()
        self._grace_due = due
        self._grace_timer = self._clock.call_later(due - self._clock.now(), self._grace_over)

    def cancel(self) -> None:
        if self._grace_timer is not None:
            self._grace_timer.cancel()

    def _grace_over(self) -> None:
        with self._serialiser:
            self._grace_timer = None
            self._grace_due = None
            self._divergences.grace_over(self._clock.now())


class _ReactionView:
    """The manager as rules and recovery see it."""

    def __init__(self, inference: Inference, divergences: Divergences) -> None:
        self.actual = inference.actual
        self.target = inference.target
        self.observation = inference.observation
        self.chosen_by = divergences.chosen_by
