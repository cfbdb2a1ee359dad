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
from typing import Any, TextIO, cast

from rich import box
from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from sm_bt.engine.events import Event
from sm_bt.engine.manager import ModeManager
from sm_bt.monitor_rows import INFERRED, ROW_EVENTS, Row, Rows, Selection, Summary, snapshot

#: Row styles: divergences that rules/recovery (or a human) must deal with, and ones that are settling.
ERROR_STYLE = "bold red"
TRANSIENT_STYLE = "yellow"

JsonSnapshot = dict[str, Any]

__all__ = ["ERROR_STYLE", "INFERRED", "TRANSIENT_STYLE", "Monitor", "Row", "Selection", "Summary", "held", "legend",
           "render_rich", "render_text", "row_style", "snapshot", "terminal_console", "to_json"]


def render_text(rows: list[Row], summary: Summary | None = None) -> str:
    """A plain-text table (no colours), the layout of the reference's monitor; ``summary`` (when
    some parts are left out) under it."""
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
    if summary is not None:
        lines.append(f" {summary.describe()}")
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


def render_rich(rows: list[Row], *, title: str | None = None, summary: Summary | None = None) -> Table:
    """The table for a rich console: a ``systems`` section then a ``nodes`` section, ``(*)`` kept
    (dimmed), each diverging row styled by :func:`row_style`, and the legend as caption, with
    ``summary`` (when some parts are left out)."""
    caption = legend()
    for holder, parts in held(rows).items():
        caption.append(f"\nheld by {holder}: {', '.join(parts)}")
    if summary is not None:
        caption.append(f"\n{summary.describe()}", style="bold")
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


def to_json(rows: list[Row], now: float, epoch: float = 0.0, summary: Summary | None = None) -> JsonSnapshot:
    """A JSON-serialisable snapshot at clock time ``now``: raw values (``null`` when absent),
    inferred flags, and the divergence (``null`` when on target). Every time in it (``time``, a
    divergence's ``since``) is in seconds since ``epoch``, the start of the run, on the manager's
    clock (virtual seconds on simulated nodes), rounded to the microsecond. ``summary``, if given,
    is its counts under ``"summary"``."""
    data: JsonSnapshot = {"time": round(now - epoch, 6), "parts": [_json_row(row, epoch) for row in rows]}
    if summary is not None:
        data["summary"] = {"parts": summary.parts, "systems": summary.systems, "nodes": summary.nodes,
                           "diverging": summary.diverging, "errors": summary.errors, "shown": summary.shown}
    return data


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

    The manager's callbacks run inside its lock, possibly in another thread, so they only note
    which parts changed; the owner calls :meth:`refresh` (from its loop) to render, and only a
    change of what is shown renders anything. ``title`` is shown above the table with the clock
    time, counted from ``epoch`` (a wall clock's raw monotonic time means nothing to a reader: pass
    its start). ``selection`` says which parts are shown (:class:`~sm_bt.monitor_rows.Selection`;
    when it leaves some out, the summary says how many there are). With ``changes``, each JSON line
    after the first has only the rows that changed since the line before, and under ``"left"`` the
    parts no longer shown.
    """

    def __init__(self, manager: ModeManager, output: Console | TextIO, *, title: str | None = None,
                 epoch: float = 0.0, selection: Selection | None = None, changes: bool = False) -> None:
        self.manager = manager
        self.epoch = epoch
        self.output = output
        self.title = title
        self.changes = changes
        #: How many times the view was rendered (tables printed, live updates, JSON lines).
        self.renders = 0
        self._dirty = True
        self._last: tuple[list[Row], Summary] | None = None
        self._live: Live | None = None
        with manager.lock:
            self._rows = Rows(manager, selection or Selection())
            self._subscription = manager.subscribe(self._changed, kinds=ROW_EVENTS)

    @property
    def json(self) -> bool:
        return not isinstance(self.output, Console)

    @property
    def selection(self) -> Selection:
        return self._rows.selection

    @property
    def dirty(self) -> bool:
        """Something may have changed since the last render."""
        return self._dirty

    def _changed(self, event: Event) -> None:
        self._rows.changed(event)
        self._dirty = True

    def current(self) -> tuple[list[Row], Summary]:
        """The rows shown now and the summary of all parts."""
        return self._rows.current()

    def table(self, shown: tuple[list[Row], Summary] | None = None) -> Table:
        """The current table (``shown``: rows and summary, if given), titled with the clock time."""
        now = f"t = {self.manager.clock.now() - self.epoch:.2f} s"
        title = f"{self.title} at {now}" if self.title else now
        rows, summary = self.current() if shown is None else shown
        return render_rich(rows, title=title, summary=summary if summary.shown < summary.parts else None)

    def print_table(self) -> None:
        """Print the current view now, changed or not (a table, or one JSON line, always whole)."""
        self._dirty = False
        shown = self.current()
        self._show(shown, None, live=False)
        self._last = shown

    def refresh(self) -> bool:
        """Render if what is shown changed since the last render; return whether it did."""
        if not self._dirty:
            return False
        self._dirty = False  # before reading: a change meanwhile marks dirty again
        shown = self.current()
        if shown == self._last:
            return False
        self._show(shown, self._last, live=self._live is not None)
        self._last = shown
        return True

    @contextmanager
    def live(self) -> Iterator[Monitor]:
        """Show the table in place (rich ``Live``, refreshed only by :meth:`refresh`). In JSON mode
        there is nothing to keep in place: :meth:`refresh` prints lines as usual."""
        if not isinstance(self.output, Console):
            yield self
            return
        self._dirty = False
        self._last = self.current()
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

    def _show(self, shown: tuple[list[Row], Summary], before: tuple[list[Row], Summary] | None, *,
              live: bool) -> None:
        self.renders += 1
        if isinstance(self.output, Console):
            if live and self._live is not None:
                self._live.update(self.table(shown), refresh=True)
            else:
                self.output.print(self.table(shown))
            return
        rows, summary = shown
        data: JsonSnapshot
        if self.changes and before is not None:
            earlier = {row.part: row for row in before[0]}
            now = {row.part for row in rows}
            data = to_json([row for row in rows if earlier.get(row.part) != row], self.manager.clock.now(),
                           self.epoch, summary)
            data["left"] = [part for part in earlier if part not in now]
        else:
            data = to_json(rows, self.manager.clock.now(), self.epoch, summary)
        self.output.write(json.dumps(data) + "\n")
        self.output.flush()
