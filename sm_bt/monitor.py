"""The mode monitor's table: part, target state, actual state, target mode, actual mode.

Systems first, then nodes, each alphabetically, as the reference's monitor; ``(*)`` marks values
that were inferred rather than reported, and ``!`` marks a part that diverges from its target.
"""

from __future__ import annotations

from dataclasses import dataclass

from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import NodePart


@dataclass(frozen=True)
class Row:
    part: str
    kind: str
    target_state: str
    actual_state: str
    target_mode: str
    actual_mode: str
    diverges: bool


def snapshot(manager: ModeManager) -> list[Row]:
    """One row per part: systems, then nodes, each sorted by name."""
    rows: list[Row] = []
    model = manager.model
    ordered = sorted(model.parts.values(), key=lambda p: (isinstance(p, NodePart), p.name))
    for part in ordered:
        actual = manager.actual(part.name)
        target = manager.target(part.name)
        state = actual.state.label + ("(*)" if actual.state_inferred else "")
        mode = (actual.mode + ("(*)" if actual.mode_inferred else "")) if actual.mode else ""
        rows.append(Row(
            part=part.name,
            kind=part.kind.value,
            target_state=target.state.label if target else "",
            actual_state=state,
            target_mode=(target.mode or "") if target else "",
            actual_mode=mode,
            diverges=manager.divergence(part.name) is not None,
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
    return "\n".join(lines)
