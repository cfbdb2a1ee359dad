"""First pass: find the parts of a model file and read their top-level keys.

Every later check needs to know, for any part name, whether it exists, what kind it is, its
modes and its default mode; :class:`PartDecl` holds exactly that, plus the raw sub-trees that
the node, system and rule builders read.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from sm_bt.model.diagnostics import Diagnostics, did_you_mean, quoted_list
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, describe
from sm_bt.model.types import DEFAULT_MODE, DONT_CARE, PartKind

PARAMS_KEY = "ros__parameters"
_KNOWN_KEYS = ("type", "parts", "modes", "rules", "defaultmode", "match", "manager", "system")
#: The keys that only a remote part has (sm_bt.model.remote_parts).
REMOTE_KEYS = ("manager", "system", "served_by")
#: The type that makes a part remote: served by another manager, a node to this one.
REMOTE_TYPE = "remote"
# rmw_validate_node_name / rmw_validate_namespace: letters, digits, underscores; no leading digit.
_NAME_SEGMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


@dataclass
class PartDecl:
    """What the first pass learnt about one part (``kind``/``default_mode`` are None if invalid)."""

    name: str
    line: int
    params: YMap
    kind: PartKind | None = None
    modes: YMap | None = None
    modes_line: int = 0
    default_mode: str | None = None
    parts: tuple[YScalar, ...] | None = None
    parts_line: int = 0
    rules: YNode | None = None
    match: YNode | None = None
    remote: bool = False  # type: remote (its kind is NODE)

    @property
    def mode_names(self) -> tuple[str, ...]:
        return self.modes.keys if self.modes is not None else ()

    def outline(self) -> PartDecl:
        """This declaration without the text below its modes' names: what checks of other parts
        read (kind, default mode, mode names). Once its part is built, the outline is all that is
        kept, so that a big file's text tree is let go part by part."""
        modes = None if self.modes is None else YMap(tuple((key, key) for key, _ in self.modes), self.modes.line)
        return dataclasses.replace(self, params=YMap((), self.params.line), modes=modes, match=None)

    def resolve_mode(self, name: str) -> str | None:
        """The mode ``name`` refers to: itself, or the default for ``__DEFAULT__``; None if unknown."""
        if name in self.mode_names:
            return name
        if name == DEFAULT_MODE:
            return self.default_mode
        return None


def read_declarations(doc: YMap, diag: Diagnostics) -> dict[str, PartDecl]:
    """Every part of the file, in file order, with its keys checked."""
    decls: dict[str, PartDecl] = {}
    for key, value in doc:
        _collect(key, value, (), decls, diag)
    for decl in decls.values():
        _read_keys(decl, diag)
    return decls


def _collect(key: YScalar, value: YNode, namespace: tuple[str, ...], decls: dict[str, PartDecl],
             diag: Diagnostics) -> None:
    """Walk namespace keys down to ``ros__parameters`` (``foo: {B: ...}`` is the part ``foo/B``)."""
    path = (*namespace, key.text)
    if key.text == PARAMS_KEY:
        diag.error(key.line, f"'{PARAMS_KEY}' needs a part name above it: write 'NAME:' / "
                             f"'  {PARAMS_KEY}:'")
        return
    if not isinstance(value, YMap):
        diag.error(key.line, f"{'/'.join(path)!r} has {describe(value)} where a map with "
                             f"'{PARAMS_KEY}:' is needed: this is a ROS 2 parameter file, write "
                             f"'{key.text}:' / '  {PARAMS_KEY}:' / '    type: ...'")
        return
    params = value.get(PARAMS_KEY)
    nested = [(k, v) for k, v in value if k.text != PARAMS_KEY]
    if params is None and (not nested or not all(isinstance(v, YMap) for _, v in nested)):
        diag.error(key.line, f"{'/'.join(path)!r} has no '{PARAMS_KEY}:' map: put the part's keys "
                             f"(type, modes, ...) under '{PARAMS_KEY}:'")
        return
    if params is not None:
        _add_part(key, params[1], path, decls, diag)
    for child_key, child_value in nested:
        if isinstance(child_value, YMap):
            _collect(child_key, child_value, path, decls, diag)
        else:
            diag.error(child_key.line, f"{child_key.text!r} is beside '{PARAMS_KEY}' of {'/'.join(path)!r}: "
                                       f"move it under '{PARAMS_KEY}:'")


