"""Trees: what a mission tree asks of the model, what it never asks, and what a fault makes
unreachable while no contingency of the tree watches for it.

Read from the tree file itself (with each element's file and line): ``ChangeMode``,
``HoldMode`` and ``SwitchOnDivergence`` ask for a mode, ``ChangeState`` for a transition;
``OnDivergence`` and ``SwitchOnDivergence`` are contingencies watching a part (or every part)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from sm_bt.analysis.faults import Outcome
from sm_bt.analysis.findings import Finding, Kind, Level
from sm_bt.analysis.reach import asked_for
from sm_bt.model.types import Location, Model, SystemPart
from sm_bt.trees.tree_documents import Documents

_ASKS = {"changemode": "mode", "holdmode": "mode", "switchondivergence": "mode"}
_WATCHES = ("ondivergence", "switchondivergence")


@dataclass
class TreeUse:
    """What one tree file asks for and watches."""

    path: str
    #: (part, mode) -> where the tree asks for it first.
    modes: dict[tuple[str, str], Location] = field(default_factory=dict)
    transitions: dict[tuple[str, str], Location] = field(default_factory=dict)
    #: Parts a contingency watches (None: every part).
    watched: set[str | None] = field(default_factory=set)


def tree_use(path: str | Path) -> TreeUse:
    """Read ``path`` (a tree file that checks clean) for what it asks and watches."""
    documents = Documents(Path(path))
    documents.read(Path(path), set())
    use = TreeUse(str(path))
    for tree in documents.trees.values():
        for element in tree.iter():
            tag = element.tag.lower()
            file, line = documents.where.get(id(element), (str(path), 0))
            where = Location(file, line)
            part = element.get("system") if tag == "switchondivergence" else element.get("part")
            if tag in _ASKS and part and element.get("mode"):
                use.modes.setdefault((part, element.get("mode", "")), where)
            elif tag == "changestate" and part and element.get("transition"):
                use.transitions.setdefault((part, element.get("transition", "")), where)
            if tag in _WATCHES:
                use.watched.add(element.get("part") or None)
    return use


def tree_findings(model: Model, uses: list[TreeUse], outcomes: list[Outcome]) -> list[Finding]:
    findings: list[Finding] = []
    asked = {key for use in uses for key in use.modes}
    for use in uses:
        for (part, mode), where in use.modes.items():
            blocking = [o for o in outcomes if (part, mode) in o.blocked
                        and not _covered(model, use.watched, [fault.node for fault in o.faults])]
            if blocking:
                nodes = list(dict.fromkeys(fault.node for o in blocking for fault in o.faults))
                first = blocking[0]
                findings.append(Finding(
                    Kind.TREE_UNREACHABLE, Level.WARNING, where,
                    f"the tree asks for {part} {mode}, which a fault of {', '.join(nodes)} makes unreachable, and no "
                    f"contingency of the tree (OnDivergence, SwitchOnDivergence) watches "
                    f"{'it' if len(nodes) == 1 else 'them'}",
                    f"from {first.start}, a {' + '.join(map(str, first.faults))}: {first.blocked[(part, mode)]}"))
    tops = {name for name, part in model.parts.items() if isinstance(part, SystemPart)} & {p for p, _ in asked}
    unasked = sorted((part, mode) for part, mode in asked_for(model) if part in tops and (part, mode) not in asked)
    if uses and unasked:
        findings.append(Finding(
            Kind.TREE_UNASKED, Level.NOTE, model.parts[unasked[0][0]].location,
            f"no tree asks for {', '.join(f'{part} {mode}' for part, mode in unasked)}"))
    return findings


def _covered(model: Model, watched: set[str | None], nodes: list[str]) -> bool:
    """Does a contingency watch one of ``nodes`` (or a system above it, or every part)?"""
    if None in watched:
        return True
    for node in nodes:
        frontier, seen = [node], set()
        while frontier:
            part = frontier.pop()
            if part in watched:
                return True
            seen.add(part)
            frontier += [name for name, system in model.parts.items()
                         if isinstance(system, SystemPart) and part in system.parts and name not in seen]
    return False
