"""Mission trees from BehaviorTree.CPP/Groot-style XML, checked line by line.

sm_bt's behaviours are py_trees ports nodes, so ``py_trees.parsers.behaviour_tree_xml`` builds
them by class name. :func:`load_tree` puts a check in front of it, so that a mistake is an error
with the file and line, never a traceback::

    <root main_tree_to_execute="Mission">
      <BehaviorTree ID="Mission">
        <Sequence name="Mission" memory="true">
          <ChangeState name="Configure" part="pilot" transition="configure"/>
          <ChangeMode name="Normal" part="pilot" mode="f_normal_mode" timeout="10"/>
          <HoldMode name="Survey" part="pilot" mode="f_degraded_mode">
            <WaitForMode part="pilot" mode="f_degraded_mode" timeout="5"/>
          </HoldMode>
        </Sequence>
      </BehaviorTree>
    </root>

What is checked: the XML is well formed (no DOCTYPE: entities are refused); every tag is a
known node (a ports class of py_trees' registry or of ``registry``, a composite, a decorator,
``SubTree``); every attribute is a port or a constructor argument of its node, with a value of
the argument's type; required arguments are there; decorators have one child; ``SubTree`` IDs
exist; with a model (or manager), every part, mode and transition named exists. ``Import`` /
``Include`` of other files work as in py_trees, relative to the importing file.

BehaviorTree.CPP spellings are read too: ``ReactiveSequence``/``ReactiveFallback`` (no memory),
``Repeat num_cycles``, ``Retry num_attempts``, ``Timeout msec``. Behaviours get the XML ``name``
(the tag when there is none), not py_trees' parent-prefixed names.
"""

from __future__ import annotations

import inspect
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import py_trees
from py_trees.common import Status
from py_trees.parsers import behaviour_tree_xml as bt_xml
from py_trees.ports import PortsMixin, get_ports_registry, register_ports_class
from py_trees.ports_utils import NOOP_LOGGER, collect_type_hints, convert_str_to_type

from sm_bt.behaviours.idioms import _Subtree
from sm_bt.behaviours.manager_access import ManagerBehaviour, attach_manager
from sm_bt.engine.manager import ModeManager
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.errors import Error
from sm_bt.model.types import Model
from sm_bt.trees import bt_cpp_nodes  # noqa: F401 (registers BehaviorTree.CPP's nodes under their tags)
from sm_bt.trees.declared_nodes import STANDS_IN_FOR, stand_in
from sm_bt.trees.stubs import Stub
from sm_bt.trees.tree_documents import MAX_DEPTH, Declared, Documents, TreeIssue

__all__ = ["MAX_DEPTH", "AlwaysFailure", "AlwaysRunning", "AlwaysSuccess", "TreeFileError", "TreeIssue", "check_tree",
           "load_tree"]

_REFERENCE = re.compile(r"\{[^{}]+\}")
#: Deeper than this is refused (py_trees' builder recurses once per level).
_COMPOSITES = {"sequence", "selector", "fallback", "parallel"}
_REACTIVE = {"reactivesequence": "Sequence", "reactivefallback": "Fallback"}
_PARALLEL_POLICIES = ("success_on_all", "success_on_one")
# BehaviorTree.CPP's attribute names for py_trees' decorator arguments: (name, scale).
_CPP_ATTRIBUTES = {"repeat": {"num_cycles": ("num_success", 1.0)},
                   "retry": {"num_attempts": ("num_failures", 1.0)},
                   "timeout": {"msec": ("duration", 1e-3)}}
_NOT_ATTRIBUTES = {"self", "name", "manager", "child", "children", "behaviour_class_name"}


class _PlainLeaf(PortsMixin, register=False):
    INPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        self._subtree_namespace = subtree_namespace


class AlwaysSuccess(_PlainLeaf, py_trees.behaviour.Behaviour):
    """SUCCESS at once, every tick (py_trees' ``Success``; also ``<Success/>``)."""

    def update(self) -> Status:
        return Status.SUCCESS