def _add_part(key: YScalar, params: YNode, path: tuple[str, ...], decls: dict[str, PartDecl],
              diag: Diagnostics) -> None:
    segments = [segment for piece in path for segment in piece.split("/")]
    if segments and segments[0] == "":
        segments = segments[1:]  # a leading '/' is the root namespace, as in rcl
    name = "/".join(segments)
    bad = [s for s in segments if not _NAME_SEGMENT.fullmatch(s)]
    if not segments or bad:
        diag.error(key.line, f"part name {name!r} is not a valid ROS 2 node name: use letters, digits "
                             "and underscores (not starting with a digit), namespaces separated by '/'")
        return
    if name in decls:
        diag.error(key.line, f"part {name!r} is defined twice (first at line {decls[name].line}): "
                             "merge the two definitions")
        return
    if not isinstance(params, YMap):
        diag.error(key.line, f"'{PARAMS_KEY}' of part {name!r} must be a map of keys (type, modes, ...)")
        return
    decls[name] = PartDecl(name, key.line, params)


def _read_keys(decl: PartDecl, diag: Diagnostics) -> None:
    for key, _ in decl.params:
        if key.text not in _KNOWN_KEYS:
            diag.warning(key.line, f"part {decl.name!r}: unknown key {key.text!r} is ignored"
                                   f"{did_you_mean(key.text, _KNOWN_KEYS)} (known keys: {', '.join(_KNOWN_KEYS)})")
    decl.kind = _read_kind(decl, diag)
    decl.modes = _read_modes(decl, diag)
    decl.default_mode = _read_default(decl, diag)
    parts = decl.params.get("parts")
    if parts is not None:
        decl.parts_line = parts[0].line
        decl.parts = _read_parts_list(decl, parts[1], diag)
    rules = decl.params.get("rules")
    decl.rules = rules[1] if rules else None
    match = decl.params.get("match")
    decl.match = match[1] if match else None
    if decl.remote:
        for entry in (parts, match, rules):
            if entry is not None:
                diag.error(entry[0].line, f"remote part {decl.name!r} cannot have {entry[0].text!r}: its manager "
                                          "holds its parts, parameters and rules; remove it")
    elif decl.kind is not None:
        for name in REMOTE_KEYS:
            if (entry := decl.params.get(name)) is not None:
                diag.error(entry[0].line, f"part {decl.name!r}: {name!r} is for a part another manager serves: "
                                          f"remove it, or write 'type: {REMOTE_TYPE}'")
    if decl.kind is PartKind.NODE and not decl.remote and parts is not None:
        diag.error(parts[0].line, f"node {decl.name!r} cannot have 'parts': remove it, or write "
                                  "'type: system' if this is a system")
    if decl.kind is PartKind.SYSTEM and match is not None:
        diag.error(match[0].line, f"system {decl.name!r} cannot have 'match' (it is for node "
                                  "parameters): move it to the node")


def _read_kind(decl: PartDecl, diag: Diagnostics) -> PartKind | None:
    entry = decl.params.get("type")
    if entry is None:
        diag.error(decl.line, f"part {decl.name!r} has no 'type': add 'type: node' or 'type: system'")
        return None
    key, value = entry
    text = value.text if isinstance(value, YScalar) else describe(value)
    for kind in PartKind:
        if text == kind.value:
            return kind
    if text == REMOTE_TYPE:
        decl.remote = True
        return PartKind.NODE
    hint = f"write {text.lower()!r} (lower-case)" if text.lower() in ("node", "system", REMOTE_TYPE) else (
        "write 'node', 'system' or 'remote'")
    diag.error(key.line, f"part {decl.name!r}: type {text!r} is not 'node', 'system' or 'remote': {hint}")
    return None


