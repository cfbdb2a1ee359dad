"""Checks and walks over the system hierarchy that need the parts of every system."""

from __future__ import annotations

from collections.abc import Mapping

from sm_bt.model.diagnostics import Diagnostics


def report_cycles(children: Mapping[str, tuple[str, ...]], lines: Mapping[str, int], diag: Diagnostics) -> bool:
    """Report each cycle once (``a -> b -> a``); True when there is none."""
    done: set[str] = set()
    seen_cycles: set[frozenset[str]] = set()

    def visit(name: str, path: list[str]) -> None:
        if name in path:
            cycle = [*path[path.index(name):], name]
            if frozenset(cycle) not in seen_cycles:
                seen_cycles.add(frozenset(cycle))
                shown = " -> ".join(cycle)
                what = "contains itself" if len(cycle) == 2 else "contains itself through its parts"
                diag.error(lines.get(name, 0), f"system {name!r} {what}: {shown}: remove one of these "
                                               "parts so that the hierarchy is a tree")
            return
        if name in done:
            return
        for child in children.get(name, ()):
            visit(child, [*path, name])
        done.add(name)

    for name in children:
        visit(name, [])
    return not seen_cycles


def parts_below(name: str, children: Mapping[str, tuple[str, ...]]) -> tuple[str, ...]:
    """Every part under ``name`` (direct parts first, then deeper), each once; cycle-safe."""
    found: dict[str, None] = {}
    frontier = list(children.get(name, ()))
    while frontier:
        current = frontier.pop(0)
        if current in found or current == name:
            continue
        found[current] = None
        frontier.extend(children.get(current, ()))
    return tuple(found)