class AlwaysFailure(_PlainLeaf, py_trees.behaviour.Behaviour):
    """FAILURE at once, every tick (py_trees' ``Failure``; also ``<Failure/>``)."""

    def update(self) -> Status:
        return Status.FAILURE


class AlwaysRunning(_PlainLeaf, py_trees.behaviour.Behaviour):
    """RUNNING, every tick (py_trees' ``Running``; also ``<Running/>``)."""

    def update(self) -> Status:
        return Status.RUNNING


for _tag, _cls in (("Success", AlwaysSuccess), ("Failure", AlwaysFailure), ("Running", AlwaysRunning)):
    register_ports_class(_tag, _cls)


class TreeFileError(Error):
    """A tree file could not be loaded; ``issues`` holds every mistake found, one per line of
    ``str(error)`` as ``file:line: error: message``."""

    def __init__(self, issues: list[TreeIssue]) -> None:
        self.issues = tuple(issues)
        super().__init__("\n".join(str(issue) for issue in self.issues))


def load_tree(path: str | os.PathLike[str], *, manager: ModeManager | None = None, model: Model | None = None,
              registry: Mapping[str, Any] | None = None, main_tree: str | None = None,
              inputs: Mapping[str, object] | None = None,
              stubs: Mapping[str, Stub] | None = None) -> py_trees.behaviour.Behaviour:
    """Build the tree of the XML file at ``path``; raise :class:`TreeFileError` with every
    mistake found. With ``manager``, it is attached to the tree (:func:`attach_manager`) and its
    model checked against; ``model`` alone checks without attaching. ``registry`` adds or
    overrides node classes (tag -> class or ``functools.partial``) over py_trees' registry of
    ports classes (which holds every sm_bt behaviour and every imported ports class). ``inputs``
    set the main tree's values (``<BehaviorTree ID="Pilot" cycles="2">``, read as ``{cycles}``).
    ``stubs`` (:func:`~sm_bt.trees.stubs.load_stubs`) say what stand-ins do: for a node the file
    declares in ``<TreeNodesModel>``, or one it only names (then it is an Action)."""
    if manager is not None and model is None:
        model = manager.model
    reader = _Reader(Path(path), model, {**get_ports_registry(), **(registry or {})}, stubs or {})
    root = reader.build(main_tree, {key: str(value) for key, value in (inputs or {}).items()})
    if manager is not None:
        attach_manager(root, manager)
    return root


def check_tree(path: str | os.PathLike[str], model: Model | None = None, *,
               registry: Mapping[str, Any] | None = None, main_tree: str | None = None,
               stubs: Mapping[str, Stub] | None = None) -> list[TreeIssue]:
    """Every mistake in the tree file at ``path`` (empty when it loads), against ``model``."""
    try:
        load_tree(path, model=model, registry=registry, main_tree=main_tree, stubs=stubs)
    except TreeFileError as error:
        return list(error.issues)
    return []


