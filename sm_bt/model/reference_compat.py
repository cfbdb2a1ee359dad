"""What the reference manager (micro-ROS/system_modes 0.9.0) cannot read, or does not do, in a model.

sm_bt reads every model the reference reads; the converse does not hold. The reference parses a
model as flat ROS parameter names and guesses what each is from substrings (``modes.``,
``ros__parameters``, ``rules.``), so sm_bt's extensions are not refused there but misread, some
of them fatally (``__order__`` is taken for a part, and a change to its mode crashes the manager).
:func:`reference_issues` finds each such construct with its line and what to write instead:

* errors: the reference misreads the construct (crash, load failure, a phantom part, a wrong
  state) or cannot find the default mode;
* warnings: the reference reads the file but does something else than sm_bt with it (never
  reaches a mode, never recognises one).

Run it on a model that loads (``sm-bt check --reference``): it looks only at what loading checked.
"""

from __future__ import annotations

from sm_bt.model.declarations import PartDecl, read_declarations
from sm_bt.model.diagnostics import Diagnostics
from sm_bt.model.rcl_yaml import YMap, YNode, YScalar, YSeq, parse_document
from sm_bt.model.system_modes import ORDER_KEY
from sm_bt.model.types import DEFAULT_MODE, DONT_CARE, Location, ModelIssue, PartKind, Severity

#: Substrings by which the reference's parser sorts parameter names (its rules and modes parsers).
_RULES_MARK, _MODES_MARK = "rules.", "modes."


def reference_issues(text: str, filename: str) -> list[ModelIssue]:
    """The constructs of a model (which loads in sm_bt) that the reference misreads or ignores."""
    diag = Diagnostics(filename)
    doc = parse_document(text, diag)
    if doc is None:
        return []
    found = _Found(filename)
    for decl in read_declarations(doc, diag).values():
        if decl.remote:
            found.error(decl.line, f"{decl.name}: the reference has no remote parts (it takes any type but 'node' "
                                   "for a system): a model with remote parts is for sm_bt only")
            continue
        _default_mode(decl, found)
        if decl.modes is None:
            continue
        if decl.kind is PartKind.SYSTEM:
            _system_modes(decl, decl.modes, found)
        elif decl.kind is PartKind.NODE:
            _node_modes(decl, decl.modes, found)
            if decl.match is not None:
                found.error(decl.match.line, f"node {decl.name}: the reference has no 'match:' (it compares every "
                                               "parameter exactly): its inference will not recognise values inside "
                                               "these ranges; drop 'match:' or give exact values")
        _rules(decl, found)
    return sorted(found.issues, key=lambda issue: issue.location.line)


class _Found:
    def __init__(self, filename: str) -> None:
        self.filename = filename
        self.issues: list[ModelIssue] = []

    def error(self, line: int, message: str) -> None:
        self.issues.append(ModelIssue(Location(self.filename, line), Severity.ERROR, f"reference: {message}"))

    def warning(self, line: int, message: str) -> None:
        self.issues.append(ModelIssue(Location(self.filename, line), Severity.WARNING, f"reference: {message}"))


def _default_mode(decl: PartDecl, found: _Found) -> None:
    entry = decl.params.get("defaultmode")
    if entry is not None and decl.default_mode not in (None, DEFAULT_MODE):
        found.error(entry[0].line, f"{decl.name}: the reference ignores 'defaultmode' (an unreleased branch has "
                                   f"it) and looks for a mode named {DEFAULT_MODE}: rename mode "
                                   f"{decl.default_mode!r} to {DEFAULT_MODE}")
    if decl.modes is None or not decl.modes.entries or decl.default_mode != DEFAULT_MODE:
        return
    first = decl.modes.entries[0][0]
    if first.text != DEFAULT_MODE:
        found.error(first.line, f"{decl.name}: the reference needs {DEFAULT_MODE} before the other modes (it fails to "
                                f"load with 'Could not find default mode for mode {first.text!r}'): move "
                                f"{DEFAULT_MODE} up")


