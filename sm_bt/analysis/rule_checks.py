"""Rules, read from the model: rules that send a system round in a circle on one lasting
fault (a ping-pong), and rules that a mode change of their own system sets off half way (the
pattern of system_modes #94).

A circle: rule r1 takes the system from A to B when part p is in X, and a rule of B takes it on
(and back to A) when the same p is in X: a fault that keeps p there switches the system back and
forth until recovery's budget is used. Half way: a rule of mode B fires when p is in X, and X is
what another mode A of the system asks of p; a request from A to B passes through "target B, p
still X", where the reference's manager fires the rule and undoes the request (sm_bt fires no rule
while a request works on the part, but the model says something it does not mean)."""

from __future__ import annotations

from sm_bt.analysis.findings import Finding, Kind, Level
from sm_bt.model.states import StateMode
from sm_bt.model.types import Model, Rule, SystemPart


def rule_findings(model: Model) -> list[Finding]:
    findings: list[Finding] = []
    for part in model.parts.values():
        if not isinstance(part, SystemPart):
            continue
        rules = list(part.rules)
        for index, rule in enumerate(rules):
            first = next((r for r in rules[:index] if (r.if_target, r.if_part, r.if_part_state) ==
                          (rule.if_target, rule.if_part, rule.if_part_state)), None)
            if first is not None and first.new_target != rule.new_target:
                findings.append(Finding(
                    Kind.RULE_SHADOWED, Level.WARNING, rule.location,
                    f"rule {rule.name} of {rule.system} never fires: {first.name} has the same condition "
                    f"({rule.if_part} {rule.if_part_state} while {rule.if_target}) and comes first (rules are tried "
                    f"in order of name), sending {rule.system} to {first.new_target} instead of {rule.new_target}"))
            circle = _circle(rule, rules)
            if circle is not None and circle[0] is min(circle, key=lambda r: r.name):  # each circle once
                findings.append(Finding(
                    Kind.RULE_PING_PONG, Level.ERROR, rule.location,
                    f"rules {', '.join(r.name for r in circle)} of {rule.system} go round in a circle while "
                    f"{rule.if_part} stays {rule.if_part_state}: a lasting fault switches {rule.system} back and "
                    "forth until recovery's budget is used",
                    " -> ".join([str(circle[0].if_target), *(str(r.new_target) for r in circle)])))
            for mode in part.modes.values():
                entry = mode.entries.get(rule.if_part)
                if (entry is not None and entry.target == rule.if_part_state and f"active.{mode.name}" != str(
                        rule.if_target) and _entry(part, rule) != rule.if_part_state):
                    findings.append(Finding(
                        Kind.RULE_UNDOES_REQUEST, Level.WARNING, rule.location,
                        f"rule {rule.name} of {rule.system} fires when {rule.if_part} is {rule.if_part_state} while "
                        f"{rule.system} should be {rule.if_target}, which is what mode {mode.name} asks of "
                        f"{rule.if_part}: a change from {mode.name} to {rule.if_target} passes through that, and the "
                        "reference's manager undoes it (system_modes #94; sm_bt fires no rule while a request works "
                        "on the part)",
                        f"change_mode {rule.system} {rule.if_target.mode or rule.if_target}"))
                    break
    return findings


def _entry(part: SystemPart, rule: Rule) -> StateMode | None:
    """What the rule's ``if_target`` asks of its ``if_part``."""
    mode = part.modes.get(rule.if_target.mode) if rule.if_target.mode else None
    entry = mode.entries.get(rule.if_part) if mode is not None else None
    return entry.target if entry is not None else None


def _circle(start: Rule, rules: list[Rule]) -> list[Rule] | None:
    """The rules from ``start`` back to its ``if_target``, each watching the same part in the same
    state (``None``: no circle)."""
    path = [start]
    while len(path) <= len(rules):
        here = path[-1].new_target
        if here == start.if_target:
            return path
        following = [r for r in rules if r.if_target == here and r.if_part == start.if_part
                     and r.if_part_state == start.if_part_state and r not in path]
        if not following:
            return None
        path.append(following[0])
    return None
