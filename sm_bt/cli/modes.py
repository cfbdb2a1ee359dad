"""``sm-bt modes MODEL``: the systems, modes, rules and node parameters of a model, as text."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterator

from sm_bt.cli.arguments import non_negative
from sm_bt.cli.common import add_lenient, bundled_names, load_or_report, part_counts, print_issues
from sm_bt.model.types import (
    DONT_CARE,
    EXACT,
    Match,
    Model,
    NodePart,
    ParamValue,
    PartEntry,
    Rule,
    SystemPart,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL",
                        help="model file, or the name of a bundled model (" + ", ".join(bundled_names()) + "); "
                             "with --ros, a part")
    add_lenient(parser)
    parser.add_argument("--ros", action="store_true",
                        help="ask a running mode manager for the modes it offers for the part MODEL names "
                             "(as `sm-bt mode list PART`)")
    parser.add_argument("--timeout", type=non_negative, default=10.0, metavar="SECONDS",
                        help="with --ros: give up after this long (default 10)")


def run(args: argparse.Namespace) -> int:
    if args.ros:
        from sm_bt.cli.remote import run_mode

        return run_mode(argparse.Namespace(action="list", part=args.model, timeout=args.timeout))
    model = load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    print_issues(model.warnings, sys.stderr)
    for line in describe_model(model):
        print(line)
    return 0


def describe_model(model: Model) -> Iterator[str]:
    """The hierarchy of ``model`` as plain-text lines (systems top-down, then every node)."""
    yield f"model {model.path}: {part_counts(model)}"
    shown: set[str] = set()
    for root in model.roots():
        part = model.parts[root]
        if isinstance(part, SystemPart):
            yield ""
            yield from _describe_system(model, part, 0, shown)
    if model.nodes:
        yield ""
        yield "nodes and remote parts" if any(node.remote is not None for node in model.nodes) else "nodes"
    for node in model.nodes:
        yield from _describe_node(model, node, 1)
    yield ""
    yield f"legend: * default mode, (keep) {DONT_CARE} (left as it is), ~ inference matching"


def _describe_system(model: Model, system: SystemPart, depth: int, shown: set[str]) -> Iterator[str]:
    pad = "  " * depth
    if system.name in shown:
        yield f"{pad}system {system.name} (shown above)"
        return
    shown.add(system.name)
    yield f"{pad}system {system.name}"
    yield f"{pad}  parts: {', '.join(system.parts) or '(none)'}"
    yield f"{pad}  modes:"
    for mode in system.modes.values():
        marker = "*" if mode.name == system.default_mode else " "
        yield f"{pad}    {marker} {mode.name}"
        for part in system.parts:
            entry = mode.entries.get(part)
            if entry is not None:
                yield f"{pad}        {part}: {_entry_text(entry)}"
        if len(mode.stages) > 1:
            yield f"{pad}        order: {' -> '.join(', '.join(stage) for stage in mode.stages)}"
    if system.rules:
        yield f"{pad}  rules:"
        for rule in system.rules:
            yield f"{pad}    {_rule_text(rule)}"
    for name in system.parts:
        child = model.parts[name]
        if isinstance(child, SystemPart):
            yield from _describe_system(model, child, depth + 1, shown)


def _describe_node(model: Model, node: NodePart, depth: int) -> Iterator[str]:
    pad = "  " * depth
    parents = model.parents(node.name)
    where = f"part of {', '.join(parents)}" if parents else "in no system"
    if node.remote is not None:  # its modes are names: its manager holds what they are
        yield f"{pad}remote {node.name} ({node.remote.system} of the manager at {node.remote.manager or '/'}, {where})"
        yield f"{pad}  modes: " + ", ".join(("*" if mode == node.default_mode else "") + mode for mode in node.modes)
        return
    yield f"{pad}node {node.name} ({where})"
    yield f"{pad}  modes:"
    for mode in node.modes.values():
        marker = "*" if mode.name == node.default_mode else " "
        yield f"{pad}    {marker} {mode.name}"
        for spec in mode.parameters.values():
            match = "" if spec.match == EXACT else f"  ~ {_match_text(spec.match)}"
            yield f"{pad}        {spec.name}: {format_value(spec.value)}{match}"
    if node.rules:
        yield f"{pad}  rules:"
        for rule in node.rules:
            yield f"{pad}    {_rule_text(rule)}"


def _entry_text(entry: PartEntry) -> str:
    return "(keep)" if entry.target is None else str(entry.target)


def _rule_text(rule: Rule) -> str:
    return (f"{rule.name}: if target {rule.if_target} and {rule.if_part} is {rule.if_part_state} "
            f"-> {rule.new_target}")


def _match_text(match: Match) -> str:
    pieces = []
    if match.tolerance is not None:
        pieces.append(f"tolerance {format_value(match.tolerance)}")
    if match.minimum is not None or match.maximum is not None:
        low = "-inf" if match.minimum is None else format_value(match.minimum)
        high = "inf" if match.maximum is None else format_value(match.maximum)
        pieces.append(f"[{low}, {high}]")
    return ", ".join(pieces)


def format_value(value: ParamValue) -> str:
    """A parameter value as it would be written in a model file, typed unambiguously: strings
    quoted, booleans ``true``/``false``, doubles with a decimal point or exponent."""
    if isinstance(value, tuple):
        return "[" + ", ".join(format_value(item) for item in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return repr(value)
