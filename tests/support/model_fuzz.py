"""Hostile SMH model files for the loader's fuzz tests: two hypothesis strategies and the oracle.

* :func:`smh_documents` is structure-aware: SMH-shaped YAML trees (parts, ``type``, ``parts``,
  modes of systems and nodes, rules, ``__order__``, ``match``, ``defaultmode``, namespaces) with
  damage drawn into them (wrong types, unknown and near-miss names, duplicate keys, anchors,
  aliases and merge keys, tags including ``!!python/...``, nesting past the loader's limit, a
  part or mode repeated hundreds of times, odd scalars), written out in block or flow style,
  sometimes with CRLF line ends, a byte-order mark or a second document.
* :func:`mutated_models` mutates the bytes of the shipped and fixture models: flipped and
  inserted bytes (control characters, invalid UTF-8, YAML indicators), deleted, duplicated and
  moved ranges, truncation.

:func:`check_load` is the oracle: loading the file either gives a ``Model`` (on which a manager
can be built and which ``sm-bt modes`` can print) or raises ``ModelError`` whose every issue
names the file and a line between 1 and the file's last line; anything else fails the test, and
so does a load slower than :func:`time_bound` for the file's size. :data:`OUTCOMES` counts the
outcomes for ``make stress``'s summary.
"""

from __future__ import annotations

import contextlib
import json
import re
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from hypothesis import strategies as st
from model_generator import generated_models

from sm_bt.bundled import path as bundled_path
from sm_bt.model import ModelError, load_model
from sm_bt.model.rcl_yaml import rcl_scalar
from sm_bt.model.types import Model

# -- a YAML tree that can be damaged, and its text ---------------------------------------------------


@dataclass
class Scalar:
    text: str
    style: str = "plain"  # plain | single | double | lines (one word per line, as SMH writes `parts`)
    anchor: str | None = None
    tag: str | None = None


@dataclass
class Seq:
    items: list[Node] = field(default_factory=list)
    flow: bool = False
    anchor: str | None = None
    tag: str | None = None


@dataclass
class Map:
    entries: list[tuple[Node, Node]] = field(default_factory=list)
    flow: bool = False
    anchor: str | None = None
    tag: str | None = None


@dataclass
class Alias:
    name: str


Node = Scalar | Seq | Map | Alias

# Plain scalars this writer emits unquoted: nothing YAML could read as an indicator or comment.
_PLAIN = re.compile(r"[A-Za-z0-9_/~.+-](?:[A-Za-z0-9_./+ -]*[A-Za-z0-9_./+-])?")


def _properties(node: Node) -> str:
    if isinstance(node, Alias):
        return ""
    words = [f"&{node.anchor}" if node.anchor else "", node.tag or ""]
    return "".join(word + " " for word in words if word)


def _scalar_text(node: Scalar) -> str:
    style = node.style
    if style in ("plain", "lines") and not _PLAIN.fullmatch(node.text):
        style = "double"
    if style == "single" and any(ord(c) < 0x20 or c == "\x7f" for c in node.text):
        style = "double"
    if style == "single":
        return "'" + node.text.replace("'", "''") + "'"
    if style == "double":
        return json.dumps(node.text, ensure_ascii=False)
    return node.text


def _inline(node: Node) -> str:
    if isinstance(node, Alias):
        return f"*{node.name}"
    props = _properties(node)
    if isinstance(node, Scalar):
        return props + _scalar_text(node)
    if isinstance(node, Seq):
        return props + "[" + ", ".join(_inline(item) for item in node.items) + "]"
    return props + "{" + ", ".join(f"{_inline(key)}: {_inline(value)}" for key, value in node.entries) + "}"


def _is_block(node: Node) -> bool:
    return ((isinstance(node, Seq) and not node.flow and bool(node.items))
            or (isinstance(node, Map) and not node.flow and bool(node.entries)))


def _is_lines(node: Node) -> bool:
    return (isinstance(node, Scalar) and node.style == "lines" and " " in node.text
            and _PLAIN.fullmatch(node.text) is not None)


def _block(node: Seq | Map, indent: int, out: list[str]) -> None:
    pad = " " * indent
    pairs: list[tuple[str, Node]] = ([(f"{_inline(key)}:", value) for key, value in node.entries]
                                     if isinstance(node, Map) else [("-", item) for item in node.items])
    for lead, value in pairs:
        props = _properties(value).rstrip()
        if _is_block(value):
            assert isinstance(value, (Seq, Map))
            out.append(f"{pad}{lead}" + (f" {props}" if props else ""))
            _block(value, indent + 2, out)
        elif _is_lines(value):
            assert isinstance(value, Scalar)
            out.append(f"{pad}{lead}" + (f" {props}" if props else ""))
            out.extend(f"{pad}  {word}" for word in value.text.split())
        else:
            out.append(f"{pad}{lead} {_inline(value)}")


