"""Build a system part: its parts, and its modes with an entry for every part.

As in the reference, a non-default mode inherits the default mode's entry for each part it
omits. Unlike the reference, membership is checked: every part must be defined in the file and
appear in the default mode, and ``parts:`` (ignored by the reference) must agree with the modes.

Two extensions live here: a ``__DONTCARE__`` entry ("leave this part as it is", target ``None``)
and the ``__order__`` key giving the switching stages of a mode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sm_bt.model.declarations import PARAMS_KEY, PartDecl, part_ref
from sm_bt.model.diagnostics import Diagnostics, did_you_mean, quoted_list
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, describe
from sm_bt.model.states import StateMode
from sm_bt.model.targets import parse_state_mode
from sm_bt.model.types import DONT_CARE, Location, PartEntry, SystemMode, SystemPart

ORDER_KEY = "__order__"

Stages = tuple[tuple[str, ...], ...]


@dataclass(frozen=True)
class _RawEntry:
    target: StateMode | None
    line: int
    valid: bool  # False when the value was refused (the part still counts as listed)


@dataclass
class _RawMode:
    name: str
    line: int
    entries: dict[str, _RawEntry] = field(default_factory=dict)
    order: tuple[YScalar, YNode] | None = None


def build_system(decl: PartDecl, decls: dict[str, PartDecl], diag: Diagnostics, *,
                 strict: bool) -> SystemPart | None:
    """The system part, or ``None`` when it cannot be built (the reasons are reported)."""
    if decl.modes is None:
        return None
    raw = {key.text: _read_mode(decl, key, value, decls, diag, strict) for key, value in decl.modes}
    if decl.default_mode is None:
        return None
    default = raw[decl.default_mode]
    parts = _parts(decl, raw, default, decls, diag)
    if not parts:
        diag.error(default.line, f"system {decl.name!r} has no parts: list them in its default mode "
                                 f"{default.name!r} as 'part: state[.MODE]'")
        return None
    default_stages = _stages(default, decl.name, parts, diag)
    modes: dict[str, SystemMode] = {}
    for mode in raw.values():
        entries: dict[str, PartEntry] = {}
        for part in parts:
            own = mode.entries.get(part)
            if own is not None:
                if own.valid:
                    entries[part] = PartEntry(part, own.target, Location(diag.file, own.line))
                continue
            inherited = default.entries[part]
            if inherited.valid:
                entries[part] = PartEntry(part, inherited.target, Location(diag.file, inherited.line),
                                          inherited=True)
        stages = default_stages if mode.order is None else _stages(mode, decl.name, parts, diag)
        modes[mode.name] = SystemMode(mode.name, entries, stages, Location(diag.file, mode.line))
    return SystemPart(decl.name, decl.default_mode, modes, parts, (), Location(diag.file, decl.line))


def _read_mode(decl: PartDecl, key: YScalar, value: YNode, decls: dict[str, PartDecl],
               diag: Diagnostics, strict: bool) -> _RawMode:
    mode = _RawMode(key.text, key.line)
    where = f"system {decl.name!r}, mode {key.text!r}"
    if not isinstance(value, YMap):
        diag.error(key.line, f"{where}: a system mode maps each part to 'state[.MODE]', not "
                             f"{describe(value)}: write '{key.text}:' / '  PART: active'")
        return mode
    for part_key, part_value in value:
        name = part_ref(part_key.text)
        if name == ORDER_KEY:
            mode.order = (part_key, part_value)
            continue
        if name == PARAMS_KEY:
            diag.error(part_key.line, f"{where}: a system mode sets the states of parts, not parameters: "
                                      "write 'PART: state[.MODE]' entries, or 'type: node' if "
                                      f"{decl.name!r} is a node")
            continue
        if name not in decls:
            message = (f"{where}: part {name!r} is not defined in this file"
                       f"{did_you_mean(name, decls)}: fix the name or define the part at the top level")
            if strict:
                diag.error(part_key.line, message)
            else:
                diag.warning(part_key.line, message + " (entry ignored)")
            continue
        if not isinstance(part_value, YScalar):
            diag.error(part_key.line, f"{where}: the entry for {name!r} must be 'state[.MODE]' or "
                                      f"{DONT_CARE}, not {describe(part_value)}")
            mode.entries[name] = _RawEntry(None, part_key.line, valid=False)
            continue
        if part_value.text == DONT_CARE:
            mode.entries[name] = _RawEntry(None, part_key.line, valid=True)
            continue
        target = parse_state_mode(part_value.text, decls[name], part_key.line, f"{where}, part {name!r}", diag)
        mode.entries[name] = _RawEntry(target, part_key.line, valid=target is not None)
    return mode


def _parts(decl: PartDecl, raw: dict[str, _RawMode], default: _RawMode, decls: dict[str, PartDecl],
           diag: Diagnostics) -> tuple[str, ...]:
    """The system's parts: in ``parts:`` order if given, else as they first appear in the modes."""
    used: dict[str, tuple[str, int]] = {}  # part -> (first mode using it, line)
    for mode in [default, *(m for m in raw.values() if m is not default)]:
        for part, entry in mode.entries.items():
            used.setdefault(part, (mode.name, entry.line))
            if part not in default.entries:
                diag.error(entry.line, f"system {decl.name!r}, mode {mode.name!r}: part {part!r} is not in "
                                       f"the default mode {default.name!r}: add '{part}: STATE' to "
                                       f"{default.name!r} (every mode covers the same parts)")
    ordered = list(used)
    if decl.parts is not None:
        listed = _listed_parts(decl, decls, diag)
        for part, (mode_name, line) in used.items():
            if part not in listed:
                diag.error(line, f"system {decl.name!r}: part {part!r} (used in mode {mode_name!r}) is missing "
                                 f"from 'parts:' (line {decl.parts_line}): add it there")
        for part, line in listed.items():
            if part in decls and part not in used:
                diag.error(line, f"system {decl.name!r}: {part!r} is listed in 'parts:' but no mode sets it: "
                                 f"add '{part}: STATE' to the default mode {default.name!r} or remove it "
                                 "from 'parts:'")
        ordered = [p for p in listed if p in used] + [p for p in used if p not in listed]
    return tuple(p for p in ordered if p in default.entries)


