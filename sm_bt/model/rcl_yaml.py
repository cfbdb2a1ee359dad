"""Read YAML the way ROS 2's parameter-file parser (``rcl_yaml_param_parser``) does.

An SMH model *is* a ROS 2 parameter file: the reference manager loads it with rcl, so a value
must get the type rcl gives it, not the one PyYAML would. PyYAML is used only to compose the
node tree (for line numbers); its own scalar typing is never applied. rcl types an unquoted
scalar by trying, in order: bool, int64 (C ``strtoll``, base 0), double (C ``strtod`` plus the
``.inf``/``.nan`` spellings), and falls back to string. Quoted scalars and ``!!str`` are strings.

rcl's refusals are reproduced as errors: anchors and aliases, empty unquoted values, arrays of
mixed types, arrays holding arrays or maps. Duplicate keys (which rcl silently overwrites) are
refused too, since one of the two values is always a mistake.
"""

from __future__ import annotations

import functools
import math
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import yaml
from yaml._yaml import CParser
from yaml._yaml import Mark as CMark

from sm_bt.model.diagnostics import Diagnostics
from sm_bt.model.types import ParamValue

#: A single typed value, as rcl produces it.
Scalar = bool | int | float | str

_TRUE = frozenset(("Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"))
_FALSE = frozenset(("N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"))
_SPECIAL_DOUBLES = {
    **{s: math.nan for s in (".nan", ".NaN", ".NAN")},
    **{s: math.inf for s in (".inf", ".Inf", ".INF", "+.inf", "+.Inf", "+.INF")},
    **{s: -math.inf for s in ("-.inf", "-.Inf", "-.INF")},
}
_INT64_MIN, _INT64_MAX = -(2**63), 2**63 - 1
# strtoll(base 0): optional whitespace and sign, then hex (0x..), octal (leading 0) or decimal.
_STRTOLL = re.compile(r"\s*([+-]?)(?:0[xX]([0-9a-fA-F]+)|(0[0-7]*)|([1-9][0-9]*))")
# strtod: decimal or hexadecimal floating point, inf/infinity, nan/nan(chars); case-insensitive.
_STRTOD_DECIMAL = re.compile(r"\s*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_STRTOD_HEX = re.compile(r"\s*([+-]?)0[xX]((?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][+-]?[0-9]+)?)")
_STRTOD_INF = re.compile(r"\s*([+-]?)(?:inf|infinity)", re.IGNORECASE)
_STRTOD_NAN = re.compile(r"\s*[+-]?nan(?:\([0-9A-Za-z_]*\))?", re.IGNORECASE)
_STR_TAG = "tag:yaml.org,2002:str"
_INTERNED_LENGTH = 64


def rcl_scalar(text: str, *, quoted: bool = False) -> Scalar:
    """The value rcl reads from a scalar (``quoted`` for single- or double-quoted ones)."""
    if quoted:
        return text
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    as_int = _strtoll(text)
    if as_int is not None:
        return as_int
    as_double = _strtod(text)
    if as_double is not None:
        return as_double
    return text


def _strtoll(text: str) -> int | None:
    match = _STRTOLL.fullmatch(text)
    if match is None:
        return None
    sign, hex_digits, octal_digits, decimal_digits = match.groups()
    if hex_digits is not None:
        value = int(hex_digits, 16)
    elif octal_digits is not None:
        value = int(octal_digits, 8)
    else:
        value = int(decimal_digits, 10)
    value = -value if sign == "-" else value
    # Out of range sets ERANGE: rcl then tries the value as a double.
    return value if _INT64_MIN <= value <= _INT64_MAX else None


def _strtod(text: str) -> float | None:
    if text in _SPECIAL_DOUBLES:
        return _SPECIAL_DOUBLES[text]
    if _STRTOD_NAN.fullmatch(text):
        return math.nan
    inf = _STRTOD_INF.fullmatch(text)
    if inf:
        return -math.inf if inf.group(1) == "-" else math.inf
    hex_match = _STRTOD_HEX.fullmatch(text)
    if hex_match:
        mantissa = hex_match.group(2)
        if "p" not in mantissa.lower():
            mantissa += "p0"
        try:
            value = float.fromhex(hex_match.group(1) + "0x" + mantissa)
        except OverflowError:
            return None
        return value
    if _STRTOD_DECIMAL.fullmatch(text):
        value = float(text)
        # ERANGE (overflow, or underflow of a non-zero number): rcl keeps the text as a string.
        if math.isinf(value) or (0.0 < abs(value) < 2.2250738585072014e-308):
            return None
        if value == 0.0 and re.search(r"[1-9]", text.split("e")[0].split("E")[0]):
            return None
        return value
    return None


