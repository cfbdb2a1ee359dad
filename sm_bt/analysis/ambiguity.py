"""Inference: modes that the configuration of the parts cannot tell apart.

Node modes whose parameter values overlap are the loader's warnings already (``sm-bt check``);
they are reported here too, with the systems' modes that differ only in such node modes or in
don't-care entries. Which one inference reports: the target's mode first, then the default mode,
then the first by name; so with one of them as the target, the other's configuration reads as
it, and a change between them is never seen."""

from __future__ import annotations

import itertools

from sm_bt.analysis.findings import Finding, Kind, Level
from sm_bt.model.match_specs import may_both_match
from sm_bt.model.states import StateMode
from sm_bt.model.types import Model, NodePart, Severity, SystemMode, SystemPart


def ambiguity(model: Model) -> list[Finding]:
    findings = [Finding(Kind.AMBIGUOUS, Level.WARNING, issue.location, issue.message) for issue in model.warnings
                if issue.severity is Severity.WARNING and "tell them apart" in issue.message]
    for name, part in model.parts.items():
        if not isinstance(part, SystemPart):
            continue
        for first, second in itertools.combinations(part.modes.values(), 2):
            if _same_configuration(model, first, second):
                reported = sorted((first.name, second.name), key=lambda mode: (mode != part.default_mode, mode))[0]
                findings.append(Finding(
                    Kind.AMBIGUOUS, Level.WARNING, second.location,
                    f"modes {first.name} and {second.name} of {name} cannot be told apart by their parts' states "
                    f"and modes: with either as the target the other's configuration reads as it, and with none "
                    f"inference reports {reported}", _entries(second)))
    return findings


def _same_configuration(model: Model, first: SystemMode, second: SystemMode) -> bool:
    return all(_may_both(model, part, first.entries[part].target, second.entries[part].target)
               for part in first.entries)


def _may_both(model: Model, part: str, first: StateMode | None, second: StateMode | None) -> bool:
    """Could one configuration of ``part`` match both targets (``None``: don't care)?"""
    if first is None or second is None or first == second:
        return True
    if first.state is not second.state or first.mode is None or second.mode is None:
        return False
    found = model.parts[part]
    if isinstance(found, NodePart):
        one, other = found.modes[first.mode].parameters, found.modes[second.mode].parameters
        return all(may_both_match(spec, other[key]) for key, spec in one.items() if key in other)
    assert isinstance(found, SystemPart)
    return _same_configuration(model, found.modes[first.mode], found.modes[second.mode])


def _entries(mode: SystemMode) -> str:
    shown = [f"{part} {entry.target if entry.target is not None else '__DONTCARE__'}"
             for part, entry in mode.entries.items()]
    return ", ".join(shown[:6]) + (", ..." if len(shown) > 6 else "")
