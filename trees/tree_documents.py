"""Tree files as read: parsed with each element's file and line, imports followed, the trees
defined, the node types declared in ``<TreeNodesModel>`` (:class:`Declared`), and every mistake in
them (:class:`TreeIssue`)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.parsers import expat

from sm_bt.model.diagnostics import did_you_mean

#: Elements nested deeper than this are refused (a tree file is not a way to exhaust the stack).
MAX_DEPTH = 100
#: The kinds of node ``<TreeNodesModel>`` declares (Groot2, BehaviorTree.CPP 4), by lower-case tag.
KINDS = {"action": "Action", "condition": "Condition", "control": "Control", "decorator": "Decorator",
         "subtree": "SubTree"}
_PORTS = ("input_port", "output_port", "inout_port")


@dataclass(frozen=True)
class Declared:
    """A node type that a ``<TreeNodesModel>`` declares: its kind, its ports (by direction) and
    where the declaration is."""

    node_id: str
    kind: str  # one of KINDS' values
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    path: str
    line: int


@dataclass(frozen=True)
class TreeIssue:
    """One mistake in a tree file, where it is."""

    path: str
    line: int  # 1-based; 0 when the file as a whole is at fault
    message: str

    def __str__(self) -> str:
        where = f"{self.path}:{self.line}" if self.line else self.path
        return f"{where}: error: {self.message}"


class Documents:
    """The files of one tree load, from ``path`` on: :meth:`read` parses one and follows its
    imports; ``trees`` holds every ``<BehaviorTree>`` by ID, ``where`` each element's file and line,
    ``issues`` every mistake found."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.issues: list[TreeIssue] = []
        self.where: dict[int, tuple[str, int]] = {}  # id(element) -> (file, line)
        self.trees: dict[str, ET.Element] = {}
        self.declared: dict[str, Declared] = {}

    def issue(self, element: ET.Element | None, message: str) -> None:
        path, line = self.where.get(id(element), (str(self.path), 0)) if element is not None else (str(self.path), 0)
        self.issues.append(TreeIssue(path, line, message))

    def read(self, path: Path, seen: set[Path]) -> ET.Element | None:
        try:
            data = path.read_bytes()
        except OSError as error:
            self.issues.append(TreeIssue(str(path), 0, f"cannot read it: {error.strerror or error}"))
            return None
        document = self._parse(path, data)
        if document is None:
            return None
        seen = seen | {path.resolve()}
        for child in list(document):
            tag = child.tag.lower()
            if tag in ("import", "include"):
                document.remove(child)
                self._import(child, path, seen)
            elif tag == "behaviortree":
                self._define(child)
            elif tag in ("treenodesmodel", "treenodes"):
                document.remove(child)  # Groot's palette: declarations, nothing to build
                self._declare(child)
            else:
                self.issue(child, f"<{child.tag}> at the top level: expected <BehaviorTree ID=...>, "
                                   "<Import src=...> or <Include file=...>")
        return document

    def _parse(self, path: Path, data: bytes) -> ET.Element | None:
        parser = expat.ParserCreate()
        stack: list[ET.Element] = []
        found: list[ET.Element] = []

        def start(tag: str, attributes: dict[str, str]) -> None:
            element = ET.Element(tag, attributes)
            self.where[id(element)] = (str(path), parser.CurrentLineNumber)
            (stack[-1].append(element) if stack else found.append(element))
            stack.append(element)
            if len(stack) > MAX_DEPTH:
                raise _Refused(f"nested more than {MAX_DEPTH} deep")

        def refuse_doctype(*_: Any) -> None:
            raise _Refused("a DOCTYPE (tree files need no entities; they are refused)")

        parser.StartElementHandler = start
        parser.EndElementHandler = lambda _tag: stack.pop()
        parser.StartDoctypeDeclHandler = refuse_doctype
        try:
            parser.Parse(data, True)
        except expat.ExpatError as error:
            self.issues.append(TreeIssue(str(path), error.lineno, f"not well-formed XML: "
                                         f"{expat.ErrorString(error.code)} (column {error.offset + 1})"))
            return None
        except _Refused as refused:
            self.issues.append(TreeIssue(str(path), parser.CurrentLineNumber, str(refused)))
            return None
        if not found:
            self.issues.append(TreeIssue(str(path), 1, "no root element"))
            return None
        return found[0]

    def _import(self, element: ET.Element, importer: Path, seen: set[Path]) -> None:
        src = element.get("src") or element.get("file") or element.get("path")
        if not src:
            self.issue(element, f"<{element.tag}> needs src=\"other.xml\"")
            return
        target = (importer.parent / src).resolve()
        if target in seen:
            self.issue(element, f"{src} imports itself (through {importer.name})")
            return
        document = self.read(target, seen)
        if document is None:
            if not target.exists():
                self.issues.pop()
                self.issue(element, f"cannot import {src}: no file {target}")
            return

    def _declare(self, model: ET.Element) -> None:
        for element in model:
            kind = KINDS.get(element.tag.lower())
            node_id = element.get("ID")
            if kind is None:
                self.issue(element, f"<{element.tag}> in <TreeNodesModel>: expected one of "
                                    f"{', '.join(f'<{k}>' for k in KINDS.values())}")
                continue
            if not node_id:
                self.issue(element, f"<{element.tag}> in <TreeNodesModel> needs an ID")
                continue
            ports = {direction: tuple(port.get("name", "") for port in element if port.tag.lower() == direction)
                     for direction in _PORTS}
            path, line = self.where.get(id(element), (str(self.path), 0))
            declared = Declared(node_id, kind, ports["input_port"] + ports["inout_port"],
                                ports["output_port"] + ports["inout_port"], path, line)
            first = self.declared.setdefault(node_id, declared)
            if first.kind != kind:
                self.issue(element, f"{node_id} is declared a {kind} here and a {first.kind} at "
                                    f"{first.path}:{first.line}")

    def _define(self, element: ET.Element) -> None:
        identifier = element.get("ID")
        if not identifier:
            self.issue(element, "<BehaviorTree> needs an ID")
        elif identifier in self.trees:
            first = self.where.get(id(self.trees[identifier]), ("?", 0))
            self.issue(element, f"tree {identifier!r} is defined twice (first at {first[0]}:{first[1]})")
        else:
            self.trees[identifier] = element

    def main(self, document: ET.Element, main_tree: str | None) -> ET.Element | None:
        wanted = main_tree or document.get("main_tree_to_execute")
        if wanted is None:
            if len(self.trees) == 1:
                return next(iter(self.trees.values()))
            self.issue(document, "which tree is the main one? set main_tree_to_execute=\"ID\" "
                                  f"(trees: {', '.join(self.trees) or 'none'})")
            return None
        if wanted not in self.trees:
            self.issue(document, f"no tree {wanted!r} to execute{did_you_mean(wanted, self.trees)}")
            return None
        return self.trees[wanted]


class _Refused(Exception):
    pass
