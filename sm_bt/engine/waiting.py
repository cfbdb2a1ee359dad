"""Requests that wait for holds to end (``queue=True``) instead of being refused at once.

A queued request is a :class:`~sm_bt.engine.requests.Request` like any other, not done yet: its
``feedback`` says what it waits for, ``cancel()`` takes it out of the queue. Whenever a hold ends,
the queued requests are tried again in the order they came, each admitted as if it were asked
for then; one that is still held waits on. None waits forever: a request still held when its own
timeout runs out fails, naming the holder.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.requests import Request
from sm_bt.engine.serialiser import Serialiser

log = logging.getLogger("sm_bt.manager")


@dataclass(eq=False)
class Queued:
    request: Request
    #: Why it is still held ("" once nothing holds it back).
    held: Callable[[], str]
    #: Start it (admitted from scratch: a node may have gone out of reach meanwhile).
    begin: Callable[[], object]
    timer: TimerHandle | None = None


class Waiting:
    """The queued requests, tried again (in ``serialiser``'s entries) whenever a hold ends."""

    def __init__(self, clock: Clock, serialiser: Serialiser, end: Callable[[Request, bool, str], None]) -> None:
        self._clock = clock
        self._serialiser = serialiser
        self._end = end  # ends a request: logged, told
        self._queued: list[Queued] = []
        self._due = False

    def __bool__(self) -> bool:
        return bool(self._queued)

    def add(self, request: Request, why: str, limit: float, held: Callable[[], str],
            begin: Callable[[], object]) -> None:
        """Queue ``request`` (held because of ``why``) for at most ``limit`` seconds."""
        queued = Queued(request, held, begin)
        request._progress = lambda: f"queued: {held() or why}"
        queued.timer = self._clock.call_later(limit, lambda: self._timed_out(queued, limit))
        self._queued.append(queued)
        log.info("request #%d %s queued [%s]: %s", request.id, request.description, request.requester, why)

    def hold_ended(self) -> None:
        """A hold ended: try the queue again once the current entry settles."""
        if self._queued and not self._due:
            self._due = True
            self._serialiser.defer(self._retry)

    def withdraw(self, request: Request) -> bool:
        """Take ``request`` out of the queue (``cancel()``), if it is there."""
        for queued in self._queued:
            if queued.request is request:
                self._drop(queued)
                self._end(request, False, "cancelled")
                return True
        return False

    def close(self, reason: str) -> None:
        for queued in list(self._queued):
            self._drop(queued)
            self._end(queued.request, False, reason)

    def _retry(self) -> None:
        self._due = False
        for queued in list(self._queued):
            if queued in self._queued and not queued.held():
                self._drop(queued)
                queued.request._progress = None
                queued.begin()

    def _drop(self, queued: Queued) -> None:
        self._queued.remove(queued)
        if queued.timer is not None:
            queued.timer.cancel()

    def _timed_out(self, queued: Queued, limit: float) -> None:
        with self._serialiser:
            if queued not in self._queued:
                return
            self._drop(queued)
            self._end(queued.request, False, f"still held after {limit:g} s: {queued.held() or 'held'}")
