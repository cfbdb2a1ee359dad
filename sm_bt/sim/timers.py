"""Timers kept per node process, so that a crash or a restart cancels everything the old process
had scheduled."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable

from sm_bt.engine.clock import TimerHandle, VirtualClock


class _NodeTimer:
    """``action``, scheduled on behalf of a node's process (its handle in ``timers`` until it runs)."""

    __slots__ = ("action", "handle", "timers")

    def __init__(self, timers: set[TimerHandle], action: Callable[[], None]) -> None:
        self.timers = timers
        self.action = action
        self.handle: TimerHandle | None = None

    def __call__(self) -> None:
        self.timers.discard(self.handle)
        self.action()


class ProcessTimers:
    def __init__(self, clock: VirtualClock) -> None:
        self._clock = clock
        self._timers: defaultdict[str, set[TimerHandle]] = defaultdict(set)

    def after(self, node: str, delay: float, action: Callable[[], None]) -> None:
        """Run ``action`` in ``delay`` s (at once if negative) unless ``node``'s timers are cancelled."""
        timers = self._timers[node]
        run = _NodeTimer(timers, action)
        run.handle = self._clock.call_later(max(0.0, delay), run)
        timers.add(run.handle)

    def cancel(self, node: str) -> None:
        for handle in self._timers.pop(node, ()):
            handle.cancel()