def type_name(value: ParamValue) -> str:
    """The ROS 2 parameter type of a value: ``bool``, ``integer``, ``double``, ``string`` or ``…[]``."""
    if isinstance(value, tuple):
        return f"{type_name(value[0])}[]" if value else "array"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "double"
    return "string"


def same_type(a: ParamValue, b: ParamValue) -> bool:
    """``type_name(a) == type_name(b)``, without building the names for scalars (a model file
    compares every parameter of every mode with its default)."""
    if type(a) is not type(b):
        return False
    return not isinstance(a, tuple) or type_name(a) == type_name(b)


class YScalar(NamedTuple):
    """A scalar: its text as written (after YAML folding), its rcl-typed value and its line.

    A named tuple, not a frozen dataclass: a model file has one per value and key, and a tuple is
    built several times faster."""

    text: str
    value: Scalar
    line: int
    #: For a plain scalar spread over several lines (``parts:``), the line of each word.
    word_lines: tuple[int, ...] = ()


@dataclass(frozen=True)
class YSeq:
    """A sequence of scalars (an rcl array)."""

    items: tuple[YScalar, ...]
    line: int

    @property
    def value(self) -> ParamValue:
        return tuple(item.value for item in self.items)  # type: ignore[return-value]


@dataclass(frozen=True)
class YMap:
    """A mapping with unique keys, in file order."""

    entries: tuple[tuple[YScalar, YNode], ...]
    line: int

    def __iter__(self) -> Iterator[tuple[YScalar, YNode]]:
        return iter(self.entries)

    def get(self, key: str) -> tuple[YScalar, YNode] | None:
        for entry in self.entries:
            if entry[0].text == key:
                return entry
        return None

    @functools.cached_property
    def keys(self) -> tuple[str, ...]:
        # Cached: a part's modes are looked up by name for every system mode that names the part.
        return tuple(key.text for key, _ in self.entries)


YNode = YScalar | YSeq | YMap


def describe(node: YNode) -> str:
    """A few words for messages: ``"a map"``, ``"a list"`` or the scalar's text."""
    if isinstance(node, YMap):
        return "a map"
    if isinstance(node, YSeq):
        return "a list"
    return repr(node.text)


#: Deeper than any model needs (a model is about six levels deep); deeper input is refused with
#: a clear error instead of being built.
MAX_DEPTH = 100


class _Skipped:
    """A node that is not kept (refused alias, empty value, misplaced list or map), already
    reported or to be reported by whoever holds it."""


_SKIPPED = _Skipped()


@dataclass
class _Collection:
    """A sequence or mapping being built from the parser's events."""

    line: int
    is_map: bool
    kept: bool  # False: composed only for its anchors and aliases, nothing in it is converted
    items: list[YScalar] = field(default_factory=list)
    entries: list[tuple[YScalar, YNode]] = field(default_factory=list)
    first_line: dict[str, int] = field(default_factory=dict)
    key: YScalar | _Skipped | None = None  # a mapping's key awaiting its value (_SKIPPED: drop it)
    count: int = 0  # children seen (an alias counts: "[*a]" is not an empty list)