def _read_modes(decl: PartDecl, diag: Diagnostics) -> YMap | None:
    entry = decl.params.get("modes")
    if entry is None:
        diag.error(decl.line, f"part {decl.name!r} has no 'modes': add a 'modes:' map with a "
                              f"{DEFAULT_MODE} mode")
        return None
    key, modes = entry
    decl.modes_line = key.line
    if decl.remote:
        modes = _mode_list(decl, modes, diag)
    if not isinstance(modes, YMap):
        diag.error(key.line, f"'modes' of part {decl.name!r} must be a map of mode names, not "
                             f"{describe(modes)}")
        return None
    for mode_key, _ in modes:
        if "." in mode_key.text:
            diag.error(mode_key.line, f"mode name {mode_key.text!r} of part {decl.name!r} contains '.': "
                                      "mode names may not contain dots, rename it")
        if mode_key.text == DONT_CARE:
            diag.error(mode_key.line, f"{DONT_CARE} is reserved (it means 'leave the part as it is'): "
                                      "rename the mode")
    return modes


def _mode_list(decl: PartDecl, value: YNode, diag: Diagnostics) -> YMap:
    """A remote part's modes, as its manager names them: a YAML list (or names on lines, as
    ``parts:``), made the map of names the other parts have (empty where a node has parameters)."""
    if isinstance(value, YScalar):
        words = value.text.split()
        lines = value.word_lines if len(value.word_lines) == len(words) else (value.line,) * len(words)
        names = [YScalar(word, word, line) for word, line in zip(words, lines, strict=True)]
    elif isinstance(value, YSeq):
        names = list(value.items)
    else:
        diag.error(value.line, f"'modes' of remote part {decl.name!r} lists the names of its modes, as its "
                               f"manager names them (e.g. [{DEFAULT_MODE}, DEGRADED]), not a map")
        return YMap((), value.line)
    entries: dict[str, tuple[YScalar, YNode]] = {}
    for name in names:
        if name.text in entries:
            diag.error(name.line, f"mode {name.text!r} of remote part {decl.name!r} is listed twice (first at "
                                  f"line {entries[name.text][0].line}): remove one")
        else:
            entries[name.text] = (name, YMap((), name.line))
    return YMap(tuple(entries.values()), value.line)


def _read_default(decl: PartDecl, diag: Diagnostics) -> str | None:
    entry = decl.params.get("defaultmode")
    if entry is not None:
        key, value = entry
        if not isinstance(value, YScalar):
            diag.error(key.line, f"'defaultmode' of part {decl.name!r} must be a mode name, not "
                                 f"{describe(value)}")
            return None
        if decl.modes is not None and value.text not in decl.mode_names:
            diag.error(value.line, f"defaultmode {value.text!r} of part {decl.name!r} is not one of its "
                                   f"modes{did_you_mean(value.text, decl.mode_names)}: use one of "
                                   f"{quoted_list(decl.mode_names)}")
            return None
        return value.text if decl.modes is not None else None
    if decl.modes is None:
        return None
    if DEFAULT_MODE in decl.mode_names:
        return DEFAULT_MODE
    diag.error(decl.modes_line, f"part {decl.name!r} has no default mode: add a {DEFAULT_MODE} mode or a "
               "'defaultmode: NAME' key")
    return None


def _read_parts_list(decl: PartDecl, value: YNode, diag: Diagnostics) -> tuple[YScalar, ...]:
    # A multi-line plain scalar folds to "a b c"; a YAML list is accepted too.
    if isinstance(value, YScalar):
        words = value.text.split()
        lines = value.word_lines if len(value.word_lines) == len(words) else (value.line,) * len(words)
        return tuple(YScalar(part_ref(word), word, line) for word, line in zip(words, lines, strict=True))
    if isinstance(value, YSeq):
        return tuple(YScalar(part_ref(item.text), item.value, item.line) for item in value.items)
    diag.error(value.line, f"'parts' of system {decl.name!r} must list part names (one per line, or "
                           "a YAML list), not a map")
    return ()


def part_ref(text: str) -> str:
    """A part name as written in a system (a leading '/' is the root namespace, as at the top level)."""
    return text[1:] if text.startswith("/") else text