def emit(root: Node) -> str:
    """YAML text for ``root``: block style where the tree asks for it, flow style elsewhere."""
    if _is_block(root):
        assert isinstance(root, (Seq, Map))
        out: list[str] = [_properties(root).rstrip()] if _properties(root) else []
        _block(root, 0, out)
        return "\n".join(out) + "\n"
    return _inline(root) + "\n"


# -- SMH-shaped trees ----------------------------------------------------------------------------------

PART_NAMES = ("pilot", "laser", "amcl", "nav", "base", "ns/inner", "/rooted", "Laser", "laser_", "ns")
MODE_NAMES = ("__DEFAULT__", "FAST", "SLOW", "f_degraded_mode", "fast", "X.Y", "__DONTCARE__", "active", "")
STATE_WORDS = ("active", "inactive", "unconfigured", "finalized", "errorprocessing", "ACTIVE", "configuring",
               "__DONTCARE__", "", "Active ")
TAGS = ("!!str", "!!int", "!!float", "!!bool", "!!null", "!!binary", "!!set", "!!omap", "!custom",
        "!!python/object/apply:os.system", "!!python/name:os.system", "!<tag:yaml.org,2002:str>")
ODD_SCALARS = ("true", "False", "yes", "on", "Off", "~", "null", "0x1F", "010", "0o17", "0b101", "1e3", "1e400",
               "-.inf", ".nan", "1_000", "+1", "1.", ".", "-", "9" * 30, "", " ", "a: b", "- x", "#x", "&a", "*a",
               "!x", "%x", "@x", "`x", "|", ">", "'", '"', "\t", "\x00", "\x1b[31m", "\u2028", "\ufeff", "é",
               "\U0001f916", "__DEFAULT__", "ros__parameters", "<<")
NAMES = st.sampled_from(PART_NAMES) | st.text(alphabet="abcLN_/.", min_size=1, max_size=6)
STYLES = st.sampled_from(("plain", "plain", "plain", "single", "double"))


TEXTS = (st.sampled_from(ODD_SCALARS) | st.integers(-2 ** 70, 2 ** 70).map(str) | st.floats().map(repr)
         | st.text(st.characters(exclude_categories=("Cc", "Cs")), max_size=12))
SCALARS = st.builds(Scalar, TEXTS, STYLES)
# Strategies are built once: hypothesis validates each new strategy object on its first draw.
JUNK = st.recursive(SCALARS, lambda inner: st.builds(Seq, st.lists(inner, max_size=3), st.booleans())
                    | st.builds(Map, st.lists(st.tuples(SCALARS, inner), max_size=3), st.booleans()),
                    max_leaves=8)
LIST_TEXTS = st.sampled_from((st.integers(-9, 9).map(str), st.floats(-9, 9).map(repr),
                              st.sampled_from(("true", "false")), st.text("abc", max_size=3)))


@st.composite
def _targets(draw: Any) -> Scalar:
    state = draw(st.sampled_from(STATE_WORDS))
    if draw(st.booleans()):
        state += "." + draw(st.sampled_from(MODE_NAMES))
    return Scalar(state, draw(STYLES))


@st.composite
def _parameter_values(draw: Any) -> Node:
    kind = draw(st.integers(0, 9))
    if kind <= 5:
        return draw(SCALARS)
    if kind <= 7:  # a list: usually of one type, sometimes mixed or empty
        texts = draw(LIST_TEXTS) if draw(st.booleans()) else TEXTS
        items = draw(st.lists(st.builds(Scalar, texts, STYLES), max_size=4))
        return Seq(list(items), flow=draw(st.booleans()))
    return Map([(Scalar(draw(st.sampled_from("abc"))), draw(SCALARS))], flow=draw(st.booleans()))


TARGETS = _targets()
# Mostly a default mode first (without one, nothing else in the part is checked).
MODE_LISTS = st.builds(lambda first, rest: first + rest, st.sampled_from(([], ["__DEFAULT__"], ["__DEFAULT__"])),
                       st.lists(st.sampled_from(MODE_NAMES), max_size=3))