def parse_document(text: str, diag: Diagnostics) -> YMap | None:
    """Build ``text`` into a typed tree; ``None`` (with errors) when there is nothing usable.

    libyaml's parser (the one ``CSafeLoader`` uses) gives the events with their marks; the tree is
    built from them here, without recursion, so that no input can exhaust the stack.
    """
    # What the builder finds is kept only if the whole text parses: after a syntax error, the
    # events before it often show the error's symptoms (an empty value), not a second problem.
    found = Diagnostics(diag.file)
    try:
        root = _Builder(text, found).build()
    except _TooDeep as too_deep:
        diag.error(too_deep.line, f"the file nests more than {MAX_DEPTH} levels deep: a model needs a few "
                                  "(part, ros__parameters, modes, mode, parameter); check the brackets and "
                                  "indentation at this line")
        return None
    except _SecondDocument as second:
        diag.error(second.line, "YAML syntax error: expected a single document in the stream but found another "
                                "document: a model file holds one YAML document: remove the second '---' and what "
                                "follows, or merge the documents")
        return None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        diag.error(min(_line_of(mark), last_line(text)), f"YAML syntax error: {what}: fix the YAML syntax at this line")
        return None
    except yaml.reader.ReaderError as exc:
        # libyaml reads the text as UTF-8: its position counts bytes, not characters.
        before = text.encode("utf-8", "surrogatepass")[:exc.position].decode("utf-8", "replace")
        line = min(len(LINE_BREAK.split(before)), last_line(text))
        diag.error(line, f"character {exc.character!r} is not allowed in YAML (control characters and invalid "
                         "code points): remove it")
        return None
    except yaml.YAMLError as exc:
        diag.error(1, f"YAML error: {str(exc).splitlines()[0]}: fix the YAML syntax")
        return None
    diag.errors.extend(found.errors)
    if root is _SKIPPED and diag.errors:
        return None
    if root is None:
        diag.error(1, "the file holds no model: write at least one part with 'ros__parameters'")
        return None
    if not isinstance(root, YMap):
        diag.error(root.line if isinstance(root, (YScalar, YSeq)) else 1,
                   "a model file must be a map of part names at the top level")
        return None
    return root


class _TooDeep(Exception):
    def __init__(self, line: int) -> None:
        self.line = line


class _SecondDocument(Exception):
    def __init__(self, line: int) -> None:
        self.line = line


def _line_of(mark: yaml.Mark | CMark | None) -> int:
    return mark.line + 1 if mark is not None else 1


#: What libyaml (hence every mark) counts as a line break.
LINE_BREAK = re.compile("\r\n|[\r\n\x85\u2028\u2029]")


def last_line(text: str) -> int:
    """The number of the file's last line. libyaml marks the end of the stream one line further
    down after a final line break; an error there is on the last line."""
    if "\r" in text or "\x85" in text or "\u2028" in text or "\u2029" in text:
        lines = LINE_BREAK.split(text)
        return max(1, len(lines) - (lines[-1] == ""))
    return max(1, text.count("\n") + (not text.endswith("\n")))


