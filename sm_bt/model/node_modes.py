"""Build a node part: its modes as complete parameter sets, with their match specs.

As in the reference, a non-default mode is a delta over the default mode: parameters it does not
list keep the default value, and it may not introduce a parameter the default lacks. Beyond the
reference, a value whose type differs from the default's is refused (a typed ROS 2 node rejects
such a set), and two modes that inference could not tell apart get a warning.
"""

from __future__ import annotations

from dataclasses import dataclass

from sm_bt.model.declarations import PARAMS_KEY, PartDecl
from sm_bt.model.diagnostics import Diagnostics
from sm_bt.model.match_specs import (
    MatchEntry,
    check_parameters,
    compared_exactly,
    may_both_match,
    read_match_map,
    value_outside,
)
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, describe, same_type, type_name
from sm_bt.model.remote_parts import build_remote
from sm_bt.model.types import EXACT, Location, NodeMode, NodePart, ParamSpec, ParamValue


@dataclass(frozen=True)
class _Param:
    name: str
    value: ParamValue
    line: int


@dataclass(frozen=True)
class _RawMode:
    name: str
    line: int
    params: dict[str, _Param]
    match: dict[str, MatchEntry]


def build_node(decl: PartDecl, diag: Diagnostics) -> NodePart | None:
    """The node part, or ``None`` when it cannot be built (the reasons are reported)."""
    if decl.remote:
        return build_remote(decl, diag)
    if decl.modes is None:
        return None
    raw = [_read_mode(decl, key, value, diag) for key, value in decl.modes]
    raw_modes = {mode.name: mode for mode in raw if mode is not None}
    if decl.default_mode is None or decl.default_mode not in raw_modes:
        return None
    default = raw_modes[decl.default_mode]
    defaults = {name: p.value for name, p in default.params.items()}
    part_match: dict[str, MatchEntry] = {}
    if decl.match is not None:
        where = f"node {decl.name!r}"
        part_match = check_parameters(read_match_map(decl.match, where, diag), defaults, where, diag)
    modes: dict[str, NodeMode] = {}
    for mode in raw_modes.values():
        where = f"node {decl.name!r}, mode {mode.name!r}"
        own_match = check_parameters(mode.match, defaults, where, diag)
        _check_delta(mode, default, where, diag)
        specs: dict[str, ParamSpec] = {}
        for name, base in default.params.items():
            param = mode.params.get(name, base)
            if not same_type(param.value, base.value):
                param = base  # reported by _check_delta; keep the default so later checks still run
            entry = own_match.get(name) or part_match.get(name)
            if entry is not None and value_outside(entry.match, param.value):
                diag.error(entry.line, f"{where}: its value {name}={param.value!r} (line {param.line}) is "
                                       f"outside its match range {_range_text(entry)}: widen the range or "
                                       "fix the value")
            specs[name] = ParamSpec(name, param.value, Location(diag.file, param.line),
                                    entry.match if entry else EXACT)
        modes[mode.name] = NodeMode(mode.name, specs, Location(diag.file, mode.line))
    _warn_ambiguous(decl.name, modes, diag)
    return NodePart(decl.name, decl.default_mode, modes, (), Location(diag.file, decl.line))


def _range_text(entry: MatchEntry) -> str:
    low, high = entry.match.minimum, entry.match.maximum
    return f"[{'-inf' if low is None else low}, {'inf' if high is None else high}] (line {entry.line})"


def _read_mode(decl: PartDecl, key: YScalar, value: YNode, diag: Diagnostics) -> _RawMode | None:
    where = f"node {decl.name!r}, mode {key.text!r}"
    if not isinstance(value, YMap):
        diag.error(key.line, f"{where}: a node mode holds '{PARAMS_KEY}:' with parameter values, not "
                             f"{describe(value)}: write '{key.text}:' / '  {PARAMS_KEY}:' / '    param: value'")
        return None
    params: dict[str, _Param] | None = None
    match: dict[str, MatchEntry] = {}
    for entry_key, entry_value in value:
        if entry_key.text == PARAMS_KEY:
            if isinstance(entry_value, YMap):
                params = {}
                _flatten(entry_value, "", params, where, diag)
            else:
                diag.error(entry_key.line, f"{where}: '{PARAMS_KEY}' must be a map of parameter values, "
                                           f"not {describe(entry_value)}")
        elif entry_key.text == "match":
            match = read_match_map(entry_value, where, diag)
        else:
            diag.error(entry_key.line, f"{where}: {entry_key.text!r} does not belong in a node mode, which "
                                       f"holds '{PARAMS_KEY}:' (and optionally 'match:'): put parameters "
                                       f"under '{PARAMS_KEY}:', or write 'type: system' if "
                                       f"{decl.name!r} is a system with parts")
    if params is None:
        if not any(k.text == PARAMS_KEY for k, _ in value):
            diag.error(key.line, f"{where}: no '{PARAMS_KEY}:' map: add one with the mode's parameter values")
        return None
    return _RawMode(key.text, key.line, params, match)