class _Reader:
    def __init__(self, path: Path, model: Model | None, registry: dict[str, Any], stubs: Mapping[str, Stub]) -> None:
        self.path = path
        self.model = model
        self.registry = registry
        self.stubs = stubs
        self.stubbed: set[str] = set()  # the stubs a node of the tree used
        self.documents = Documents(path)
        self.issues = self.documents.issues
        self.trees = self.documents.trees
        self.display: dict[str, str] = {}  # internal name -> the name to show

    # -- reading ---------------------------------------------------------------------------------

    def build(self, main_tree: str | None, inputs: dict[str, str]) -> py_trees.behaviour.Behaviour:
        document = self.documents.read(self.path, seen=set())
        if document is None:
            raise TreeFileError(self.issues)
        for node_id, declared in self.documents.declared.items():  # a class of its own wins
            if node_id not in self.registry and declared.kind in STANDS_IN_FOR:
                self.registry[node_id] = stand_in(declared, self.stubs.get(node_id))
        main = self.documents.main(document, main_tree)
        if main is not None:
            for key, value in inputs.items():
                main.set(key, value)
        for tree in self.trees.values():
            self._check_tree_element(tree)
        self._check_stubs()
        if self.issues or main is None:
            raise TreeFileError(self.issues or [TreeIssue(str(self.path), 0, "no tree to build")])
        try:
            remapping = bt_xml.build_subtree_remapping(main, self.trees, {}, "/", NOOP_LOGGER)
            root = bt_xml.build_tree_from_xml(main, remapping_table=remapping, node_registry=self.registry,
                                              bt_index=self.trees, subtree_namespace="/", parent_names_str="")
        except Exception as error:  # checked above: what is left has no line to name
            raise TreeFileError([TreeIssue(str(self.path), 0, f"py_trees could not build it: {error}")]) from None
        self._rename(root)
        return root

    def _issue(self, element: ET.Element | None, message: str) -> None:
        self.documents.issue(element, message)

    # -- checking -----------------------------------------------------------------------------------

    def _references(self, element: ET.Element) -> bool:
        """Every ``{...}`` in the element's attributes is a whole ``{key}`` value (py_trees raises on
        any other use of braces)."""
        ok = True
        for key, value in element.attrib.items():
            if key != "name" and ("{" in value or "}" in value) and not _REFERENCE.fullmatch(value):
                self._issue(element, f"{key}={value!r}: a blackboard reference is a whole value, {{key}}")
                ok = False
        return ok

    def _check_tree_element(self, tree: ET.Element) -> None:
        self._references(tree)
        children = list(tree)
        if len(children) != 1:
            self._issue(tree, f"<BehaviorTree ID={tree.get('ID')!r}> must hold exactly one node, not {len(children)}")
            return
        self._check(children[0])

    def _check(self, element: ET.Element) -> None:
        tag = element.tag
        lower = tag.lower()
        if lower in _REACTIVE:  # BehaviorTree.CPP: re-checks every child every tick
            element.tag = _REACTIVE[lower]
            element.set("memory", "false")
            tag, lower = element.tag, element.tag.lower()
        if not self._references(element):
            for child in element:  # its children may have mistakes of their own
                self._check(child)
            return
        if lower in ("subtree", "subtreeplus"):  # not a behaviour: its name is the subtree's namespace
            self._check_subtree(element)
            return
        self._name(element)
        if tag in self.stubs and tag not in self.registry:  # named only, stubbed: an Action
            path, line = self.documents.where.get(id(element), (str(self.path), 0))
            inputs = tuple(key for key in element.attrib if key != "name")
            self.registry[tag] = stand_in(Declared(tag, "Action", inputs, (), path, line), self.stubs[tag])
        if tag in self.stubs and getattr(self.registry.get(tag), "DECLARED", None) is not None:
            self.stubbed.add(tag)
        if tag in self.registry:
            self._check_node(element, self.registry[tag])
        elif lower in _COMPOSITES:
            self._check_composite(element)
        elif lower in bt_xml.DECORATOR_NODES:
            self._check_decorator(element, bt_xml.DECORATOR_NODES[lower])
        else:
            known = [*self.registry, "Sequence", "Fallback", "Selector", "Parallel", "SubTree",
                     *(cls.__name__ for cls in bt_xml.DECORATOR_NODES.values())]
            declared = self.documents.declared.get(tag)
            if declared is not None:
                self._issue(element, f"<{tag}> is declared a {declared.kind} ({declared.path}:{declared.line}): only "
                                     "declared Actions and Conditions run as stand-ins; a class for it is needed "
                                     "(registry=)")
            else:
                self._issue(element, f"unknown node <{tag}>{did_you_mean(tag, known)} (declare it in "
                                     "<TreeNodesModel> to run it as a stand-in, or pass its class in registry=)")
        for child in element:  # an unknown node's children are checked too: every mistake in one run
            self._check(child)

    def _check_stubs(self) -> None:
        for node_id, stub in self.stubs.items():
            if node_id in self.stubbed:
                continue
            own = self.registry.get(node_id)
            why = ("is a node sm_bt has: a stub stands in only for nodes it lacks"
                   if own is not None and getattr(own, "DECLARED", None) is None else "is no node of the tree")
            self.issues.append(TreeIssue(stub.path, stub.line, f"stub for {node_id}: {node_id} {why}"))

    def _name(self, element: ET.Element) -> None:
        internal = f"n{len(self.display)}"  # unique, so py_trees' duplicate-name check never trips
        self.display[internal] = element.get("name") or element.tag
        element.set("name", internal)

    def _check_composite(self, element: ET.Element) -> None:
        allowed = {"name", "memory"} | ({"policy"} if element.tag.lower() == "parallel" else set())
        self._unknown_attributes(element, allowed)
        memory = element.get("memory")
        if memory is not None and memory.lower() not in ("true", "false"):
            self._issue(element, f"memory must be true or false, not {memory!r}")
        policy = element.get("policy")
        if policy is not None and policy not in _PARALLEL_POLICIES:
            self._issue(element, f"policy must be one of {', '.join(_PARALLEL_POLICIES)}, not {policy!r}")

    def _check_decorator(self, element: ET.Element, cls: type) -> None:
        for cpp, (ours, scale) in _CPP_ATTRIBUTES.get(element.tag.lower(), {}).items():
            if cpp in element.attrib and ours not in element.attrib:
                value = element.attrib.pop(cpp)
                element.set(ours, _scaled(value, scale))
        if len(element) != 1:
            self._issue(element, f"<{element.tag}> decorates exactly one child, not {len(element)}")
        self._arguments(element, cls, ports=set(), constants=True)

    def _check_subtree(self, element: ET.Element) -> None:
        identifier = element.get("ID")
        if not identifier:
            self._issue(element, "<SubTree> needs the ID of a <BehaviorTree>")
        elif identifier not in self.trees:
            self._issue(element, f"no tree {identifier!r}{did_you_mean(identifier, self.trees)}")

    def _check_node(self, element: ET.Element, entry: Any) -> None:
        cls = entry.func if hasattr(entry, "func") else entry
        if not (inspect.isclass(cls) and issubclass(cls, PortsMixin)):
            self._issue(element, f"<{element.tag}> is registered as {entry!r}, not a ports class")
            return
        ports = set(cls.input_ports()) | set(cls.output_ports())
        arguments = self._arguments(element, cls, ports)
        if arguments is None:
            return
        # A composite or decorator (an idiom's subtree) is tried with a stand-in child.
        accepts = inspect.signature(cls.__init__).parameters
        if issubclass(cls, py_trees.composites.Composite) and "children" in accepts:
            arguments["children"] = [py_trees.behaviours.Success("stand-in") for _ in range(len(element))]
        elif issubclass(cls, py_trees.decorators.Decorator) and "child" in accepts:
            arguments["child"] = py_trees.behaviours.Success("stand-in")
        self._try_build(element, entry, arguments)

    def _arguments(self, element: ET.Element, cls: type, ports: set[str],
                   constants: bool = False) -> dict[str, Any] | None:
        """The constructor arguments of ``element`` converted to ``cls``'s type hints, after
        checking that every attribute is known and every required argument given. With
        ``constants``, ``{key}`` may name a value of the enclosing tree (py_trees' decorators)."""
        parameters = _parameters(cls)
        allowed = {"name"} | ports | set(parameters)
        if not self._unknown_attributes(element, allowed):
            return None
        missing = [name for name, parameter in parameters.items()
                   if parameter.default is inspect.Parameter.empty and name not in element.attrib]
        if missing:
            self._issue(element, f"<{element.tag}> needs {', '.join(missing)}")
            return None
        given = {key: value for key, value in element.attrib.items() if key in parameters}
        if constants:
            given = {key: value for key, value in given.items() if not bt_xml.is_key(value)}
        for key, value in given.items():
            if bt_xml.is_key(value):
                self._issue(element, f"{key}={value!r}: only ports take blackboard keys; {key} is fixed at load "
                                     f"(ports of <{element.tag}>: {', '.join(sorted(ports)) or 'none'})")
                return None
        hints = collect_type_hints(cls)
        converted: dict[str, Any] = {}
        for key, value in given.items():
            hint = hints.get(key)
            try:
                ok, converted[key] = (True, value) if hint is None else convert_str_to_type(value, hint, NOOP_LOGGER)
            except Exception:  # py_trees raises for some types, returns False for others
                ok, converted[key] = False, value
            if not ok and hint in (int, float, bool):  # other hints: the constructor judges
                self._issue(element, f"{key}={value!r} is not {_a(hint)}")
                return None
            if not ok:
                converted[key] = value
        return converted

    def _unknown_attributes(self, element: ET.Element, allowed: set[str]) -> bool:
        unknown = [key for key in element.attrib if key not in allowed]
        for key in unknown:
            self._issue(element, f"<{element.tag}> has no attribute {key!r}{did_you_mean(key, allowed)} "
                                 f"(attributes: {', '.join(sorted(allowed))})")
        return not unknown

    def _try_build(self, element: ET.Element, entry: Any, arguments: dict[str, Any]) -> None:
        """Build the node once (then drop it) to check its arguments and, for sm_bt behaviours,
        the parts and modes it names."""
        name = self.display[element.get("name", "")]
        try:
            node = entry(name=name, behaviour_class_name=element.tag, **arguments)
        except Exception as error:
            self._issue(element, f"<{element.tag} {name!r}>: {_without(name, error)}")
            return
        try:
            for behaviour in node.iterate():
                if self.model is not None and isinstance(behaviour, ManagerBehaviour):
                    behaviour.check_model(self.model)
        except ValueError as error:
            self._issue(element, f"<{element.tag} {name!r}>: {_without(behaviour.qualified_name, error)}")
        finally:
            for behaviour in node.iterate():
                for client in behaviour.blackboards:
                    client.unregister(clear=False)

    # -- after py_trees built it --------------------------------------------------------------------

    def _rename(self, root: py_trees.behaviour.Behaviour) -> None:
        for behaviour in root.iterate():
            internal = behaviour.name.rsplit(".", 1)[-1]
            shown = self.display.get(internal)
            if shown is None:
                continue  # made by a node itself (an idiom's inner behaviours)
            behaviour.name = shown
            for client in behaviour.blackboards:
                if client.name.rsplit(".", 1)[-1] == internal:
                    object.__setattr__(client, "name", shown)
                    py_trees.blackboard.Blackboard.clients[client.id()] = shown


