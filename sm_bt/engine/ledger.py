"""The manager's ledger: every part's target and inferred actual, and the events their changes make.

Targets are written here only (:meth:`Ledger.set_target`), and inference's changes are applied
here only (:meth:`Ledger.apply`): each one becomes an event in the outbox (if an observer wants
it), marks the divergences it may change (the part's, and those of the systems whose rules watch
it) and lets the requests waiting for the part's actual look again.
"""

from __future__ import annotations

from collections.abc import Callable

from sm_bt.engine.clock import Clock
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.events import Divergence, Event, EventKind, Outbox
from sm_bt.engine.inference import Actual, Changes, Inference
from sm_bt.engine.lifecycle import Transition, first_transition
from sm_bt.engine.requests import Request
from sm_bt.model.states import StateMode
from sm_bt.model.types import Model


class Ledger:
    """Targets and actuals of ``model``'s parts (``inference``), told through ``outbox``.
    ``reached(part)`` is called for every part whose actual changed and that a request waits on
    (:attr:`waiting`)."""

    def __init__(self, model: Model, inference: Inference, divergences: Divergences, outbox: Outbox,
                 clock: Clock) -> None:
        self.model = model
        self.inference = inference
        self.divergences = divergences
        self._outbox = outbox
        self._clock = clock
        #: Parts that requests wait on (their actual must reach the target), kept by the requests.
        self.waiting: set[str] = set()
        self.reached: Callable[[str], None] = lambda part: None
        self._last_mode: dict[str, str] = {}  # the last active mode asked for, kept over deactivation
        # The parts whose rules look at each part: a change of it may make one of them apply.
        self._watchers: dict[str, list[str]] = {}
        for spec in model.parts.values():
            for rule in spec.rules:
                self._watchers.setdefault(rule.if_part, []).append(rule.system)

    def set_target(self, part: str, target: StateMode | None, transition: Transition | None = None) -> None:
        if target is not None and target.mode is not None:
            self._last_mode[part] = target.mode
        if self.inference.target(part) == target:
            return
        if self._outbox.wanted(EventKind.TARGET, part):
            before = self.inference.actual(part)
            if transition is None and target is not None:
                transition = first_transition(before.state, target.state)
            self.emit(EventKind.TARGET, part, target=target, previous=before, transition=transition)
        self.divergences.touch(part)
        self.apply(self.inference.set_target(part, target))

    def apply(self, changes: Changes) -> None:
        now = self._clock.now()
        outbox, touch, watchers, waiting = self._outbox, self.divergences.touch, self._watchers, self.waiting
        kind = EventKind.ACTUAL  # read once: an enum's member is slow to look up
        wanting = outbox.wanting(kind)
        for part, (old, new) in changes.items():
            if wanting is None or part in wanting:
                outbox.actual(Event(kind, part, now, "", new, None, None, None, old))
            touch(part)
            for watcher in watchers.get(part, ()):
                touch(watcher)
            if part in waiting:
                self.reached(part)

    def emit(self, kind: EventKind, part: str, text: str = "", *, target: StateMode | None = None,
             divergence: Divergence | None = None, request: Request | None = None,
             previous: Actual | None = None, transition: Transition | None = None) -> None:
        if not self._outbox.wanted(kind, part):
            return
        actual = self.inference.actual(part) if part in self.model.parts else None
        self._outbox.put(Event(kind, part, self._clock.now(), text, actual, target, divergence, request, previous,
                               transition))

    def wants(self, kind: EventKind, part: str) -> bool:
        """Whether an observer wants such an event (else it need not be made)."""
        return self._outbox.wanted(kind, part)

    def wanting(self, kind: EventKind) -> frozenset[str] | None:
        """The parts whose events of ``kind`` an observer wants (``None``: every part)."""
        return self._outbox.wanting(kind)

    def put(self, event: Event) -> None:
        self._outbox.put(event)

    def mode_for_activation(self, part: str) -> str:
        """Activation keeps the mode last asked for (the reference falls back to the default)."""
        return self._last_mode.get(part, self.model.parts[part].default_mode)