def _flatten(node: YMap, prefix: str, out: dict[str, _Param], where: str, diag: Diagnostics) -> None:
    """Nested maps give dotted names (``ns: {sub: 1}`` is ``ns.sub``), as rcl does."""
    for key, value in node:
        name = prefix + key.text
        if isinstance(value, YMap):
            _flatten(value, name + ".", out, where, diag)
            continue
        if name in out:
            diag.error(key.line, f"{where}: parameter {name!r} is set twice (first at line "
                                 f"{out[name].line}): remove one")
            continue
        if isinstance(value, YSeq) and not value.items:
            continue  # its items were refused and reported
        out[name] = _Param(name, value.value, key.line)


def _check_delta(mode: _RawMode, default: _RawMode, where: str, diag: Diagnostics) -> None:
    for name, param in mode.params.items():
        base = default.params.get(name)
        if base is None:
            diag.error(param.line, f"{where}: parameter {name!r} is not in the default mode "
                                   f"{default.name!r}: add it to {default.name} or remove it")
        elif not same_type(param.value, base.value):
            diag.error(param.line, f"{where}: parameter {name!r} is {type_name(param.value)} "
                                   f"{param.value!r} but {type_name(base.value)} in the default mode "
                                   f"(line {base.line}), and a ROS 2 node refuses a change of type: "
                                   f"{_type_fix(param.value, base.value)}")


def _type_fix(value: ParamValue, wanted: ParamValue) -> str:
    want, got = type_name(wanted), type_name(value)
    if want == "double" and got == "integer":
        return f"write {value}.0"
    if want == "double[]" and got == "integer[]":
        return "write the items as doubles (e.g. 1.0 instead of 1)"
    if want == "string" and not isinstance(value, tuple):
        return "quote the value to make it a string"
    return f"write a {want} value"


def _warn_ambiguous(node: str, modes: dict[str, NodeMode], diag: Diagnostics) -> None:
    """Warn once per set of modes that inference cannot tell apart. Modes compared exactly are
    grouped by their values (linear in the number of modes); a mode with a match range is
    compared with each other mode (few modes have ranges)."""
    ordered = list(modes.values())
    exact = [all(compared_exactly(spec) for spec in mode.parameters.values()) for mode in ordered]
    groups: dict[tuple[tuple[str, str, ParamValue], ...], list[NodeMode]] = {}
    for mode, is_exact in zip(ordered, exact, strict=True):
        if is_exact:
            key = tuple(sorted((name, type(spec.value).__name__, spec.value) for name, spec in mode.parameters.items()))
            groups.setdefault(key, []).append(mode)
    for group in groups.values():
        if len(group) > 1:
            quoted = [repr(mode.name) for mode in group[:4]]
            names = (", ".join(quoted) + f" and {len(group) - 4} more" if len(group) > 4
                     else ", ".join(quoted[:-1]) + f" and {quoted[-1]}")
            diag.warning(group[1].location.line, f"node {node!r}: modes {names} have the same parameter values"
                                                 f"{_shown(group[1])}, so inference cannot tell them apart (the "
                                                 "target, then the default mode decides): change a value or a "
                                                 "match range if they must be told apart")
    for index, later in enumerate(ordered):
        for position, earlier in enumerate(ordered[:index]):
            if exact[index] and exact[position]:
                continue  # grouped above
            if all(may_both_match(spec, later.parameters[name]) for name, spec in earlier.parameters.items()):
                diag.warning(later.location.line, f"node {node!r}: modes {earlier.name!r} and {later.name!r} "
                                                  "accept overlapping values, so inference cannot tell them "
                                                  "apart (the target, then the default mode decides): change a "
                                                  "value or a match range if they must be told apart")


def _shown(mode: NodeMode) -> str:
    values = [f"{name}={spec.value!r}" for name, spec in mode.parameters.items()]
    return f" ({', '.join(values[:3])}{', ...' if len(values) > 3 else ''})" if values else ""
