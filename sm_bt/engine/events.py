"""What the manager tells its observers (events, in order, through an outbox), and the divergence record."""

from __future__ import annotations

import enum
from collections import deque
from collections.abc import Callable, Iterable
from typing import NamedTuple

from sm_bt.engine.inference import Actual
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.requests import Request
from sm_bt.model.states import StateMode


class Cause(str, enum.Enum):
    """Why a part's actual differs from its target."""

    IN_FLIGHT = "in_flight"  # a request is still working on it
    GRACE = "grace"  # it only just started; not an error yet
    FAULT = "fault"  # a node left its target by itself: rules and recovery act on it
    OVERRIDE = "override"  # parts were asked for something else directly: left alone


#: The causes that make a divergence an error (read once: an enum's member is slow to look up).
ERROR_CAUSES = frozenset({Cause.FAULT, Cause.OVERRIDE})


class Divergence(NamedTuple):
    """A part whose actual state/mode is not its target, since ``since`` (clock seconds); an
    immutable record.

    ``reason`` explains it in words: what is off, or, once recovery gave up on the part, why it
    gave up (``"gave up after 3 attempts: laser_resender hung in activating for 30 s"``).
    """

    part: str
    target: StateMode
    actual: Actual
    since: float
    cause: Cause
    reason: str = ""

    @property
    def is_error(self) -> bool:
        """True once it is beyond the grace period and no request explains it."""
        return self.cause in ERROR_CAUSES

    def __str__(self) -> str:
        why = f": {self.reason}" if self.reason else ""
        return f"{self.part}: target {self.target}, actual {self.actual} ({self.cause.value}{why})"


class EventKind(str, enum.Enum):
    ACTUAL = "actual"  # inferred actual state/mode changed
    TARGET = "target"  # target changed
    DIVERGENCE = "divergence"  # started, ended (divergence None), or changed: cause or target; actual
    # or reason only while no request works on it (then they move with every node report)
    REQUEST = "request"  # a request started or finished
    RULE = "rule"  # a rule fired
    FAILED = "failed"  # recovery gave up on a part
    HOLD = "hold"  # a hold on the part began or ended (sm_bt.engine.holds)


class Event(NamedTuple):
    """One thing the manager tells its observers (an immutable record).

    ``actual`` is the part's inferred actual when the event was made. ``previous`` is, for an
    ``ACTUAL`` event, the actual before the change; for a ``TARGET`` event, the part's actual just
    before its target changed (the state a change starts from). ``transition`` (``TARGET`` events)
    is the lifecycle transition asked of the part: the one requested by ``change_state``, or the
    first step from ``previous`` towards the new target's state; ``None`` when the state stays.
    ``message`` says it in one line (made when read: most events are never printed).
    """

    kind: EventKind
    part: str
    time: float
    text: str = ""  # the message, where the fields do not tell it
    actual: Actual | None = None
    target: StateMode | None = None
    divergence: Divergence | None = None
    request: Request | None = None
    previous: Actual | None = None
    transition: Transition | None = None

    @property
    def message(self) -> str:
        if self.text:
            return self.text
        if self.kind is EventKind.ACTUAL:
            return f"{self.part}: {self.previous} -> {self.actual}"
        if self.kind is EventKind.TARGET:
            return f"target {self.target}"
        if self.kind is EventKind.DIVERGENCE:
            return str(self.divergence) if self.divergence is not None else \
                f"{self.part} is back on target {self.target}"
        return ""


Observer = Callable[[Event], None]


class Subscription:
    """Returned by ``ModeManager.subscribe``; ``cancel()`` stops the notifications."""

    def __init__(self, callback: Observer, parts: frozenset[str] | None, kinds: frozenset[EventKind] | None,
                 remove: Callable[[Subscription], None]) -> None:
        self.callback = callback
        self.parts = parts
        self.kinds = kinds
        self.everything = parts is None and kinds is None
        self._remove = remove

    def wants(self, event: Event) -> bool:
        return (self.parts is None or event.part in self.parts) and (self.kinds is None or event.kind in self.kinds)

    def cancel(self) -> None:
        self._remove(self)


class Outbox:
    """Events waiting to be told, in order. A part's actual changes that pile up before they are
    told become one event (first old value, last new value; none if they cancel out), so
    observers never see the intermediate inferences of one settling."""

    def __init__(self) -> None:
        self._queue: deque[list[Event | None]] = deque()
        self._actual: dict[str, list[Event | None]] = {}  # part -> its untold ACTUAL event's slot
        # What the subscribers want: an event nobody wants is not made (a change of 100,000 nodes
        # is half a million of them).
        self._everywhere: frozenset[EventKind] = frozenset()  # kinds wanted of every part
        self._of_part: dict[str, frozenset[EventKind]] = {}  # and of some parts
        self._wanting: dict[EventKind, frozenset[str]] = {}  # the same, by kind

    def wanted(self, kind: EventKind, part: str) -> bool:
        """Whether a subscriber wants events of ``kind`` about ``part``."""
        return kind in self._everywhere or kind in self._of_part.get(part, ())

    def wanting(self, kind: EventKind) -> frozenset[str] | None:
        """The parts whose events of ``kind`` a subscriber wants, ``None`` for every part (for a
        loop over many parts: a set lookup each instead of :meth:`wanted`)."""
        if kind in self._everywhere:
            return None
        return self._wanting.get(kind, frozenset())

    def interest(self, subscriptions: Iterable[Subscription]) -> None:
        """Take note of what ``subscriptions`` want (whenever they change)."""
        every = frozenset(EventKind)
        everywhere: set[EventKind] = set()
        of_part: dict[str, set[EventKind]] = {}
        for subscription in subscriptions:
            kinds = every if subscription.kinds is None else subscription.kinds
            if subscription.parts is None:
                everywhere |= kinds
            else:
                for part in subscription.parts:
                    of_part.setdefault(part, set()).update(kinds)
        self._everywhere = frozenset(everywhere)
        self._of_part = {part: frozenset(kinds - everywhere) for part, kinds in of_part.items() if kinds - everywhere}
        wanting: dict[EventKind, set[str]] = {}
        for part, kinds in self._of_part.items():
            for kind in kinds:
                wanting.setdefault(kind, set()).add(part)
        self._wanting = {kind: frozenset(parts) for kind, parts in wanting.items()}

    def put(self, event: Event) -> None:
        self._queue.append([event])

    def actual(self, event: Event) -> None:
        slot = self._actual.get(event.part)
        told = slot[0] if slot is not None else None
        if told is None:
            slot = [event]
            self._actual[event.part] = slot
            self._queue.append(slot)
            return
        assert slot is not None
        merged = told._replace(actual=event.actual, time=event.time)
        slot[0] = None if merged.previous == merged.actual else merged

    def pop(self) -> Event | None:
        while self._queue:
            slot = self._queue.popleft()
            event = slot[0]
            if event is not None and self._actual.get(event.part) is slot:
                del self._actual[event.part]
            if event is not None:
                return event
        return None
