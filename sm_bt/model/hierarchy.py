"""Checks and walks over the system hierarchy that need the parts of every system."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

from sm_bt.model.diagnostics import Diagnostics


def report_cycles(children: Mapping[str, tuple[str, ...]], lines: Mapping[str, int], diag: Diagnostics) -> bool:
    """Report each cycle once (``a -> b -> a``); True when there is none.

    Depth first with a stack of its own, not recursion: a legal hierarchy may be nested deeper
    than Python's recursion limit (1,000 systems one inside the other load)."""
    done: set[str] = set()
    seen_cycles: set[frozenset[str]] = set()
    for root in children:
        if root in done:
            continue
        path = [root]
        on_path = {root: 0}
        stack: list[tuple[str, Iterator[str]]] = [(root, iter(children.get(root, ())))]
        while stack:
            name, remaining = stack[-1]
            child = next(remaining, None)
            if child is None:
                stack.pop()
                path.pop()
                del on_path[name]
                done.add(name)
                continue
            if child in on_path:
                cycle = [*path[on_path[child]:], child]
                if frozenset(cycle) not in seen_cycles:
                    seen_cycles.add(frozenset(cycle))
                    shown = " -> ".join(cycle if len(cycle) <= 8 else
                                        [*cycle[:4], f"... {len(cycle) - 6} more ...", *cycle[-2:]])
                    what = "contains itself" if len(cycle) == 2 else "contains itself through its parts"
                    diag.error(lines.get(child, 0), f"system {child!r} {what}: {shown}: remove one of these "
                                                    "parts so that the hierarchy is a tree")
                continue
            if child in done:
                continue
            on_path[child] = len(path)
            path.append(child)
            stack.append((child, iter(children.get(child, ()))))
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


def top_down(parts: Iterable[str], children: Mapping[str, tuple[str, ...]]) -> list[str]:
    """``parts`` from the top of the hierarchy down: by depth below the systems that are nobody's
    part (the deepest, for a part of several systems), systems before nodes, then by name. Where
    there are too many parts to show them all (a monitor, ``/diagnostics``), the first ones sum up
    the rest."""
    depth = dict.fromkeys(parts, 0)
    below = {part for inside in children.values() for part in inside}
    level = [part for part in depth if part not in below]
    for height in range(1, len(depth) + 1):  # a bound on the depth: a cycle cannot loop for ever
        level = [part for parent in level for part in children.get(parent, ()) if depth.get(part, height) < height]
        if not level:
            break
        for part in level:
            depth[part] = height
    return sorted(depth, key=lambda part: (depth[part], part not in children, part))
