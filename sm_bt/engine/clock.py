"""Time for the engine: a clock protocol, a deterministic virtual clock and a wall clock.

The manager never sleeps: it asks its clock to call it back later (timeouts, grace periods).
:class:`VirtualClock` runs those callbacks when the owner advances it, so simulated runs are
deterministic and can go much faster than wall time. :class:`WallClock` runs them in real time
from a background thread, for real nodes.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

log = logging.getLogger("sm_bt.clock")


class TimerHandle(Protocol):
    def cancel(self) -> None:
        """Do not run the callback (no effect if it already ran)."""


class Clock(Protocol):
    def now(self) -> float:
        """Monotonic time in seconds."""

    def call_later(self, delay: float, callback: Callable[[], None]) -> TimerHandle:
        """Run ``callback`` once, ``delay`` seconds from now (never synchronously inside this call)."""


def _nothing() -> None:
    pass


class _Timer:
    __slots__ = ("callback", "cancelled", "due")

    def __init__(self, due: float, callback: Callable[[], None]) -> None:
        self.due = due
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True
        self.callback = _nothing  # keeps nothing alive while it waits in the queue to be dropped

    def fire(self) -> None:
        # Forget the callback first: callbacks often hold their own handle (to forget it when they
        # run), and the cycle would otherwise live until a full garbage collection.
        callback, self.callback = self.callback, _nothing
        callback()


class VirtualClock:
    """A clock that only moves when told to; callbacks run in due-time order, then FIFO."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = start
        self._queue: list[tuple[float, int, _Timer]] = []
        self._sequence = itertools.count()

    def now(self) -> float:
        return self._now

    def call_later(self, delay: float, callback: Callable[[], None]) -> _Timer:
        timer = _Timer(self._now + max(0.0, delay), callback)
        heapq.heappush(self._queue, (timer.due, next(self._sequence), timer))
        return timer

    def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds``, running every callback that falls due on the way."""
        if seconds < 0:
            raise ValueError("a clock cannot go backwards")
        self.run_until(self._now + seconds)

    def run_until(self, when: float) -> None:
        """Run callbacks due up to ``when`` (including ones they schedule), then set the time to it."""
        while self._queue and self._queue[0][0] <= when:
            due, _, timer = heapq.heappop(self._queue)
            if timer.cancelled:
                continue
            self._now = max(self._now, due)
            timer.fire()
        self._now = max(self._now, when)

    def run_pending(self) -> None:
        """Run what is due now (for example zero-delay callbacks) without moving time."""
        self.run_until(self._now)

    def next_due(self) -> float | None:
        """When the next live callback is due, or ``None`` when nothing is scheduled."""
        while self._queue and self._queue[0][2].cancelled:
            heapq.heappop(self._queue)
        return self._queue[0][0] if self._queue else None


class WallClock:
    """Real time (``time.monotonic``) with timers run by one background thread, in due order.

    For backends whose nodes live in real time (ROS 2). Callbacks run in the timer thread; the
    manager serialises them with everything else through its lock, so a callback may call the
    manager. A callback that raises is logged and does not stop the thread. ``close()`` stops the
    thread; timers still pending are dropped.
    """

    def __init__(self, name: str = "sm_bt-clock") -> None:
        self._queue: list[tuple[float, int, _Timer]] = []
        self._sequence = itertools.count()
        self._condition = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def now(self) -> float:
        return time.monotonic()

    def call_later(self, delay: float, callback: Callable[[], None]) -> _Timer:
        timer = _Timer(self.now() + max(0.0, delay), callback)
        with self._condition:
            if self._closed:
                timer.cancelled = True
                return timer
            heapq.heappush(self._queue, (timer.due, next(self._sequence), timer))
            if self._queue[0][2] is timer:  # only a new earliest timer changes how long to sleep
                self._condition.notify()
        return timer

    def close(self, timeout: float = 2.0) -> None:
        """Stop the timer thread (waiting up to ``timeout`` for a callback in progress)."""
        with self._condition:
            self._closed = True
            self._queue.clear()
            self._condition.notify()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            with self._condition:
                while not self._closed:
                    if self._queue and self._queue[0][2].cancelled:
                        heapq.heappop(self._queue)
                        continue
                    wait = self._queue[0][0] - self.now() if self._queue else None
                    if wait is not None and wait <= 0:
                        break
                    self._condition.wait(wait)
                if self._closed:
                    return
                _, _, timer = heapq.heappop(self._queue)
            callback = timer.callback
            try:
                timer.fire()
            except Exception:  # one bad callback must not stop every later timer
                log.exception("timer callback %r failed", callback)
            callback = _nothing  # not kept alive while this thread waits for the next timer