class _Builder:
    """Turns libyaml's events into YScalar/YSeq/YMap, reporting what rcl refuses."""

    def __init__(self, source: str, diag: Diagnostics) -> None:
        self.source = source
        self.diag = diag
        self.stack: list[_Collection] = []
        self.root: YNode | _Skipped | None = None
        self.documents = 0
        self.last_line = last_line(source)

    def build(self) -> YNode | _Skipped | None:
        parser = CParser(self.source)
        get_event, handle = parser.get_event, self.event
        try:
            while (event := get_event()) is not None:
                handle(event)
        finally:
            parser.dispose()
        return self.root

    def event(self, event: Any) -> None:  # a yaml.Event; its exact class is tested below
        # libyaml's parser makes events of exactly these classes: `type() is` is the cheap test,
        # in the order of how often they come (this loop is most of a big file's load time).
        kind = type(event)
        line = event.start_mark.line + 1
        if line > self.last_line:  # a mark past the end of the text names its last line
            line = self.last_line
        if kind is yaml.ScalarEvent:
            if event.anchor is not None:
                self.anchor(event, line)
            self.add(self.scalar(event, line) if self.kept() else _SKIPPED, line, is_scalar=True)
        elif kind is yaml.MappingEndEvent or kind is yaml.SequenceEndEvent:
            done = self.stack.pop()
            self.add(self.finish(done) if done.kept else _SKIPPED, done.line, is_scalar=False)
        elif kind is yaml.MappingStartEvent or kind is yaml.SequenceStartEvent:
            self.anchor(event, line)
            if len(self.stack) >= MAX_DEPTH:
                raise _TooDeep(line)
            is_map = kind is yaml.MappingStartEvent
            self.stack.append(_Collection(line, is_map, self.kept() and self.accepts_collection(is_map, line)))
        elif kind is yaml.AliasEvent:
            self.diag.error(line, f"alias '*{event.anchor}': ROS 2 parameter files do not support aliases: "
                                  "write the value out in full")
            self.add(_SKIPPED, line, is_scalar=False)
        elif kind is yaml.DocumentStartEvent:
            self.documents += 1
            if self.documents > 1:
                raise _SecondDocument(line)

    def kept(self) -> bool:
        """Is the node starting now converted (not inside a dropped node or a refused key)?"""
        if not self.stack:
            return True
        top = self.stack[-1]
        return top.kept and not (top.is_map and top.key is _SKIPPED)

    def anchor(self, event: yaml.NodeEvent, line: int) -> None:
        if event.anchor is not None:
            self.diag.error(line, f"anchor '&{event.anchor}': ROS 2 parameter files do not support anchors or "
                                  "aliases: remove it and write values out in full")

    def accepts_collection(self, is_map: bool, line: int) -> bool:
        """A list or map may not be an item of a list, nor a key (both reported here)."""
        if not self.stack:
            return True
        top = self.stack[-1]
        if top.is_map and top.key is None:
            self.diag.error(line, "a key must be a plain name, not a list or map")
            return False
        if not top.is_map:
            kind = "maps" if is_map else "lists"
            self.diag.error(line, f"a list cannot hold {kind} in a ROS 2 parameter file: write a flat list "
                                  "of values")
            return False
        return True

    def scalar(self, event: yaml.ScalarEvent, line: int) -> YScalar | _Skipped:
        # One string per distinct short text: every node repeats its parameters' names and often
        # their values, which a model of 100,000 nodes would otherwise keep a million copies of.
        text = sys.intern(event.value) if len(event.value) <= _INTERNED_LENGTH else event.value
        quoted = event.style in ("'", '"') or event.tag == _STR_TAG
        top = self.stack[-1] if self.stack else None
        if top is not None and top.is_map and top.key is None:  # a key: its text, untyped
            if not text:
                self.diag.error(line, f"No key at line {line}: write a name before ':'")
                return _SKIPPED
            return YScalar(text, text, line)
        if not text and not quoted:
            self.diag.error(line, f"No value at line {line}: write a value, or \"\" for an empty string")
            return _SKIPPED
        return YScalar(text, rcl_scalar(text, quoted=quoted), line, self._word_lines(event))

    def _word_lines(self, event: yaml.ScalarEvent) -> tuple[int, ...]:
        start, end = event.start_mark, event.end_mark
        if event.style or start is None or end is None or start.line == end.line:  # plain: style ""
            return ()
        segment = self.source[start.index:end.index]
        return tuple(start.line + 1 + segment.count("\n", 0, word.start()) for word in re.finditer(r"\S+", segment))

    def add(self, node: YNode | _Skipped, line: int, *, is_scalar: bool) -> None:
        """Put a finished node where it belongs: the root, a list's items, a map's key or value."""
        if not self.stack:
            self.root = node
            return
        top = self.stack[-1]
        top.count += 1
        if not top.is_map:
            if isinstance(node, YScalar):
                if top.items and type(node.value) is not type(top.items[0].value):
                    self.diag.error(node.line, _mixed_message(top.items[0], node))
                else:
                    top.items.append(node)
            return
        if top.key is None:  # this node is a key
            top.key = self._key(top, node) if is_scalar else _SKIPPED
            return
        key, top.key = top.key, None
        if isinstance(key, YScalar) and not isinstance(node, _Skipped):
            top.entries.append((key, node))

    def _key(self, mapping: _Collection, node: YNode | _Skipped) -> YScalar | _Skipped:
        if not isinstance(node, YScalar) or not mapping.kept:
            return _SKIPPED
        if node.text in mapping.first_line:
            self.diag.error(node.line, f"duplicate key {node.text!r} (first at line "
                                       f"{mapping.first_line[node.text]}): remove or rename one of them")
            return _SKIPPED
        mapping.first_line[node.text] = node.line
        return node

    def finish(self, done: _Collection) -> YNode | _Skipped:
        if done.is_map:
            return YMap(tuple(done.entries), done.line)
        if not done.count:
            self.diag.error(done.line, "an empty list has no type in a ROS 2 parameter file: give it at least "
                                       "one value")
            return _SKIPPED
        return YSeq(tuple(done.items), done.line)


def _mixed_message(first: YScalar, item: YScalar) -> str:
    want, got = type_name(first.value), type_name(item.value)
    message = f"a list must hold values of one type: this item is {got} {item.text!r} but the first is {want}"
    if want == "double" and got == "integer":
        return f"{message}: write {item.value}.0 instead of {item.text}"
    if want == "integer" and got == "double":
        return f"{message}: write every item as a double (e.g. {first.value}.0 instead of {first.text})"
    if want == "string":
        return f"{message}: quote it (\"{item.text}\") to make it a string"
    return f"{message}: write every item with the same type"
