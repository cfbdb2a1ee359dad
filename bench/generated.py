"""Generated SMH models for the benchmarks: N nodes in systems of ``fanout``, nested until one root.

Every node has the modes ``__DEFAULT__`` and ``FAST``, which differ in 4 of its 5 parameters; every
system has the same two modes, each asking all of its parts to be active in that mode. With the
default fanout of 10, 1,000 nodes make 111 systems (depth 4 with the nodes), 10,000 nodes make
1,111 systems (depth 5): the shape the performance goals are stated for.
"""

from __future__ import annotations

from dataclasses import dataclass

ROOT = "root"
MODES = ("__DEFAULT__", "FAST")


@dataclass(frozen=True)
class Shape:
    """What :func:`model_text` made: the root system, the nodes, the systems bottom-up."""

    root: str
    nodes: tuple[str, ...]
    systems: tuple[str, ...]


def shape(nodes: int, fanout: int = 10) -> tuple[Shape, dict[str, list[str]]]:
    """The names and the parts of every system for ``nodes`` nodes (system -> its parts)."""
    if nodes < 1 or fanout < 2:
        raise ValueError("need at least one node and a fanout of at least 2")
    names = [f"n{i}" for i in range(nodes)]
    level, parts, systems, depth = names, {}, [], 0
    while True:
        depth += 1
        groups = [level[i:i + fanout] for i in range(0, len(level), fanout)]
        if len(groups) == 1:
            parts[ROOT] = groups[0]
            systems.append(ROOT)
            break
        upper = []
        for index, group in enumerate(groups):
            name = f"s{depth}_{index}"
            parts[name] = group
            systems.append(name)
            upper.append(name)
        level = upper
    return Shape(ROOT, tuple(names), tuple(systems)), parts


def model_text(nodes: int, fanout: int = 10) -> str:
    """The SMH text (one YAML document) of the generated model with ``nodes`` nodes."""
    described, parts = shape(nodes, fanout)
    out: list[str] = []
    for system in described.systems:
        members = parts[system]
        out.append(f"{system}:\n  ros__parameters:\n    type: system\n    parts:\n")
        out.extend(f"      {part}\n" for part in members)
        out.append("    modes:\n")
        for mode in MODES:
            out.append(f"      {mode}:\n")
            out.extend(f"        {part}: active.{mode}\n" for part in members)
    for index, node in enumerate(described.nodes):
        out.append(f"{node}:\n  ros__parameters:\n    type: node\n    modes:\n")
        for scale, mode in enumerate(MODES, start=1):
            out.append(
                f"      {mode}:\n        ros__parameters:\n"
                f"          speed: {0.5 * scale + index % 7}\n"
                f"          rate: {10 * scale + index % 5}\n"
                f"          planner: \"{mode.strip('_').lower()}_{index % 3}\"\n"
                f"          enabled: {'true' if scale == 2 else 'false'}\n"
                f"          frame: \"map\"\n")
    return "".join(out)
