"""One thing at a time: how the manager's entry points are serialised and its observers told.

Every entry point of :class:`~sm_bt.engine.manager.ModeManager` (a request, a backend report, a
timer) runs inside ``with serialiser:``, one re-entrant lock, so reports may arrive from any
thread. The outermost entry then *settles*: it has the manager work through what is left to do
(:class:`~sm_bt.engine.settling.Settling`: the agenda, then the divergences that changed and the
reactions to faults), and only then tells the observers the events the outbox holds, in order.
Observers may call back in: those calls only queue their effects, which the outermost entry
settles before it returns.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable, Iterable
from types import TracebackType
from typing import Protocol

from sm_bt.engine.backend import CallResult, Done
from sm_bt.engine.events import EventKind, Observer, Outbox, Subscription

log = logging.getLogger("sm_bt.manager")


class Work(Protocol):
    """The manager's work (:class:`~sm_bt.engine.settling.Settling`)."""

    def settle(self) -> None:
        """Do what is left to do."""

    def pending(self) -> bool:
        """Whether there is work left that ``settle`` would do (an observer may have left some)."""


class _Idle:
    def settle(self) -> None:
        pass

    def pending(self) -> bool:
        return False


class Serialiser:
    """``with serialiser:`` around every entry point (a class, not a generator: entered on every
    report); :attr:`work` is what the outermost entry settles (given once the manager is built)."""

    __slots__ = ("_agenda", "_depth", "_subscriptions", "closed", "lock", "outbox", "work")

    def __init__(self) -> None:
        self.lock = threading.RLock()
        self.outbox = Outbox()
        #: Once set, the outermost entry no longer settles (the manager is detached).
        self.closed = False
        self._agenda: deque[Callable[[], None]] = deque()
        self._depth = 0
        self.work: Work = _Idle()
        # A tuple, replaced on (un)subscribe: notifying iterates it with no copy.
        self._subscriptions: tuple[Subscription, ...] = ()

    def __enter__(self) -> None:
        self.lock.acquire()
        self._depth += 1

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        try:
            self._depth -= 1
            if kind is None and not self._depth and not self.closed:
                self._settle_and_notify()
        finally:
            self.lock.release()

    def defer(self, action: Callable[[], None]) -> None:
        """Run ``action`` when the current entry settles (plans handing over to their next steps)."""
        self._agenda.append(action)

    def run_agenda(self) -> None:
        while self._agenda:
            self._agenda.popleft()()

    def serialised(self, done: Done) -> Done:
        """``done`` for a backend call: run inside an entry, whatever thread calls it."""
        return _Serialised(self, done)

    def locked(self, read: Callable[[], str]) -> str:
        with self.lock:
            return read()

    def subscribe(self, callback: Observer, parts: frozenset[str] | None,
                  kinds: Iterable[EventKind] | None) -> Subscription:
        subscription = Subscription(callback, parts, None if kinds is None else frozenset(kinds), self._unsubscribe)
        with self.lock:
            self._subscriptions = (*self._subscriptions, subscription)
            self.outbox.interest(self._subscriptions)
        return subscription

    def _unsubscribe(self, subscription: Subscription) -> None:
        with self.lock:
            self._subscriptions = tuple(s for s in self._subscriptions if s is not subscription)
            self.outbox.interest(self._subscriptions)

    def _settle_and_notify(self) -> None:
        self._depth += 1
        try:
            self.work.settle()
            while (event := self.outbox.pop()) is not None:
                for subscription in self._subscriptions:
                    if subscription.everything or subscription.wants(event):
                        try:
                            subscription.callback(event)
                        except Exception:  # an observer's bug must not break the manager
                            log.exception("observer %r failed on %s", subscription.callback, event.kind.value)
                if self._agenda or self.work.pending():  # an observer called in
                    self.work.settle()
        finally:
            self._depth -= 1


class _Serialised:
    """A backend's ``done`` for a call of the manager's, run inside an entry (an object, not a
    closure: one per call in flight, and a bring-up has one for every node at once)."""

    __slots__ = ("_done", "_serialiser")

    def __init__(self, serialiser: Serialiser, done: Done) -> None:
        self._serialiser = serialiser
        self._done = done

    def __call__(self, result: CallResult) -> None:
        with self._serialiser:
            self._done(result)