PARAMETER_VALUES = _parameter_values()


@st.composite
def remote_part(draw: Any, name: str) -> Map:
    """A part another manager serves: its modes a list of names (a map, now and then), its manager
    and system names good or bad."""
    listed = draw(MODE_LISTS)
    form = draw(st.integers(0, 5))
    modes: Node = (Map([(Scalar(mode), Map([])) for mode in listed]) if form == 0
                   else Scalar(" ".join(listed), style="lines") if form == 1 and listed
                   else Seq([Scalar(mode) for mode in listed], flow=draw(st.booleans())))
    keys: list[tuple[Node, Node]] = [(Scalar("type"), Scalar(draw(st.sampled_from(("remote", "remote", "Remote"))))),
                                     (Scalar("modes"), modes)]
    for key, values in (("manager", ("/robot1", "/a/b", "robot1", "/", "/1x")), ("system", ("pilot", "a/b", "2x"))):
        if draw(st.integers(0, 2)):
            keys.append((Scalar(key), Scalar(draw(st.sampled_from(values)))))
    if draw(st.integers(0, 7)) == 0:
        keys.append((Scalar(draw(st.sampled_from(("parts", "match", "rules", "defaultmode")))),
                     Scalar(draw(st.sampled_from(MODE_NAMES)))))
    return Map([(Scalar("ros__parameters"), Map(keys))])


@st.composite
def node_part(draw: Any, name: str) -> Map:
    if draw(st.integers(0, 7)) == 0:
        return draw(remote_part(name))
    params = [f"p{index}" for index in range(draw(st.integers(0, 4)))] + draw(st.lists(NAMES, max_size=1))
    modes: list[tuple[Node, Node]] = []
    for mode in draw(MODE_LISTS):
        chosen = draw(st.lists(st.sampled_from(params), max_size=len(params), unique=True)) if params else []
        values = Map([(Scalar(param), draw(PARAMETER_VALUES)) for param in chosen], flow=draw(st.booleans()))
        body: list[tuple[Node, Node]] = [(Scalar("ros__parameters"), values)]
        if params and draw(st.integers(0, 5)) == 0:
            body.append((Scalar("match"), Map([(Scalar(params[0]), draw(_match_entry()))])))
        modes.append((Scalar(mode), Map(body)))
    keys: list[tuple[Node, Node]] = [(Scalar("type"), Scalar(draw(st.sampled_from(("node", "node", "Node", "system",
                                                                                     "robot")))))]
    keys.append((Scalar("modes"), Map(modes)))
    if params and draw(st.integers(0, 5)) == 0:
        keys.append((Scalar("match"), Map([(Scalar(params[-1]), draw(_match_entry()))])))
    if draw(st.integers(0, 7)) == 0:
        keys.append((Scalar("defaultmode"), Scalar(draw(st.sampled_from(MODE_NAMES)))))
    return Map([(Scalar("ros__parameters"), Map(keys))])


@st.composite
def _match_entry(draw: Any) -> Node:
    number = st.floats(-5, 5).map(repr) | st.integers(-5, 5).map(str) | st.sampled_from(("x", "inf", ".nan"))
    kind = draw(st.integers(0, 3))
    if kind == 0:
        return Map([(Scalar("tolerance"), Scalar(draw(number)))], flow=True)
    if kind == 1:
        return Seq([Scalar(draw(number)), Scalar(draw(number))], flow=True)
    if kind == 2:
        return Map([(Scalar(draw(st.sampled_from(("min", "max", "tol")))), Scalar(draw(number)))], flow=True)
    return draw(SCALARS)


