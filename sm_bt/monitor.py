"""The mode monitor's table: part, target state, actual state, target mode, actual mode.

Systems first, then nodes, each alphabetically, as the reference's monitor; ``(*)`` marks values
that were inferred rather than reported, and ``!`` marks a part that diverges from its target.
:func:`render_text` is the plain layout (logs, the demo), :func:`render_rich` the coloured one
(error divergences bold red, transient ones yellow), :func:`to_json` a machine-readable snapshot,
and :class:`Monitor` keeps either up to date from the manager's events.
"""

from __future__ import annotations

import io
import json
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TextIO, cast

from rich import box
from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.manager import ModeManager

INFERRED = "(*)"
#: Row styles: divergences that rules/recovery (or a human) must deal with, and ones that are settling.
ERROR_STYLE = "bold red"
TRANSIENT_STYLE = "yellow"
#: The events that can change a row; requests, rules and failures show through these.
_ROW_EVENTS = frozenset({EventKind.ACTUAL, EventKind.TARGET, EventKind.DIVERGENCE})

JsonSnapshot = dict[str, Any]


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


def snapshot(manager: ModeManager) -> list[Row]:
    """One row per part: systems, then nodes, each sorted by name."""
    rows: list[Row] = []
    for status in sorted(manager.snapshot(), key=lambda s: (s.is_node, s.part)):
        actual, target, divergence = status.actual, status.target, status.divergence
        rows.append(Row(
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
        ))
    return rows


