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

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

import yaml

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


@dataclass(frozen=True)
class YScalar:
    """A scalar: its text as written (after YAML folding), its rcl-typed value and its line."""

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

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(key.text for key, _ in self.entries)


YNode = YScalar | YSeq | YMap


def describe(node: YNode) -> str:
    """A few words for messages: ``"a map"``, ``"a list"`` or the scalar's text."""
    if isinstance(node, YMap):
        return "a map"
    if isinstance(node, YSeq):
        return "a list"
    return repr(node.text)


class _AliasNode(yaml.ScalarNode):
    """Stands in for an alias (already reported) so that composing can go on."""


class _Composer(yaml.SafeLoader):
    """Composes nodes only, noting what rcl refuses (anchors, aliases) and explicit ``!!str``."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.refused: list[tuple[int, str]] = []
        self.explicit_strings: set[int] = set()

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        event = self.peek_event()  # type: ignore[no-untyped-call]
        line = event.start_mark.line + 1 if event.start_mark else 0
        if isinstance(event, yaml.AliasEvent):
            self.get_event()  # type: ignore[no-untyped-call]
            self.refused.append((line, f"alias '*{event.anchor}': ROS 2 parameter files do not support "
                                       "aliases: write the value out in full"))
            return _AliasNode(_STR_TAG, "")
        if isinstance(event, yaml.NodeEvent) and event.anchor is not None:
            self.refused.append((line, f"anchor '&{event.anchor}': ROS 2 parameter files do not support "
                                       "anchors or aliases: remove it and write values out in full"))
            self.anchors.pop(event.anchor, None)  # a repeated anchor is reported here, not as a crash
        node = super().compose_node(parent, index)
        if isinstance(event, yaml.ScalarEvent) and event.tag == _STR_TAG:
            self.explicit_strings.add(id(node))
        return node


def parse_document(text: str, diag: Diagnostics) -> YMap | None:
    """Compose ``text`` into a typed tree; ``None`` (with errors) when there is nothing usable."""
    composer = _Composer(text)
    try:
        root = composer.get_single_node()
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else 0
        what = " ".join(part for part in (exc.context, exc.problem) if part)
        fix = ("a model file holds one YAML document: remove the second '---' and what follows, or merge "
               "the documents") if "single document" in what else "fix the YAML syntax at this line"
        diag.error(line, f"YAML syntax error: {what}: {fix}")
        return None
    except yaml.YAMLError as exc:
        diag.error(0, f"YAML error: {exc}: fix the YAML syntax")
        return None
    finally:
        composer.dispose()
    for line, message in composer.refused:
        diag.error(line, message)
    if root is None:
        diag.error(1, "the file holds no model: write at least one part with 'ros__parameters'")
        return None
    tree = _Converter(text, composer.explicit_strings, diag).convert(root)
    if not isinstance(tree, YMap):
        diag.error(_line(root), "a model file must be a map of part names at the top level")
        return None
    return tree


def _line(node: yaml.Node) -> int:
    return node.start_mark.line + 1 if node.start_mark else 0


class _Converter:
    def __init__(self, source: str, explicit_strings: set[int], diag: Diagnostics) -> None:
        self.source = source
        self.explicit_strings = explicit_strings
        self.diag = diag

    def convert(self, node: yaml.Node) -> YNode | None:
        """The typed node, or ``None`` for an empty value or a refused alias (both reported)."""
        if isinstance(node, _AliasNode):
            return None
        if isinstance(node, yaml.ScalarNode):
            return self.scalar(node)
        if isinstance(node, yaml.SequenceNode):
            return self.sequence(node)
        if isinstance(node, yaml.MappingNode):
            return self.mapping(node)
        self.diag.error(_line(node), "unsupported YAML node: write a map, a list or a value")
        return None

    def scalar(self, node: yaml.ScalarNode) -> YScalar | None:
        text = str(node.value)
        quoted = node.style in ("'", '"') or id(node) in self.explicit_strings
        if not text and not quoted:
            self.diag.error(_line(node), f"No value at line {_line(node)}: write a value, or \"\" for an "
                                         "empty string")
            return None
        return YScalar(text, rcl_scalar(text, quoted=quoted), _line(node), self._word_lines(node))

    def _word_lines(self, node: yaml.ScalarNode) -> tuple[int, ...]:
        start, end = node.start_mark, node.end_mark
        if node.style is not None or not start or not end or start.line == end.line:
            return ()
        segment = self.source[start.index:end.index]
        return tuple(start.line + 1 + segment.count("\n", 0, word.start()) for word in re.finditer(r"\S+", segment))

    def sequence(self, node: yaml.SequenceNode) -> YSeq | None:
        items: list[YScalar] = []
        for child in node.value:
            if isinstance(child, _AliasNode):
                continue
            if not isinstance(child, yaml.ScalarNode):
                kind = "lists" if isinstance(child, yaml.SequenceNode) else "maps"
                self.diag.error(_line(child), f"a list cannot hold {kind} in a ROS 2 parameter file: "
                                              "write a flat list of values")
                continue
            item = self.scalar(child)
            if item is None:
                continue
            if items and type(item.value) is not type(items[0].value):
                self.diag.error(item.line, _mixed_message(items[0], item))
                continue
            items.append(item)
        if not node.value:
            self.diag.error(_line(node), "an empty list has no type in a ROS 2 parameter file: give it "
                                         "at least one value")
            return None
        return YSeq(tuple(items), _line(node))

    def mapping(self, node: yaml.MappingNode) -> YMap:
        entries: list[tuple[YScalar, YNode]] = []
        first_line: dict[str, int] = {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, yaml.ScalarNode) or isinstance(key_node, _AliasNode):
                if not isinstance(key_node, _AliasNode):
                    self.diag.error(_line(key_node), "a key must be a plain name, not a list or map")
                continue
            key_text = str(key_node.value)
            if not key_text:
                self.diag.error(_line(key_node), f"No key at line {_line(key_node)}: write a name before ':'")
                continue
            if key_text in first_line:
                self.diag.error(_line(key_node), f"duplicate key {key_text!r} (first at line "
                                                 f"{first_line[key_text]}): remove or rename one of them")
                continue
            first_line[key_text] = _line(key_node)
            value = self.convert(value_node)
            if value is not None:
                entries.append((YScalar(key_text, key_text, _line(key_node)), value))
        return YMap(tuple(entries), _line(node))


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
