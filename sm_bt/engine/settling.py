"""Settling: what the outermost entry into the manager does before it returns (see
:mod:`sm_bt.engine.serialiser`): work through the agenda, then the divergences that changed and
the reactions to faults, which may put more on the agenda, until nothing is left."""

from __future__ import annotations

import logging
from collections.abc import Callable

from sm_bt.engine.clock import Clock
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.executions import Executions
from sm_bt.engine.hierarchy import implied_targets
from sm_bt.engine.inference import Actual
from sm_bt.engine.requests import Origin
from sm_bt.engine.responses import Reaction, Responses
from sm_bt.engine.serialiser import Serialiser
from sm_bt.model.states import StateMode

log = logging.getLogger("sm_bt.manager")

#: Settling passes before the manager reports that it could not settle (a bug, not a model).
MAX_PASSES = 100_000


class Settling:
    """The manager's work, for its :class:`~sm_bt.engine.serialiser.Serialiser`."""

    __slots__ = ("_actual", "_clock", "_divergences", "_executions", "_responses", "_serial")

    def __init__(self, serial: Serialiser, divergences: Divergences, responses: Responses, executions: Executions,
                 clock: Clock, actual: Callable[[str], Actual]) -> None:
        self._actual = actual
        self._serial = serial
        self._divergences = divergences
        self._responses = responses
        self._executions = executions
        self._clock = clock

    def pending(self) -> bool:
        """Whether divergences changed since the last pass (an observer may have caused it)."""
        return self._divergences.pending

    def settle(self) -> None:
        for _ in range(MAX_PASSES):
            self._serial.run_agenda()
            if not self._divergences.pending:
                self._responses.schedule_grace()
                return
            now = self._clock.now()
            changes, faults = self._divergences.evaluate(now)
            self._responses.changed(changes, now)
            holds = self._executions.holds
            if changes and holds:
                holds.conditions_over(self._is_in)
            for reaction in self._responses.react(faults) if faults else ():
                self._start(reaction)
        log.error("the manager did not settle after %d passes; stopped to stay responsive", MAX_PASSES)

    def _start(self, reaction: Reaction) -> None:
        """Start a rule's or recovery's request; a rule's holds its target while its condition lasts."""
        executions = self._executions
        level = executions.holds.priority_of(Origin.RULE.value)
        request = executions.start(reaction.part, reaction.target, reaction.description, reaction.origin, None,
                                   requester=reaction.requester, priority=level)
        if reaction.condition is not None and not request.refused and self._is_in(*reaction.condition):
            executions.holds.add(reaction.part, reaction.target, dict(implied_targets(executions.model, reaction.part,
                                 reaction.target)), request.requester, level, None, reaction.condition)

    def _is_in(self, part: str, state: StateMode) -> bool:
        return self._actual(part).meets(state)
