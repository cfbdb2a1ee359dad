"""The ``match:`` extension: how a node's observed parameter values are recognised as a mode.

The reference compares doubles with ``==``, so a controller that rounds a value is never seen in
its mode. A ``match:`` map loosens that per parameter::

    match:
      max_speed: {tolerance: 0.05}    # |observed - value| <= 0.05
      FollowPath:                     # nested maps give dotted names, as in ros__parameters
        max_vel_x: [0.0, 0.2]         # closed range [min, max]
      gain: {min: 1.0, max: 2.0}      # same, spelt out; either bound may be left out

A map whose keys are all among ``tolerance``/``min``/``max`` is a spec; any other map is a
namespace. Only numeric parameters can have a spec.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from sm_bt.model.diagnostics import Diagnostics, did_you_mean
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, describe
from sm_bt.model.types import Match, ParamSpec, ParamValue, exact_match

_SPEC_KEYS = frozenset({"tolerance", "min", "max"})
_FORMS = "write {tolerance: EPS}, [MIN, MAX] or {min: A, max: B}"


@dataclass(frozen=True)
class MatchEntry:
    """One parameter's spec as written, with its line (for later checks against values)."""

    name: str
    match: Match
    line: int


def read_match_map(node: YNode, where: str, diag: Diagnostics) -> dict[str, MatchEntry]:
    """The specs of a ``match:`` map, by dotted parameter name; bad ones are reported and left out."""
    entries: dict[str, MatchEntry] = {}
    if not isinstance(node, YMap):
        diag.error(node.line, f"{where}: 'match' must be a map of parameter names, not {describe(node)}")
        return entries
    _walk(node, "", where, entries, diag)
    return entries


def _walk(node: YMap, prefix: str, where: str, entries: dict[str, MatchEntry], diag: Diagnostics) -> None:
    for key, value in node:
        name = prefix + key.text
        if isinstance(value, YMap) and value.keys and not set(value.keys) <= _SPEC_KEYS:
            _walk(value, name + ".", where, entries, diag)
            continue
        match = _read_spec(name, key, value, where, diag)
        if match is None:
            continue
        if name in entries:
            diag.error(key.line, f"{where}: match for {name!r} is given twice (first at line "
                                 f"{entries[name].line}): remove one")
            continue
        entries[name] = MatchEntry(name, match, key.line)


def _read_spec(name: str, key: YScalar, value: YNode, where: str, diag: Diagnostics) -> Match | None:
    if isinstance(value, YSeq):
        numbers = [_number(item) for item in value.items]
        if len(numbers) != 2 or any(n is None for n in numbers):
            diag.error(key.line, f"{where}: match range of {name!r} must be two numbers [MIN, MAX]")
            return None
        return _checked(name, key.line, where, diag, minimum=numbers[0], maximum=numbers[1])
    if isinstance(value, YMap):
        fields: dict[str, float] = {}
        for field_key, field_value in value:
            number = _number(field_value)
            if number is None:
                diag.error(field_key.line, f"{where}: {field_key.text!r} of match {name!r} must be a "
                                           f"number, not {describe(field_value)}")
                return None
            fields[field_key.text] = number
        if not fields:
            diag.error(key.line, f"{where}: match for {name!r} is empty: {_FORMS}")
            return None
        return _checked(name, key.line, where, diag, tolerance=fields.get("tolerance"),
                        minimum=fields.get("min"), maximum=fields.get("max"))
    diag.error(key.line, f"{where}: match for {name!r} is {describe(value)}: {_FORMS}")
    return None


def _number(node: YNode) -> float | None:
    if not isinstance(node, YScalar) or isinstance(node.value, (bool, str)):
        return None
    return float(node.value) if not math.isnan(node.value) else None


def _checked(name: str, line: int, where: str, diag: Diagnostics, *, tolerance: float | None = None,
             minimum: float | None = None, maximum: float | None = None) -> Match | None:
    if tolerance is not None and (tolerance < 0 or math.isinf(tolerance)):
        diag.error(line, f"{where}: tolerance of {name!r} is {tolerance}: write a finite number >= 0")
        return None
    if minimum is not None and maximum is not None and minimum > maximum:
        diag.error(line, f"{where}: match range of {name!r} has min {minimum} > max {maximum}: swap them")
        return None
    return Match(tolerance=tolerance, minimum=minimum, maximum=maximum)


def check_parameters(entries: Mapping[str, MatchEntry], defaults: Mapping[str, ParamValue], where: str,
                     diag: Diagnostics) -> dict[str, MatchEntry]:
    """Keep the specs that name a numeric parameter of the node; report the others."""
    valid: dict[str, MatchEntry] = {}
    for name, entry in entries.items():
        if name not in defaults:
            diag.error(entry.line, f"{where}: match names {name!r}, which is not a parameter of the "
                                   f"default mode{did_you_mean(name, defaults)}: fix the name or remove it")
        elif isinstance(defaults[name], (bool, str, tuple)):
            diag.error(entry.line, f"{where}: match for {name!r} needs a numeric parameter, but it is "
                                   f"{defaults[name]!r}: remove the match (other types compare exactly)")
        else:
            valid[name] = entry
    return valid


def value_outside(match: Match, value: ParamValue) -> bool:
    """True when a mode's own value would not be recognised by its range."""
    if isinstance(value, (bool, str, tuple)):
        return False
    number = float(value)
    return math.isnan(number) or (match.minimum is not None and number < match.minimum) or (
        match.maximum is not None and number > match.maximum)


def may_both_match(first: ParamSpec, second: ParamSpec) -> bool:
    """True when some observed value would match both specs (inference could not tell them apart)."""
    first_range, second_range = _accepted_range(first), _accepted_range(second)
    if first_range is None and second_range is None:
        return exact_match(first.value, second.value)
    if first_range is None:
        return second.matches(first.value)
    if second_range is None:
        return first.matches(second.value)
    return max(first_range[0], second_range[0]) <= min(first_range[1], second_range[1])


def compared_exactly(spec: ParamSpec) -> bool:
    """True when ``spec`` accepts its own value only (no tolerance, minimum or maximum)."""
    return _accepted_range(spec) is None


def _accepted_range(spec: ParamSpec) -> tuple[float, float] | None:
    """The closed interval a numeric spec accepts, or ``None`` for an exact comparison."""
    match = spec.match
    if match.tolerance is None and match.minimum is None and match.maximum is None:
        return None
    low, high = -math.inf, math.inf
    if match.tolerance is not None and not isinstance(spec.value, (bool, str, tuple)):
        low, high = float(spec.value) - match.tolerance, float(spec.value) + match.tolerance
    if match.minimum is not None:
        low = max(low, match.minimum)
    if match.maximum is not None:
        high = min(high, match.maximum)
    return low, high