@st.composite
def system_part(draw: Any, name: str, names: list[str]) -> Map:
    members = draw(st.lists(st.sampled_from(names) | st.sampled_from(names) | NAMES, max_size=4, unique=True))
    keys: list[tuple[Node, Node]] = [(Scalar("type"), Scalar("system"))]
    if draw(st.booleans()):
        keys.append((Scalar("parts"), Scalar(" ".join(members) or "x", style="lines")
                     if draw(st.booleans()) else Seq([Scalar(m) for m in members])))
    modes: list[tuple[Node, Node]] = []
    for mode in draw(MODE_LISTS):
        entries: list[tuple[Node, Node]] = [(Scalar(member), draw(TARGETS)) for member in members
                                            if draw(st.integers(0, 4))]
        if members and draw(st.integers(0, 4)) == 0:
            stages = draw(st.lists(st.lists(st.sampled_from([*members, "ghost"]), min_size=1, max_size=2),
                                   max_size=3))
            entries.append((Scalar("__order__"), Seq([Scalar(", ".join(stage)) for stage in stages], flow=True)))
        modes.append((Scalar(mode), Map(entries, flow=draw(st.integers(0, 5)) == 0)))
    keys.append((Scalar("modes"), Map(modes)))
    rules: list[tuple[Node, Node]] = []
    for index in range(draw(st.integers(0, 2))):
        rule = [(Scalar("if_target"), draw(TARGETS)),
                (Scalar("if_part"), Seq([Scalar(draw(st.sampled_from([*members, "ghost"]))), draw(TARGETS)],
                                        flow=True)),
                (Scalar("new_target"), draw(TARGETS))]
        rules.append((Scalar(f"r{index}"), Map(draw(st.permutations(rule))[:draw(st.integers(1, 3))])))
    if rules:
        keys.append((Scalar("rules"), Map(rules)))
    return Map([(Scalar("ros__parameters"), Map(keys))])


# -- damage -------------------------------------------------------------------------------------------


def _slots(root: Node) -> list[tuple[Seq | Map, int, int]]:
    """Every place a node sits: (container, index, 0 for a list item or a key, 1 for a value)."""
    found: list[tuple[Seq | Map, int, int]] = []
    stack: list[Node] = [root]
    while stack:
        node = stack.pop()
        if isinstance(node, Seq):
            for index, item in enumerate(node.items):
                found.append((node, index, 0))
                stack.append(item)
        elif isinstance(node, Map):
            for index, (key, value) in enumerate(node.entries):
                found += [(node, index, 0), (node, index, 1)]
                stack += [key, value]
    return found


def _get(slot: tuple[Seq | Map, int, int]) -> Node:
    container, index, side = slot
    return container.items[index] if isinstance(container, Seq) else container.entries[index][side]


def _put(slot: tuple[Seq | Map, int, int], node: Node) -> None:
    container, index, side = slot
    if isinstance(container, Seq):
        container.items[index] = node
    else:
        key, value = container.entries[index]
        container.entries[index] = (node, value) if side == 0 else (key, node)


DAMAGE = ("replace", "anchor", "alias", "tag", "duplicate", "delete", "repeat", "flow", "rename", "nest", "merge")


@st.composite
def damaged(draw: Any, root: Node) -> Node:
    for _ in range(draw(st.integers(0, 4))):
        slots = _slots(root)
        if not slots:
            break
        slot = slots[draw(st.integers(0, len(slots) - 1))]
        node, (container, index, _) = _get(slot), slot
        kind = draw(st.sampled_from(DAMAGE))
        if kind == "replace":
            _put(slot, draw(JUNK))
        elif kind == "anchor" and not isinstance(node, Alias):
            node.anchor = draw(st.sampled_from(("a", "b")))
        elif kind == "alias":
            _put(slot, Alias(draw(st.sampled_from(("a", "b", "zz")))))
        elif kind == "tag" and not isinstance(node, Alias):
            node.tag = draw(st.sampled_from(TAGS))
        elif kind in ("duplicate", "delete", "repeat") and isinstance(container, Map):
            entry = container.entries[index]
            if kind == "duplicate":
                container.entries.insert(index, entry)
            elif kind == "delete":
                del container.entries[index]
            else:  # hundreds of parts, modes or parameters: what a generator might write
                key = entry[0]
                text = key.text if isinstance(key, Scalar) else "k"
                same = draw(st.booleans())  # the same value every time (identical modes) or a copy each
                container.entries[index + 1:index + 1] = [(Scalar(f"{text}{n}"), entry[1] if same else Scalar(str(n)))
                                                          for n in range(draw(st.integers(2, 300)))]
        elif kind == "flow" and isinstance(node, (Seq, Map)):
            node.flow = not node.flow
        elif kind == "rename" and isinstance(node, Scalar):
            node.text = draw(st.sampled_from((node.text.upper(), node.text + "_", node.text[1:], "/" + node.text,
                                              node.text + "/x", node.text.replace("_", ""))))
        elif kind == "nest":  # up to past the loader's depth limit (100)
            depth = draw(st.sampled_from((5, 50, 99, 101, 150)))
            for _ in range(depth):
                node = Seq([node], flow=True) if draw(st.booleans()) else Map([(Scalar("a"), node)], flow=True)
            _put(slot, node)
        elif kind == "merge" and isinstance(container, Map):
            container.entries.insert(index, (Scalar("<<"), Alias(draw(st.sampled_from(("a", "b"))))))
    return root