def _system_modes(decl: PartDecl, modes: YMap, found: _Found) -> None:
    configured: set[str] = set()  # parts that some mode wants configured (inactive or active)
    unconfigured: list[tuple[str, str, int]] = []
    for mode_key, body in modes:
        if not isinstance(body, YMap):
            continue
        for key, value in body:
            where = f"{decl.name} mode {mode_key.text}"
            if key.text == ORDER_KEY:
                found.error(key.line, f"{where}: the reference takes {ORDER_KEY} for a part and crashes on a change to "
                                      f"this mode: drop it (the parts then switch all at once)")
            elif not isinstance(value, YScalar):
                continue
            elif value.text == DONT_CARE:
                found.error(value.line, f"{where}: the reference reads {DONT_CARE} as the state 'unknown' and sends "
                                        f"{key.text} a transition to it: give {key.text} a state")
            else:
                _misread(f"modes.{mode_key.text}.{key.text}", key.line, where, found)
                state = value.text.partition(".")[0]
                if state in ("inactive", "active"):
                    configured.add(key.text)
                elif state == "unconfigured":
                    unconfigured.append((mode_key.text, key.text, value.line))
    for mode, part, line in unconfigured:
        if part in configured:
            found.warning(line, f"{decl.name} mode {mode}: the reference never sends 'cleanup', so {part} stays "
                                f"configured and {decl.name} never reaches {mode} from a mode where {part} is "
                                "inactive or active (sm-bt manager does)")


def _node_modes(decl: PartDecl, modes: YMap, found: _Found) -> None:
    for mode_key, body in modes:
        if not isinstance(body, YMap):
            continue
        match = body.get("match")
        if match is not None:
            found.error(match[0].line, f"{decl.name} mode {mode_key.text}: the reference takes 'match:' inside a mode "
                                       "for a part entry and compares parameters exactly: drop it or give exact "
                                       "values")
        params = body.get("ros__parameters")
        if params is None:
            continue
        for name, line, value in _flatten(params[1]):
            _misread(f"modes.{mode_key.text}.ros__parameters.{name}", line, f"{decl.name} mode {mode_key.text}", found)
            if isinstance(value, YSeq) and mode_key.text == DEFAULT_MODE:
                found.warning(line, f"{decl.name}: the reference never matches array parameters, so its inference "
                                    f"never recognises a mode of {decl.name} ({name!r} is an array)")


def _misread(flat: str, line: int, where: str, found: _Found) -> None:
    """The reference sees ``flat`` (a parameter's full name): a rule if it holds ``rules.``, a mode
    entry if it holds ``modes.``; which it is meant to be is known from ``flat``'s start."""
    if flat.startswith(_MODES_MARK) and _RULES_MARK in flat:
        found.error(line, f"{where}: the reference takes every parameter name holding {_RULES_MARK!r} for a rule "
                          f"({flat!r}) and fails to load the model: rename the mode or the parameter")
    elif flat.startswith(_RULES_MARK) and _MODES_MARK in flat:
        found.error(line, f"{where}: the reference takes every parameter name holding {_MODES_MARK!r} for a mode "
                          f"({flat!r}) and makes up a mode from it: rename the rule")


def _flatten(node: YNode, prefix: str = "") -> list[tuple[str, int, YNode]]:
    """Every parameter below ``node`` as (dotted name, line, value)."""
    if not isinstance(node, YMap):
        return []
    out: list[tuple[str, int, YNode]] = []
    for key, value in node:
        name = f"{prefix}{key.text}"
        if isinstance(value, YMap):
            out += _flatten(value, f"{name}.")
        else:
            out.append((name, key.line, value))
    return out


def _rules(decl: PartDecl, found: _Found) -> None:
    if not isinstance(decl.rules, YMap):
        return
    for key, _ in decl.rules:
        _misread(f"rules.{key.text}.if_target", key.line, f"{decl.name} rule {key.text}", found)