def _parameters(cls: type) -> dict[str, inspect.Parameter]:
    """The named constructor arguments of ``cls`` and its bases (the most derived wins)."""
    found: dict[str, inspect.Parameter] = {}
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        try:
            signature = inspect.signature(init)
        except (TypeError, ValueError):
            continue
        takes_more = False
        for name, parameter in signature.parameters.items():
            if parameter.kind is inspect.Parameter.VAR_KEYWORD:
                takes_more = True
            elif parameter.kind is not inspect.Parameter.VAR_POSITIONAL and name not in _NOT_ATTRIBUTES:
                found.setdefault(name, parameter)
        # A base's arguments are reachable only through **kwargs; sm_bt's own classes pass
        # **kwargs to PortsMixin alone (behaviour_class_name), never their base's arguments.
        if not takes_more or issubclass(klass, (ManagerBehaviour, _Subtree)):
            break
    return found


def _a(hint: type) -> str:
    return {int: "a whole number", float: "a number", bool: "true or false"}.get(hint, hint.__name__)


def _scaled(value: str, scale: float) -> str:
    if scale == 1.0:
        return value
    try:
        return repr(float(value) * scale)
    except ValueError:
        return value  # the decorator's own check names it


def _without(name: str, error: Exception) -> str:
    """An error message without the behaviour-name prefix (the line already says where)."""
    text = str(error)
    for prefix in (f"{name}: ",):
        if text.startswith(prefix):
            return text[len(prefix):]
    return text
