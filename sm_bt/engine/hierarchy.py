"""The shape of a model's hierarchy, computed once: parents, ancestors, heights, bottom-up order.

The model's own query helpers walk the hierarchy on every call; the engine asks the same
questions on every node report, so it asks them here once, in time linear in the model (no
recursion: a legal hierarchy may be deeper than Python's recursion limit).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, SystemPart


@dataclass(frozen=True)
class Hierarchy:
    """``parents[p]``: systems listing ``p``; ``ancestors[p]``: every system above ``p``, lowest
    first; ``height[p]``: 0 for a node or an empty system, else 1 + its tallest part;
    ``bottom_up``: every part, children before their systems."""

    parents: dict[str, tuple[str, ...]]
    ancestors: dict[str, tuple[str, ...]]
    height: dict[str, int]
    bottom_up: tuple[str, ...]

    @classmethod
    def of(cls, model: Model) -> Hierarchy:
        parents: dict[str, list[str]] = {name: [] for name in model.parts}
        for system in model.systems:
            for child in dict.fromkeys(system.parts):
                parents[child].append(system.name)
        height = _heights(model)
        bottom_up = tuple(sorted(model.parts, key=height.__getitem__))
        ancestors: dict[str, tuple[str, ...]] = {}
        for name in reversed(bottom_up):  # top-down: a part's parents are done before it
            above: dict[str, None] = {}
            for parent in parents[name]:
                above[parent] = None
                above.update(dict.fromkeys(ancestors[parent]))
            ancestors[name] = tuple(sorted(above, key=height.__getitem__))
        return cls({k: tuple(v) for k, v in parents.items()}, ancestors, height, bottom_up)


def _heights(model: Model) -> dict[str, int]:
    height: dict[str, int] = {}
    for root in model.parts:
        stack = [(root, False)]
        while stack:
            name, expanded = stack.pop()
            if name in height:
                continue
            part = model.parts[name]
            if not isinstance(part, SystemPart) or not part.parts:
                height[name] = 0
            elif expanded:
                height[name] = 1 + max(height[child] for child in part.parts)
            else:
                stack.append((name, True))
                stack.extend((child, False) for child in part.parts if child not in height)
    return height


def child_targets(system: SystemPart, target: StateMode) -> Iterator[tuple[str, StateMode]]:
    """What ``target`` of ``system`` asks of each of its parts (don't-care entries ask nothing)."""
    if target.state is State.ACTIVE:
        for entry in system.modes[target.mode or system.default_mode].entries.values():
            if entry.target is not None:
                yield entry.part, entry.target
    else:
        for child in system.parts:
            yield child, StateMode(target.state)


def implied_targets(model: Model, part: str, target: StateMode) -> list[tuple[str, StateMode]]:
    """``(part, target)`` first, then every part below with the target that implies, top-down. A
    part reached twice (shared by two systems) keeps the first target it was given."""
    found: dict[str, StateMode] = {}
    stack = [(part, target)]
    while stack:
        name, value = stack.pop()
        if name in found:
            continue
        found[name] = value
        spec = model.parts[name]
        if isinstance(spec, SystemPart):
            stack.extend(reversed(list(child_targets(spec, value))))
    return list(found.items())
