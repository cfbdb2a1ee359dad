"""Which parts diverge from their target, why, and since when: evaluated incrementally.

A part diverges when its target is set and its inferred actual differs. Why (:class:`Cause`):

* ``IN_FLIGHT`` while a request works on a node at or below it;
* ``GRACE`` until the divergence has lasted ``grace_period`` (the clock restarts whenever a
  request on it starts or ends);
* ``FAULT`` when something below went wrong by itself: a node is off its target, or a rule
  re-targeted a part below (so a system's rules see its sub-system's rule take effect, as the
  paper's hierarchical error handling has it);
* ``OVERRIDE`` otherwise: a part below was asked for something else directly (left alone).

The manager marks what changed (:meth:`Divergences.touch`); :meth:`Divergences.evaluate`
re-examines only those parts and the systems above them, children before their systems.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from typing import NamedTuple

from sm_bt.engine.events import Cause, Divergence
from sm_bt.engine.hierarchy import Hierarchy
from sm_bt.engine.inference import Inference
from sm_bt.engine.requests import Origin
from sm_bt.model.types import Model, SystemPart

#: Clock slack: a timer set for ``since + grace`` must find the grace period over when it fires.
EPSILON = 1e-6
# Read once: looking up an enum's member on its class is slow (EnumType.__getattr__).
_IN_FLIGHT, _GRACE, _FAULT, _OVERRIDE = Cause.IN_FLIGHT, Cause.GRACE, Cause.FAULT, Cause.OVERRIDE
_BY_RULE = Origin.RULE


class Change(NamedTuple):
    """A divergence that started (``old`` None), ended (``new`` None) or changed."""

    part: str
    old: Divergence | None
    new: Divergence | None


class Divergences:
    """The divergence of every part, kept up to date from what the manager marks as changed."""

    def __init__(self, model: Model, hierarchy: Hierarchy, inference: Inference, grace_period: float) -> None:
        self._model = model
        self._hierarchy = hierarchy
        self._inference = inference
        self.grace_period = grace_period
        self.records: dict[str, Divergence] = {}
        self._since: dict[str, float] = {}
        self._busy: dict[str, int] = {}  # (request, node) pairs in flight at or below each part
        self._faulty: set[str] = set()  # off target by itself, or with a fault below
        self._chosen: dict[str, Origin] = {}  # who set a part's target for it (not through a system above)
        # Per system: its parts that are faulty or were re-targeted by a rule (a fault below).
        self._blamed: dict[str, int] = dict.fromkeys(hierarchy.parents.keys(), 0)
        self._notes: dict[str, str] = {}  # what the manager adds to the reason (recovery gave up)
        self._dirty: set[str] = set()
        self._targets, self._actuals = inference.targets, inference.actuals  # read-only views
        self._systems = frozenset(name for name, spec in model.parts.items() if isinstance(spec, SystemPart))
        self._queue: list[tuple[int, str]] = []  # the dirty parts by height (children first)
        self._height = hierarchy.height
        self._grace: list[tuple[float, str]] = []  # (due, part), a heap; stale entries are skipped
        self._grace_due: dict[str, float] = {}  # the last due pushed for each part

    # -- what changed (from the manager) ---------------------------------------------------------

    def touch(self, part: str) -> None:
        """``part``'s actual, target or circumstances changed: re-examine it (its systems follow
        when that changes what they see of it)."""
        dirty = self._dirty
        if part not in dirty:
            dirty.add(part)
            heapq.heappush(self._queue, (self._height[part], part))

    @property
    def pending(self) -> bool:
        return bool(self._dirty)

    def busy(self, nodes: Iterable[str], delta: int) -> None:
        """A request started (``+1``) or ended (``-1``) working on ``nodes``. Either way the grace
        period of each part involved starts again."""
        counts: dict[str, int] = {}  # each part once, however many of its nodes (the root: all)
        ancestors = self._hierarchy.ancestors
        for node in nodes:
            counts[node] = counts.get(node, 0) + delta
            for part in ancestors[node]:
                counts[part] = counts.get(part, 0) + delta
        busy, since, touch = self._busy, self._since, self.touch
        for part, count in counts.items():
            busy[part] = busy.get(part, 0) + count
            since.pop(part, None)
            touch(part)

    def is_busy(self, part: str) -> bool:
        return self._busy.get(part, 0) > 0

    def chosen(self, part: str, origin: Origin | None) -> None:
        """Who last set ``part``'s target for the part itself (a user, or one of its rules);
        ``None`` when it came with the target of a system above."""
        blamed = self._to_blame(part)
        if origin is None:
            self._chosen.pop(part, None)
        else:
            self._chosen[part] = origin
        self._reblame(part, blamed)
        self.touch(part)

    def _to_blame(self, part: str) -> bool:
        return part in self._faulty or self._chosen.get(part) is Origin.RULE

    def _reblame(self, part: str, before: bool) -> None:
        """``part`` was (``before``) or is now a fault below its systems: tell them if that changed."""
        after = self._to_blame(part)
        if after != before:
            for parent in self._hierarchy.parents[part]:
                self._blamed[parent] += 1 if after else -1
                self.touch(parent)

    def chosen_by(self, part: str) -> Origin | None:
        return self._chosen.get(part)

    def note(self, part: str, text: str | None) -> None:
        if text is None:
            self._notes.pop(part, None)
        else:
            self._notes[part] = text
        self.touch(part)

    def grace_over(self, now: float) -> None:
        """Mark the parts whose grace period is over by ``now``."""
        while self._grace and self._grace[0][0] <= now + EPSILON:
            due, part = heapq.heappop(self._grace)
            if self._grace_due.get(part) == due:
                del self._grace_due[part]
            self.touch(part)

    def next_due(self) -> float | None:
        """When the earliest grace period still running ends."""
        while self._grace:
            due, part = self._grace[0]
            record = self.records.get(part)
            live = record is not None and record.cause is _GRACE
            if live and record is not None and abs(record.since + self.grace_period - due) < EPSILON:
                return due
            heapq.heappop(self._grace)
            if self._grace_due.get(part) == due:
                del self._grace_due[part]
        return None

    # -- evaluation ------------------------------------------------------------------------------

    def evaluate(self, now: float) -> tuple[list[Change], list[Divergence]]:
        """Re-examine what changed: the divergences that started, ended or changed, and every
        re-examined divergence that is a ``FAULT`` (children before their systems)."""
        changes: list[Change] = []
        faults: list[Divergence] = []
        queue, dirty, records, examine, pop = self._queue, self._dirty, self.records, self._examine, heapq.heappop
        while queue:
            part = pop(queue)[1]
            dirty.discard(part)
            new = examine(part, now)
            old = records.get(part)
            if new is None:
                if old is not None:
                    del records[part]
                    self._notes.pop(part, None)
                    changes.append(Change(part, old, None))
                continue
            records[part] = new
            # While a request works on it, a divergence's actual and reason move with every node
            # report: those show in ACTUAL events (and in the record), not as changes.
            if old is None or old.cause is not new.cause or old.target != new.target or (
                    new.cause is not _IN_FLIGHT and (old.actual != new.actual or old.reason != new.reason)):
                changes.append(Change(part, old, new))
            if new.cause is _FAULT:
                faults.append(new)
        return changes, faults

    def _examine(self, part: str, now: float) -> Divergence | None:
        target = self._targets.get(part)
        actual = self._actuals[part]
        on_target = target is None or actual.is_(target)
        faulty = self._blamed[part] > 0 if part in self._systems else not on_target
        faulty_set = self._faulty
        if faulty is not (part in faulty_set):
            # Blamed by its systems when faulty or re-targeted by a rule: a fault below them.
            by_rule = self._chosen.get(part) is _BY_RULE
            if faulty:
                faulty_set.add(part)
            else:
                faulty_set.discard(part)
            if not by_rule:
                for parent in self._hierarchy.parents[part]:
                    self._blamed[parent] += 1 if faulty else -1
                    self.touch(parent)
        if on_target:
            self._since.pop(part, None)
            return None
        assert target is not None
        since = self._since.setdefault(part, now)
        grace = self.grace_period
        if self._busy.get(part, 0) > 0:
            cause = _IN_FLIGHT
        elif now - since < grace - EPSILON:
            cause = _GRACE
            due = since + grace
            if self._grace_due.get(part) != due:  # each grace period once, however often examined
                self._grace_due[part] = due
                heapq.heappush(self._grace, (due, part))
        elif faulty:
            cause = _FAULT
        else:
            cause = _OVERRIDE
        return Divergence(part, target, actual, since, cause, self._notes.get(part) or actual.reason)