def tree_of(value: Any) -> Node:
    """The tree of a value read by ``yaml.safe_load`` (a valid model), written back the same way:
    strings that rcl would read as another type are quoted, a multi-word string is one word per line
    (as SMH writes ``parts``)."""
    if isinstance(value, dict):
        return Map([(Scalar(str(key)), tree_of(item)) for key, item in value.items()])
    if isinstance(value, list):
        return Seq([tree_of(item) for item in value], flow=True)
    if isinstance(value, bool):
        return Scalar("true" if value else "false")
    if isinstance(value, str):
        typed = rcl_scalar(value)
        return Scalar(value, style="lines" if " " in value else ("plain" if isinstance(typed, str) else "double"))
    return Scalar(repr(value))


@st.composite
def _random_parts(draw: Any) -> Map:
    names = draw(st.lists(st.sampled_from(PART_NAMES) | NAMES, min_size=1, max_size=5))
    entries: list[tuple[Node, Node]] = []
    for name in names:
        if draw(st.integers(0, 2)) == 0:
            entries.append((Scalar(name), draw(system_part(name, names))))
        else:
            entries.append((Scalar(name), draw(node_part(name))))
    return Map(entries)


# Half the documents start from a valid model (damage then breaks one thing at a time), half from
# SMH-shaped parts drawn at random (which break in many places at once).
VALID_MODELS = generated_models().map(lambda generated: tree_of(yaml.safe_load(generated.text)))


@st.composite
def smh_documents(draw: Any) -> bytes:
    """One SMH-shaped document, maybe damaged, as the bytes of a file."""
    root = draw(VALID_MODELS | _random_parts())
    text = emit(draw(damaged(root)))
    frame = draw(st.integers(0, 19))
    if frame == 0:
        text = text.replace("\n", "\r\n")
    elif frame == 1:
        text = "\ufeff" + text
    elif frame == 2:
        text = "---\n" + text + "...\n"
    elif frame == 3:
        text = text + "---\nother: 1\n"
    elif frame == 4:
        text = "%YAML 1.1\n---\n" + text
    return text.encode("utf-8", "surrogatepass")


# -- byte-level mutations of real models --------------------------------------------------------------

_FIXTURES = Path(__file__).parents[1] / "models"
SEEDS: tuple[bytes, ...] = tuple(path.read_bytes() for path in (
    *(bundled_path(name) for name in ("pilot", "pilot_rules", "actuation")), *sorted(_FIXTURES.glob("*.yaml"))))
TOKENS = (b"\x00", b"\x07", b"\x1b", b"\x7f", b"\x80", b"\xff", b"\xc3", b"\xef\xbb\xbf", b"\r", b"\t", b"\n",
          b" ", b":", b"-", b"[", b"{", b"&a ", b"*a", b"<<: *a\n", b"!!python/object/apply:os.system ", b"? ",
          b"---\n", b"...\n", b"'", b'"', b"|", b">", b"%", b"#", b"[" * 120, b"{a: " * 120, b"- " * 120)
MUTATIONS = ("flip", "insert", "delete", "duplicate", "move", "truncate", "swap_lines", "indent")


@st.composite
def mutated_models(draw: Any) -> bytes:
    """A shipped or fixture model with 1-8 byte-level mutations."""
    data = bytearray(draw(st.sampled_from(SEEDS)))
    for _ in range(draw(st.integers(1, 8))):
        kind = draw(st.sampled_from(MUTATIONS))
        at = draw(st.integers(0, len(data)))
        span = draw(st.integers(1, 64))
        if kind == "flip" and at < len(data):
            data[at] ^= draw(st.integers(1, 255))
        elif kind == "insert":
            data[at:at] = draw(st.sampled_from(TOKENS))
        elif kind == "delete":
            del data[at:at + span]
        elif kind == "duplicate":
            data[at:at] = data[at:at + span]
        elif kind == "move":
            chunk = bytes(data[at:at + span])
            del data[at:at + span]
            to = draw(st.integers(0, len(data)))
            data[to:to] = chunk
        elif kind == "truncate":
            del data[at:]
        elif kind in ("swap_lines", "indent"):
            lines = bytes(data).split(b"\n")
            one = draw(st.integers(0, len(lines) - 1))
            if kind == "swap_lines":
                two = draw(st.integers(0, len(lines) - 1))
                lines[one], lines[two] = lines[two], lines[one]
            else:
                lines[one] = lines[one][2:] if draw(st.booleans()) else b"  " + lines[one]
            data = bytearray(b"\n".join(lines))
    return bytes(data)


