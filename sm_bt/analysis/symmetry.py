"""Nodes that a fault analysis need not run one by one: two nodes are alike when some renaming of
the model's parts maps one onto the other, so that a fault of either ends the same way (with the
names swapped). Found by a signature per node: its own modes (their names and parameters, and
which of them inference can tell apart: the values themselves only matter through that), what
its system's modes and rules ask of it, and its system's place, alike up to the top systems (a
node of two systems, and the top systems, stand alone). The benchmarks' generated model of 1,000
nodes in systems of ten is one class."""

from __future__ import annotations

import functools
import itertools
from collections.abc import Hashable

from sm_bt.model.match_specs import compared_exactly, may_both_match
from sm_bt.model.types import Model, NodePart, SystemPart


def alike_nodes(model: Model) -> dict[str, list[str]]:
    """Each class of alike nodes, by its first node (in model order): the others."""
    parents: dict[str, list[str]] = {}
    for name, part in model.parts.items():
        if isinstance(part, SystemPart):
            for child in part.parts:
                parents.setdefault(child, []).append(name)

    @functools.cache
    def canon(name: str) -> Hashable:
        part = model.parts[name]
        if isinstance(part, NodePart):
            modes = sorted(part.modes.items())
            told_apart = tuple(not all(may_both_match(spec, other.parameters[key])
                                       for key, spec in mode.parameters.items() if key in other.parameters)
                               for (_, mode), (_, other) in itertools.combinations(modes, 2))
            shapes = tuple((name, tuple(sorted((key, type(spec.value).__name__, compared_exactly(spec))
                                               for key, spec in mode.parameters.items()))) for name, mode in modes)
            return ("node", part.default_mode, shapes, told_apart)
        assert isinstance(part, SystemPart)
        stages = tuple((mode_name, tuple(tuple(sorted(repr(place(child, name)) for child in stage))
                                         for stage in mode.stages)) for mode_name, mode in sorted(part.modes.items()))
        return ("system", part.default_mode, tuple(sorted(repr(place(child, name)) for child in part.parts)), stages)

    @functools.cache
    def place(child: str, parent: str) -> Hashable:
        system = model.parts[parent]
        assert isinstance(system, SystemPart)
        entries = tuple((mode, str(system.modes[mode].entries[child].target)) for mode in sorted(system.modes))
        rules = tuple(sorted((str(r.if_target), str(r.if_part_state), str(r.new_target))
                             for r in system.rules if r.if_part == child))
        return canon(child), entries, rules

    @functools.cache
    def key(name: str) -> Hashable:
        above = parents.get(name, [])
        if len(above) != 1:
            return ("alone", name)
        return place(name, above[0]), key(above[0])

    classes: dict[Hashable, list[str]] = {}
    for node in model.nodes:
        classes.setdefault(key(node.name), []).append(node.name)
    return {members[0]: members[1:] for members in classes.values()}