def _listed_parts(decl: PartDecl, decls: dict[str, PartDecl], diag: Diagnostics) -> dict[str, int]:
    listed: dict[str, int] = {}
    for item in decl.parts or ():
        if item.text in listed:
            diag.error(item.line, f"system {decl.name!r}: {item.text!r} is listed twice in 'parts:': "
                                  "remove one")
        elif item.text not in decls:
            diag.error(item.line, f"system {decl.name!r}: 'parts:' names {item.text!r}, which is not "
                                  f"defined in this file{did_you_mean(item.text, decls)}: fix the name or "
                                  "define the part")
        listed.setdefault(item.text, item.line)
    return listed


def _stages(mode: _RawMode, system: str, parts: tuple[str, ...], diag: Diagnostics) -> Stages:
    """The switching stages of a mode; parts not named in ``__order__`` form one last stage."""
    if mode.order is None:
        return (parts,)
    key, value = mode.order
    where = f"system {system!r}, mode {mode.name!r}"
    if not isinstance(value, YSeq):
        diag.error(key.line, f"{where}: {ORDER_KEY} must be a list of stages, not {describe(value)}: "
                             f"write {ORDER_KEY}: [\"first_part\", \"second_part, third_part\"]")
        return (parts,)
    seen: dict[str, int] = {}
    stages: list[tuple[str, ...]] = []
    for item in value.items:
        stage: list[str] = []
        for name in (part_ref(piece.strip()) for piece in item.text.split(",")):
            if not name:
                diag.error(item.line, f"{where}: stage {item.text!r} of {ORDER_KEY} has an empty part name: "
                                      "remove the extra comma")
            elif name not in parts:
                diag.error(item.line, f"{where}: {ORDER_KEY} names {name!r}, which is not a part of "
                                      f"{system!r}{did_you_mean(name, parts)}: use one of {quoted_list(parts)}")
            elif name in seen:
                diag.error(item.line, f"{where}: {ORDER_KEY} lists {name!r} twice (first at line "
                                      f"{seen[name]}): keep it in one stage")
            else:
                seen[name] = item.line
                stage.append(name)
        if stage:
            stages.append(tuple(stage))
    rest = tuple(p for p in parts if p not in seen)
    if rest:
        stages.append(rest)
    return tuple(stages)
