"""The hand-off of a backend's reports to its listener: in order, one thread at a time, never from
inside a call (see :mod:`sm_bt.ros.backend`, "Threads")."""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable
from types import TracebackType

from sm_bt.engine.clock import Clock

log = logging.getLogger("sm_bt.ros.backend")


class Dispatcher:
    """Actions for the listener's side, run in order by one thread at a time. Answers and events come
    in bursts (one per node of a change): one drain runs every action waiting.

    By default the clock drains (delay 0). Within :meth:`held` (an rclpy callback) actions only
    queue, and a thread that queued some drains when it leaves, unless another thread is draining
    already (that one takes them in turn). A thread that queued nothing leaves the others' to them:
    the watching executor's probe answers are not held back behind a burst of the backend's."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._actions: collections.deque[Callable[[], None]] = collections.deque()
        self._lock = threading.Lock()
        self._draining = False
        self._holding = _Holding()
        self._held = _Held(self)

    def put(self, action: Callable[[], None]) -> None:
        holding = self._holding
        with self._lock:
            self._actions.append(action)
            if holding.depth:
                holding.queued = True
                return
            if self._draining:
                return
            self._draining = True
        self._clock.call_later(0.0, self._drain)

    def held(self) -> _Held:
        """``with dispatcher.held():`` around an rclpy callback (see the class's doc)."""
        return self._held

    def _drain_unless_draining(self) -> None:
        with self._lock:
            mine = bool(self._actions) and not self._draining
            if mine:
                self._draining = True
        if mine:
            self._drain()

    def _drain(self) -> None:
        while True:
            with self._lock:
                if not self._actions:
                    self._draining = False
                    return
                action = self._actions.popleft()
            try:
                action()
            except Exception:  # one bad report must not hold back the others
                log.exception("backend report %r failed", action)


class _Holding(threading.local):
    """A thread's rclpy callbacks in progress, and whether they queued an action."""

    depth = 0
    queued = False


class _Held:
    """The context of :meth:`Dispatcher.held` (one object serves every thread: its state is the
    thread's :class:`_Holding`; entered once per message, so no generator is made each time)."""

    __slots__ = ("_dispatcher",)

    def __init__(self, dispatcher: Dispatcher) -> None:
        self._dispatcher = dispatcher

    def __enter__(self) -> None:
        holding = self._dispatcher._holding
        if not holding.depth:
            holding.queued = False
        holding.depth += 1

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        dispatcher = self._dispatcher
        holding = dispatcher._holding
        holding.depth -= 1
        if not holding.depth and holding.queued:
            dispatcher._drain_unless_draining()
