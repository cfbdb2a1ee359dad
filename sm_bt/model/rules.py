"""Parse a part's ``rules:`` map into resolved :class:`Rule` objects, sorted by rule name.

The reference evaluates a part's rules in alphabetical order of name (they live in a
``std::map``), so the order is kept. Every key is required and checked here; the reference
silently lets a rule without ``if_target`` never fire.
"""

from __future__ import annotations

from collections.abc import Mapping

from sm_bt.model.declarations import PartDecl, part_ref
from sm_bt.model.diagnostics import Diagnostics, did_you_mean, quoted_list
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, describe
from sm_bt.model.states import StateMode
from sm_bt.model.targets import parse_state_mode
from sm_bt.model.types import Location, Rule

_KEYS = ("if_target", "if_part", "new_target")


def build_rules(decl: PartDecl, decls: Mapping[str, PartDecl], below: tuple[str, ...],
                diag: Diagnostics) -> tuple[Rule, ...]:
    """The rules written under ``decl``; ``below`` lists the parts an ``if_part`` may name."""
    if decl.rules is None:
        return ()
    if not isinstance(decl.rules, YMap):
        diag.error(decl.rules.line, f"'rules' of part {decl.name!r} must be a map of named rules, not "
                                    f"{describe(decl.rules)}")
        return ()
    rules: list[Rule] = []
    for key, value in decl.rules:
        rule = _build_rule(decl, key, value, decls, below, diag)
        if rule is not None:
            rules.append(rule)
    return tuple(sorted(rules, key=lambda rule: rule.name))


def _build_rule(decl: PartDecl, key: YScalar, value: YNode, decls: Mapping[str, PartDecl],
                below: tuple[str, ...], diag: Diagnostics) -> Rule | None:
    where = f"part {decl.name!r}, rule {key.text!r}"
    if "." in key.text:
        diag.error(key.line, f"{where}: rule names may not contain '.': rename it")
        return None
    if not isinstance(value, YMap):
        diag.error(key.line, f"{where}: a rule is a map with {', '.join(_KEYS)}")
        return None
    for extra_key, _ in value:
        if extra_key.text not in _KEYS:
            diag.error(extra_key.line, f"{where}: unknown key {extra_key.text!r}"
                                       f"{did_you_mean(extra_key.text, _KEYS)}: a rule has only "
                                       f"{', '.join(_KEYS)}")
    missing = [k for k in _KEYS if value.get(k) is None]
    if missing:
        diag.error(key.line, f"{where}: missing {' and '.join(repr(k) for k in missing)}: a rule needs "
                             f"if_target, if_part and new_target")
    if_target = _own_state(decl, value, "if_target", where, diag)
    new_target = _own_state(decl, value, "new_target", where, diag)
    condition = _if_part(decl, value, decls, below, where, diag)
    if missing or if_target is None or new_target is None or condition is None:
        return None
    return Rule(key.text, decl.name, if_target, condition[0], condition[1], new_target,
                Location(diag.file, key.line))


def _own_state(decl: PartDecl, rule: YMap, name: str, where: str, diag: Diagnostics) -> StateMode | None:
    entry = rule.get(name)
    if entry is None:
        return None
    key, value = entry
    if not isinstance(value, YScalar):
        diag.error(key.line, f"{where}: {name} must be 'state[.MODE]', not {describe(value)}")
        return None
    return parse_state_mode(value.text, decl, key.line, f"{where}, {name}", diag)


def _if_part(decl: PartDecl, rule: YMap, decls: Mapping[str, PartDecl], below: tuple[str, ...],
             where: str, diag: Diagnostics) -> tuple[str, StateMode] | None:
    entry = rule.get("if_part")
    if entry is None:
        return None
    key, value = entry
    if not isinstance(value, YSeq) or len(value.items) != 2 or not all(
            isinstance(item.value, str) for item in value.items):
        diag.error(key.line, f"{where}: if_part must be a list of two strings, [PART, 'state[.MODE]'], "
                             f"e.g. if_part: [{below[0] if below else 'part'}, inactive]")
        return None
    part_item, state = value.items
    part = YScalar(part_ref(part_item.text), part_item.value, part_item.line)
    if part.text not in below:
        scope = f"{decl.name!r} itself" if below == (decl.name,) else f"the parts of {decl.name!r}"
        diag.error(key.line, f"{where}: if_part names {part.text!r}, which is not one of {scope}"
                             f"{did_you_mean(part.text, below)}: use one of {quoted_list(below)}")
        return None
    resolved = parse_state_mode(state.text, decls[part.text], key.line, f"{where}, if_part", diag,
                                target=False)
    return (part.text, resolved) if resolved is not None else None