def render_text(rows: list[Row]) -> str:
    """A plain-text table (no colours), the layout of the reference's monitor."""
    header = ("part", "target state", "actual state", "target mode", "actual mode")
    cells = [header] + [(r.part, r.target_state, r.actual_state, r.target_mode, r.actual_mode) for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    lines = ["  " + "  ".join(text.ljust(widths[i]) for i, text in enumerate(header))]
    kind = ""
    for row, text in zip(rows, cells[1:], strict=True):
        if row.kind != kind:
            kind = row.kind
            lines.append(f"- {kind}s " + "-" * (sum(widths) + 2 * len(widths) - len(kind) - 3))
        mark = "! " if row.diverges else "  "
        lines.append(mark + "  ".join(t.ljust(widths[i]) for i, t in enumerate(text)).rstrip())
    lines.append(" (*) = inferred    ! = diverges from target")
    lines.extend(f" held by {holder}: {', '.join(parts)}" for holder, parts in held(rows).items())
    return "\n".join(lines)


def held(rows: list[Row]) -> dict[str, list[str]]:
    """Who holds which parts (in the rows' order), for the lines under the table."""
    holders: dict[str, list[str]] = {}
    for row in rows:
        if row.held_by:
            holders.setdefault(row.held_by, []).append(row.part)
    return holders


#: Wide enough that rich never wraps a line of ours when writing to a pipe or a file.
PLAIN_WIDTH = 10_000


class _StripTrailingSpace(io.TextIOBase):
    """Passes text on with the spaces that end each line removed (rich pads table cells)."""

    def __init__(self, stream: TextIO) -> None:
        self.stream = stream
        self.pending = ""

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        *lines, self.pending = (self.pending + text).split("\n")
        for line in lines:
            self.stream.write(line.rstrip(" ") + "\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()


def terminal_console(stream: TextIO | None = None) -> Console:
    """A console for ``stream`` (stdout). On a terminal, rich's own (its width, colour unless
    ``NO_COLOR`` is set). On a pipe or a file, plain text a program or a person can read: no
    colour or other escape codes, lines never wrapped, no trailing spaces."""
    stream = sys.stdout if stream is None else stream
    console = Console(file=stream, highlight=False)
    if console.is_terminal:
        return console
    return Console(file=cast(TextIO, _StripTrailingSpace(stream)), highlight=False, width=PLAIN_WIDTH, no_color=True,
                   color_system=None, force_terminal=False, soft_wrap=True)


def row_style(row: Row) -> str | None:
    """The highlight of a row: errors stand out, settling divergences only draw the eye."""
    if not row.diverges:
        return None
    return ERROR_STYLE if row.error else TRANSIENT_STYLE


def legend() -> Text:
    """The caption: what ``(*)`` and the two highlights mean."""
    return Text.assemble((INFERRED, "dim"), " inferred   ", ("! error", ERROR_STYLE), " (fault, override)   ",
                         ("~ settling", TRANSIENT_STYLE), " (in flight, grace)")


def _value(raw: str, inferred: bool) -> Text:
    text = Text(raw)
    if raw and inferred:
        text.append(INFERRED, style="dim")
    return text


def render_rich(rows: list[Row], *, title: str | None = None) -> Table:
    """The table for a rich console: a ``systems`` section then a ``nodes`` section, ``(*)`` kept
    (dimmed), each diverging row styled by :func:`row_style`, and the legend as caption."""
    caption = legend()
    for holder, parts in held(rows).items():
        caption.append(f"\nheld by {holder}: {', '.join(parts)}")
    table = Table(title=title, caption=caption, box=box.SIMPLE_HEAD, caption_justify="left",
                  pad_edge=False)
    table.add_column("", no_wrap=True, min_width=1)
    # Narrow terminals fold long names rather than cut them: every character of a mode name counts.
    for header in ("part", "target state", "actual state", "target mode", "actual mode"):
        table.add_column(header, overflow="fold")
    kind = ""
    for index, row in enumerate(rows):
        if row.kind != kind:
            kind = row.kind
            table.add_row("", Text(f"{kind}s", style="bold"))
        mark = "" if not row.diverges else ("!" if row.error else "~")
        section_ends = index + 1 < len(rows) and rows[index + 1].kind != row.kind
        table.add_row(mark, row.part, row.target_state, _value(row.raw_state, row.state_inferred),
                      row.target_mode, _value(row.raw_mode, row.mode_inferred),
                      style=row_style(row), end_section=section_ends)
    return table


def to_json(rows: list[Row], now: float, epoch: float = 0.0) -> JsonSnapshot:
    """A JSON-serialisable snapshot at clock time ``now``: raw values (``null`` when absent),
    inferred flags, and the divergence (``null`` when on target). Every time in it (``time``, a
    divergence's ``since``) is in seconds since ``epoch``, the start of the run, on the manager's
    clock (virtual seconds on simulated nodes), rounded to the microsecond."""
    return {"time": round(now - epoch, 6), "parts": [_json_row(row, epoch) for row in rows]}


def _json_row(row: Row, epoch: float) -> dict[str, Any]:
    divergence = None
    if row.cause is not None:
        since = None if row.since is None else round(row.since - epoch, 6)
        divergence = {"cause": row.cause.value, "since": since, "error": row.error}
    return {
        "part": row.part,
        "kind": row.kind,
        "target_state": row.target_state or None,
        "target_mode": row.target_mode or None,
        "actual_state": row.raw_state,
        "actual_mode": row.raw_mode or None,
        "state_inferred": row.state_inferred,
        "mode_inferred": row.mode_inferred,
        "divergence": divergence,
        "held_by": row.held_by or None,
    }


class Monitor:
    """Keeps a view of ``manager`` up to date: a rich table on a :class:`Console`, or JSON Lines on
    a text stream.

    The manager's callbacks run inside its lock, possibly in another thread, so they only mark
    the view dirty; the owner calls :meth:`refresh` (from its loop) to render, and only a change
    of the rows renders anything. ``title`` is shown above the table with the clock time, counted
    from ``epoch`` (a wall clock's raw monotonic time means nothing to a reader: pass its start).
    """

    def __init__(self, manager: ModeManager, output: Console | TextIO, *, title: str | None = None,
                 epoch: float = 0.0) -> None:
        self.manager = manager
        self.epoch = epoch
        self.output = output
        self.title = title
        #: How many times the view was rendered (tables printed, live updates, JSON lines).
        self.renders = 0
        self._dirty = True
        self._last: list[Row] | None = None
        self._live: Live | None = None
        self._subscription = manager.subscribe(self._changed, kinds=_ROW_EVENTS)

    @property
    def json(self) -> bool:
        return not isinstance(self.output, Console)

    @property
    def dirty(self) -> bool:
        """Something may have changed since the last render."""
        return self._dirty

    def _changed(self, event: Event) -> None:
        self._dirty = True

    def table(self, rows: list[Row] | None = None) -> Table:
        """The current table (``rows`` if given), titled with the clock time."""
        now = f"t = {self.manager.clock.now() - self.epoch:.2f} s"
        title = f"{self.title} at {now}" if self.title else now
        return render_rich(snapshot(self.manager) if rows is None else rows, title=title)

    def print_table(self) -> None:
        """Print the current view now, changed or not (a table, or one JSON line)."""
        self._dirty = False
        rows = snapshot(self.manager)
        self._last = rows
        self._show(rows, live=False)

    def refresh(self) -> bool:
        """Render if the rows changed since the last render; return whether it did."""
        if not self._dirty:
            return False
        self._dirty = False  # before the snapshot: a change during it marks dirty again
        rows = snapshot(self.manager)
        if rows == self._last:
            return False
        self._last = rows
        self._show(rows, live=self._live is not None)
        return True

    @contextmanager
    def live(self) -> Iterator[Monitor]:
        """Show the table in place (rich ``Live``, refreshed only by :meth:`refresh`). In JSON mode
        there is nothing to keep in place: :meth:`refresh` prints lines as usual."""
        if not isinstance(self.output, Console):
            yield self
            return
        self._dirty = False
        self._last = snapshot(self.manager)
        with Live(self.table(self._last), console=self.output, auto_refresh=False) as live:
            self.renders += 1
            self._live = live
            try:
                yield self
            finally:
                self._live = None

    def close(self) -> None:
        """Stop following the manager."""
        self._subscription.cancel()

    def _show(self, rows: list[Row], *, live: bool) -> None:
        self.renders += 1
        if isinstance(self.output, Console):
            if live and self._live is not None:
                self._live.update(self.table(rows), refresh=True)
            else:
                self.output.print(self.table(rows))
        else:
            self.output.write(json.dumps(to_json(rows, self.manager.clock.now(), self.epoch)) + "\n")
            self.output.flush()
