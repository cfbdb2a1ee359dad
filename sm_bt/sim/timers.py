"""Timers kept per node process, so that a crash or a restart cancels everything the old process
had scheduled."""

from __future__ import annotations

from collections.abc import Callable

from sm_bt.engine.clock import TimerHandle, VirtualClock


class _NodeTimer:
    """``action``, scheduled on behalf of ``node``'s process (its handle kept until it runs)."""

    __slots__ = ("action", "handle", "node", "owner")

    def __init__(self, owner: ProcessTimers, node: str, action: Callable[[], None]) -> None:
        self.owner = owner
        self.node = node
        self.action = action
        self.handle: TimerHandle | None = None

    def __call__(self) -> None:
        self.owner._ran(self.node, self.handle)
        self.action()


class ProcessTimers:
    def __init__(self, clock: VirtualClock) -> None:
        self._clock = clock
        # Only nodes with timers pending: an empty set per node of 100,000 is 20 MB.
        self._timers: dict[str, set[TimerHandle | None]] = {}

    def after(self, node: str, delay: float, action: Callable[[], None]) -> None:
        """Run ``action`` in ``delay`` s (at once if negative) unless ``node``'s timers are cancelled."""
        run = _NodeTimer(self, node, action)
        run.handle = self._clock.call_later(max(0.0, delay), run)
        timers = self._timers.get(node)
        if timers is None:
            timers = self._timers[node] = set()
        timers.add(run.handle)

    def cancel(self, node: str) -> None:
        for handle in self._timers.pop(node, ()):
            if handle is not None:
                handle.cancel()

    def _ran(self, node: str, handle: TimerHandle | None) -> None:
        timers = self._timers.get(node)
        if timers is not None:
            timers.discard(handle)
            if not timers:
                del self._timers[node]