# -- the oracle ------------------------------------------------------------------------------------------

#: What the fuzzed files did: "model", "model with warnings", or "error: <kind of first error>".
OUTCOMES: Counter[str] = Counter()


def time_bound(size: int) -> float:
    """Seconds a load may take: 50 times the loader's ~1 µs per byte, and half a second for the
    machine's noise. A cost that grows faster than the file (a quadratic check) exceeds it; a load
    over the bound is timed twice more and the best of the three counts, so that a pause of the
    machine (or of the garbage collector) is not taken for the loader's cost."""
    return 0.5 + 50e-6 * size


def _last_line(data: bytes) -> int:
    """The file's last line, counted as libyaml counts line breaks (CRLF, CR, LF, NEL, U+2028/9)."""
    text = data.decode("utf-8", "replace")
    lines = re.split("\r\n|[\r\n\x85\u2028\u2029]", text)
    return max(1, len(lines) - (lines[-1] == ""))


def _kind(message: str) -> str:
    """A message with its names and numbers taken out, to count errors by kind."""
    head = message.split(": ")[0]
    return re.sub(r"\d+", "N", re.sub(r"'[^']*'|\"[^\"]*\"", "…", head))[:70]


def check_load(data: bytes, path: Path) -> str:
    """Write ``data`` to ``path``, load it, check the outcome (see the module's docstring); return it."""
    try:
        outcome = _checked_load(data, path)
    except Exception:  # not an interrupt of the run (Ctrl-C), which the summary counted as a crash
        OUTCOMES["crash"] += 1  # an exception other than ModelError, or a broken promise of the oracle
        raise
    OUTCOMES[outcome] += 1
    return outcome


def _checked_load(data: bytes, path: Path) -> str:
    from sm_bt.cli.modes import describe_model
    from sm_bt.sim import SimulatedSystem

    path.write_bytes(data)
    last_line = _last_line(data)
    start = time.perf_counter()
    try:
        model = load_model(path)
    except ModelError as error:
        elapsed = time.perf_counter() - start
        assert error.issues, "a ModelError without issues"
        for issue in error.issues:
            assert issue.location.file == str(path), str(issue)
            assert 1 <= issue.location.line <= last_line, f"line {issue.location.line} of {last_line}: {issue}"
            assert issue.message.strip(), str(issue)
        assert str(error).startswith(f"{path}:{error.issues[0].location.line}: error: "), str(error)
        outcome = "error: " + _kind(error.issues[0].message)
    else:
        elapsed = time.perf_counter() - start
        assert isinstance(model, Model)
        for warning in model.warnings:
            assert 1 <= warning.location.line <= last_line, str(warning)
        SimulatedSystem(model, record=False)  # a model that loads is one a manager can run
        assert list(describe_model(model))
        outcome = "model with warnings" if model.warnings else "model"
    if elapsed > time_bound(len(data)):  # a slow moment of a shared machine, or a real cost: load again
        elapsed = min([elapsed, *(_load_seconds(path) for _ in range(2))])
    assert elapsed <= time_bound(len(data)), f"{elapsed:.2f} s for {len(data)} bytes (best of 3 loads)"
    return outcome


def _load_seconds(path: Path) -> float:
    start = time.perf_counter()
    with contextlib.suppress(ModelError):
        load_model(path)
    return time.perf_counter() - start


def summary() -> str:
    """Counts by outcome (errors by their kind, the most frequent first)."""
    total = sum(OUTCOMES.values())
    if not total:
        return ""
    crashes = OUTCOMES["crash"]
    refused = total - crashes - OUTCOMES["model"] - OUTCOMES["model with warnings"]
    lines = [f"fuzzed model files: {total:,}, crashes: {crashes:,}",
             f"  model: {OUTCOMES['model']:,}   model with warnings: {OUTCOMES['model with warnings']:,}   "
             f"ModelError: {refused:,}"]
    errors = [(kind, count) for kind, count in OUTCOMES.most_common() if kind.startswith("error: ")]
    lines += [f"  {count:>8,}  {kind}" for kind, count in errors[:15]]
    if len(errors) > 15:
        lines.append(f"  {sum(count for _, count in errors[15:]):>8,}  ({len(errors) - 15} other kinds of error)")
    return "\n".join(lines)
