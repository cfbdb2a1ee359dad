"""The mode monitor's rows: one per part, and which of them to show.

A model of a hundred thousand nodes has more parts than any screen or reader, so the monitor
shows a :class:`Selection` of them: the parts whose names match a pattern, only the diverging
ones, or at most a number of rows, the divergences that are errors first, then the other
divergences, then the rest. A :class:`Summary` says how many there are of each. :class:`Rows`
keeps the selection up to date from the manager's events: an event costs a set insertion, and a
refresh makes rows only for the parts it shows that changed.
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Iterable
from dataclasses import dataclass

from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.snapshots import PartSnapshot
from sm_bt.model.hierarchy import parts_below, top_down
from sm_bt.model.types import NodePart

INFERRED = "(*)"
#: The events that can change a row (requests, rules and failures show through these).
ROW_EVENTS = frozenset({EventKind.ACTUAL, EventKind.TARGET, EventKind.DIVERGENCE, EventKind.HOLD})


@dataclass(frozen=True)
class Row:
    """One part as the monitor shows it.

    ``raw_state``/``raw_mode`` are the actual values, ``state_inferred``/``mode_inferred`` say
    whether they were inferred; ``actual_state``/``actual_mode`` add the ``(*)`` marker for
    display. ``cause`` and ``since`` describe the divergence (``None`` when on target), ``error``
    is true when it is beyond the grace period and unexplained (fault or override). ``held_by``:
    who holds the part (:mod:`~sm_bt.engine.holds`; "" when nobody).
    """

    part: str
    kind: str
    target_state: str
    target_mode: str
    raw_state: str
    raw_mode: str
    state_inferred: bool
    mode_inferred: bool
    cause: Cause | None = None
    since: float | None = None
    error: bool = False
    held_by: str = ""

    @property
    def actual_state(self) -> str:
        return self.raw_state + (INFERRED if self.state_inferred else "")

    @property
    def actual_mode(self) -> str:
        return self.raw_mode + (INFERRED if self.raw_mode and self.mode_inferred else "")

    @property
    def diverges(self) -> bool:
        return self.cause is not None


def row_of(status: PartSnapshot) -> Row:
    actual, target, divergence = status.actual, status.target, status.divergence
    return Row(
        part=status.part,
        kind=status.kind.value,
        target_state=target.state.label if target else "",
        target_mode=(target.mode or "") if target else "",
        raw_state=actual.state.label,
        raw_mode=actual.mode or "",
        state_inferred=actual.state_inferred,
        mode_inferred=bool(actual.mode) and actual.mode_inferred,
        cause=divergence.cause if divergence else None,
        since=divergence.since if divergence else None,
        error=divergence is not None and divergence.is_error,
        held_by=status.held_by,
    )


def snapshot(manager: ModeManager) -> list[Row]:
    """One row per part: systems, then nodes, each sorted by name."""
    return [row_of(status) for status in sorted(manager.snapshot(), key=lambda s: (s.is_node, s.part))]


@dataclass(frozen=True)
class Selection:
    """Which parts to show: those whose names match any of ``patterns`` (shell-style: ``*``, ``?``,
    ``[abc]``; every part when there is none), only the diverging ones if ``diverging``, and no
    more than ``limit`` of them (``None``: all). Over the limit, the divergences that are errors
    come first, then the other divergences, then the rest from the top of the hierarchy down; they
    are shown systems first, then nodes, each by name, as always."""

    patterns: tuple[str, ...] = ()
    diverging: bool = False
    limit: int | None = None

    def __post_init__(self) -> None:
        if self.limit is not None and self.limit < 1:
            raise ValueError(f"a monitor shows at least one row, not {self.limit}")

    def names(self, parts: Iterable[str]) -> list[str]:
        """The parts (of ``parts``) whose names match."""
        if not self.patterns:
            return list(parts)
        pattern = re.compile("|".join(f"(?:{fnmatch.translate(p)})" for p in self.patterns))
        return [part for part in parts if pattern.match(part)]


@dataclass(frozen=True)
class Summary:
    """How many parts the model has, of which kind, how many diverge (``errors`` of them beyond
    the grace period and unexplained), and how many rows are shown."""

    parts: int
    systems: int
    nodes: int
    diverging: int
    errors: int
    shown: int

    def describe(self) -> str:
        """``111,111 parts (11,111 systems, 100,000 nodes): 12 diverge, 1 an error; 40 shown``."""
        diverging = f"{self.diverging:,} diverge" + (f", {self.errors:,} an error" if self.errors == 1 else
                                                     f", {self.errors:,} errors" if self.errors else "")
        return (f"{parts_phrase(self.parts, self.systems)}: {diverging if self.diverging else 'none diverges'}; "
                f"{self.shown:,} shown")


def parts_phrase(parts: int, systems: int) -> str:
    """``111,111 parts (11,111 systems, 100,000 nodes)``: how large a model is, where its parts are counted."""
    return f"{_count(parts, 'part')} ({_count(systems, 'system')}, {_count(parts - systems, 'node')})"


def _count(number: int, noun: str) -> str:
    return f"{number:,} {noun}{'' if number == 1 else 's'}"


class Rows:
    """The rows of ``manager``'s parts that ``selection`` shows, kept from the manager's events.

    :meth:`changed` runs in the manager's lock, on any thread (a ROS backend's); :meth:`current`
    in the owner's, taking the lock while it reads."""

    def __init__(self, manager: ModeManager, selection: Selection) -> None:
        self._manager = manager
        self.selection = selection
        model = manager.model
        self._children = {system.name: system.parts for system in model.systems}
        ordered = sorted(model.parts, key=lambda name: (isinstance(model.parts[name], NodePart), name))
        # The candidates in display order; a part's place in it orders any subset.
        self._candidates = selection.names(ordered)
        self._place = {part: index for index, part in enumerate(self._candidates)}
        # The order the rest fills a limit in: the top of the hierarchy first, which sums up the rest.
        place = self._place
        self._fill = [place[part] for part in top_down(model.parts, self._children) if part in place]
        self._cache: dict[str, Row] = {}
        self._stale: set[str] = set()
        with manager.lock:
            # Every divergence (part -> error?), matched or not: the summary counts them all.
            self._diverging = {d.part: d.is_error for d in manager.divergences()}
            self._errors = sum(self._diverging.values())

    def changed(self, event: Event) -> None:
        """Note what ``event`` changed (call in the manager's lock)."""
        part = event.part
        if event.kind is EventKind.DIVERGENCE:
            was = self._diverging.pop(part, None)
            if was:
                self._errors -= 1
            if event.divergence is not None:
                error = event.divergence.is_error
                self._diverging[part] = error
                self._errors += error
        elif event.kind is EventKind.HOLD:  # held_by shows on the part and every part below it
            self._stale.update(parts_below(part, self._children))
        self._stale.add(part)

    def current(self) -> tuple[list[Row], Summary]:
        """The rows shown now, in display order, and the summary."""
        manager = self._manager
        with manager.lock:
            cache = self._cache
            for part in self._stale:
                cache.pop(part, None)
            self._stale.clear()
            shown = self._shown()
            rows = []
            for part in shown:
                row = cache.get(part)
                if row is None:
                    row = cache[part] = row_of(manager.status(part))
                rows.append(row)
            if len(cache) > 2 * len(rows) + 64:  # rows of parts no longer shown: made again if they are
                self._cache = {row.part: row for row in rows}
            parts, systems = len(manager.model.parts), len(self._children)
            summary = Summary(parts, systems, parts - systems, len(self._diverging), self._errors, len(rows))
        return rows, summary

    def _shown(self) -> list[str]:
        return shown(self._candidates, self._place, self._fill, self._diverging, self.selection)


def shown(candidates: list[str], place: dict[str, int], fill: list[int], diverging: dict[str, bool],
          selection: Selection) -> list[str]:
    """The parts :class:`Selection` shows: of ``candidates`` (display order; ``place``: each one's
    index there; ``fill``: their indices from the top of the hierarchy down), given the parts that
    diverge (``diverging``: part -> whether it is an error)."""
    limit = selection.limit
    if not selection.diverging and (limit is None or len(candidates) <= limit):
        return candidates
    ranked = sorted((not error, place[part]) for part, error in diverging.items() if part in place)
    picked = [index for _, index in ranked[:limit]]
    if not selection.diverging and limit is not None and len(picked) < limit:
        taken = set(picked)
        for index in fill:
            if len(picked) >= limit:
                break
            if index not in taken:
                picked.append(index)
    return [candidates[index] for index in sorted(picked)]
