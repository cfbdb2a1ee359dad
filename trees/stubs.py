"""Stubs: what the nodes a tree declares, or names without sm_bt knowing them, do when it runs.

A stubs file (YAML, or JSON: the same mapping) gives, for a node ID, what its stand-in returns and
for how long (seconds of the tree's clock)::

    FollowPath: {status: running, for: 12.0, then: success}
    ComputePathToPose: {status: success}
    IsStuck: {status: failure}

``status`` is ``success``, ``failure`` or ``running``; with ``running``, ``for`` says how long
(without it, for ever) and ``then`` what comes after (``success`` unless said). Every mistake is
reported with the file's line, as a tree file's are.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml
from py_trees.common import Status

from sm_bt.model.diagnostics import did_you_mean
from sm_bt.trees.tree_documents import TreeIssue

_STATUSES = {"success": Status.SUCCESS, "failure": Status.FAILURE, "running": Status.RUNNING}
_KEYS = ("status", "for", "then")


@dataclass(frozen=True)
class Stub:
    """What a stand-in returns: ``status``, and after ``seconds`` of RUNNING (``None``: for ever)
    ``then``; ``path``/``line`` say where the stub is written."""

    status: Status
    seconds: float | None = None
    then: Status = Status.SUCCESS
    path: str = ""
    line: int = 0

    def describe(self) -> str:
        if self.status != Status.RUNNING:
            return str(self.status.value)
        if self.seconds is None:
            return "RUNNING for ever"
        return f"RUNNING for {self.seconds:g} s, then {self.then.value}"


def load_stubs(path: str | os.PathLike[str]) -> tuple[dict[str, Stub], list[TreeIssue]]:
    """The stubs of the file at ``path`` by node ID, and every mistake found in it."""
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
        document = yaml.compose(text, Loader=yaml.SafeLoader)
    except OSError as error:
        return {}, [TreeIssue(name, 0, f"cannot read it: {error.strerror or error}")]
    except UnicodeDecodeError as error:
        return {}, [TreeIssue(name, 0, f"not a text file ({error.reason} at byte {error.start})")]
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        problem = getattr(error, "problem", error)
        return {}, [TreeIssue(name, mark.line + 1 if mark else 0, f"not YAML or JSON: {problem}")]
    if document is None:
        return {}, []
    if not isinstance(document, yaml.MappingNode):
        return {}, [TreeIssue(name, document.start_mark.line + 1, "stubs are a mapping: node ID -> {status: ...}")]
    stubs: dict[str, Stub] = {}
    issues: list[TreeIssue] = []
    for key, value in document.value:
        line = key.start_mark.line + 1
        node_id = key.value if isinstance(key, yaml.ScalarNode) else ""
        stub = _stub(name, line, node_id, value, issues)
        if stub is None:
            continue
        if node_id in stubs:
            issues.append(TreeIssue(name, line, f"{node_id} is stubbed twice (first at line {stubs[node_id].line})"))
            continue
        stubs[node_id] = stub
    return stubs, issues


def _stub(name: str, line: int, node_id: str, node: yaml.Node, issues: list[TreeIssue]) -> Stub | None:
    def wrong(message: str, at: yaml.Node | None = None) -> None:
        issues.append(TreeIssue(name, at.start_mark.line + 1 if at is not None else line, message))

    if not node_id:
        wrong("a stub's key is a node ID (a name)")
        return None
    if not isinstance(node, yaml.MappingNode):
        wrong(f"{node_id}: give {{status: success|failure|running[, for: SECONDS, then: success|failure]}}", node)
        return None
    fields: dict[str, yaml.Node] = {}
    for key, value in node.value:
        if key.value not in _KEYS:
            hint = did_you_mean(str(key.value), _KEYS)
            wrong(f"{node_id}: no field {key.value!r}{hint} (fields: {', '.join(_KEYS)})", key)
            return None
        fields[key.value] = value
    statuses = {}
    for field in ("status", "then"):
        if field in fields:
            text = str(fields[field].value).lower()
            if text not in _STATUSES or (field == "then" and text == "running"):
                allowed = [s for s in _STATUSES if field == "status" or s != "running"]
                wrong(f"{node_id}: {field} must be one of {', '.join(allowed)}, not {fields[field].value!r}",
                      fields[field])
                return None
            statuses[field] = _STATUSES[text]
    if "status" not in statuses:
        wrong(f"{node_id}: give its status (success, failure or running)")
        return None
    seconds = None
    if "for" in fields:
        try:
            seconds = float(fields["for"].value)
        except (TypeError, ValueError):
            seconds = -1.0
        if not seconds >= 0:
            wrong(f"{node_id}: for is seconds (0 or more), not {fields['for'].value!r}", fields["for"])
            return None
    if statuses["status"] != Status.RUNNING and ("for" in fields or "then" in fields):
        wrong(f"{node_id}: for and then go with status running")
        return None
    return Stub(statuses["status"], seconds, statuses.get("then", Status.SUCCESS), name, line)
