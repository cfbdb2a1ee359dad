"""Settling: what the outermost entry into the manager does before it returns (see
:mod:`sm_bt.engine.serialiser`): work through the agenda, then the divergences that changed and
the reactions to faults, which may put more on the agenda, until nothing is left."""

from __future__ import annotations

import logging

from sm_bt.engine.clock import Clock
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.executions import Executions
from sm_bt.engine.responses import Responses
from sm_bt.engine.serialiser import Serialiser

log = logging.getLogger("sm_bt.manager")

#: Settling passes before the manager reports that it could not settle (a bug, not a model).
MAX_PASSES = 100_000


class Settling:
    """The manager's work, for its :class:`~sm_bt.engine.serialiser.Serialiser`."""

    __slots__ = ("_clock", "_divergences", "_executions", "_responses", "_serial")

    def __init__(self, serial: Serialiser, divergences: Divergences, responses: Responses, executions: Executions,
                 clock: Clock) -> None:
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
            for change in changes:
                self._responses.changed(change.part, change.new, now)
            for reaction in self._responses.react(faults) if faults else ():
                self._executions.start(reaction.part, reaction.target, reaction.description, reaction.origin, None)
        log.error("the manager did not settle after %d passes; stopped to stay responsive", MAX_PASSES)
