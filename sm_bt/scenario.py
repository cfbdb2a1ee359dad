"""Scenarios: faults on a timeline and what must hold, for a mission run on simulated or ROS 2 nodes.

A scenario file (YAML) has ``events`` (each at a time of the run, in seconds) and ``expect``::

    events:
      - {at: 5.0, crash: laser_resender}            # also vanish, restart: NODE
      - {at: 6.0, fail_next: {node: amcl, transition: activate}}
      - {at: 7.0, hang_next: {node: amcl, transition: configure}}
      - {at: 8.0, reject_parameters: {node: controller_server, reason: busy}}   # reason: null clears
      - {at: 9.0, set_parameter: {node: controller_server, name: max_vel, value: 0.2}}
      - {at: 10, request: {pilot: f_degraded_mode}}  # a mode asked from outside (an operator)
      - {at: 15, world: {laser: broken}}             # an event of the scenario's world (below)
    expect:
      - {at: 3.0, modes: {pilot: active.f_normal_mode, amcl: active}}   # what holds then
      - {never: {laser_resender: finalized}}         # at no tick of the run
      - {tree: SUCCESS}                              # how the tree ends

:func:`load_scenario` reads it against a model, every mistake with its line; :class:`Checks`
applies the events and judges the expectations as a run goes (``sm-bt run --scenario``).

A tree whose own actions drive a simulated robot (the pilot's) needs that robot's world: the
scenario names it, ``world: MODULE:NAME`` (``NAME()`` makes a :class:`SimulatedWorld`), and its
events are ``{at: SECONDS, world: {NAME: VALUE}}``.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import py_trees
import yaml

from sm_bt.engine.clock import Clock
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, Transition, transition_by_label
from sm_bt.engine.manager import ModeManager
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, ParamValue
from sm_bt.trees.tree_documents import TreeIssue

_NODE_EVENTS = ("crash", "vanish", "restart")
_NODE_TRANSITION_EVENTS = ("fail_next", "hang_next")
EVENTS = (*_NODE_EVENTS, *_NODE_TRANSITION_EVENTS, "reject_parameters", "set_parameter", "request", "world")
_TREE_ENDS = ("SUCCESS", "FAILURE", "RUNNING")
#: What a scenario may name for ``sm-bt test`` to run it with: files relative to the scenario's
#: own (the model also as a bundled name), and the run's length in seconds.
SETUP = ("model", "tree", "stubs", "until", "world")


class MissionSystem(Protocol):
    """What a run ticks a mission against and a scenario's events act on: simulated nodes
    (:class:`~sm_bt.sim.SimulatedSystem`, virtual time) or ROS 2 nodes
    (:class:`~sm_bt.ros.mission_system.RosSystem`, real time)."""

    manager: ModeManager

    @property
    def clock(self) -> Clock: ...

    def run(self, seconds: float) -> None:
        """Let ``seconds`` of the run's time pass."""

    def tree(self, root: py_trees.behaviour.Behaviour, **setup: Any) -> py_trees.trees.BehaviourTree:
        """A tree around ``root``, set up with the manager, the clock and ``setup``."""

    def crash(self, node: str) -> None: ...

    def vanish(self, node: str) -> None: ...

    def restart(self, node: str) -> None: ...

    def fail_next(self, node: str, transition: Transition) -> None: ...

    def hang_next(self, node: str, transition: Transition) -> None: ...

    def reject_parameters(self, node: str, reason: str | None) -> None: ...

    def set_parameter(self, node: str, name: str, value: ParamValue) -> None: ...


class SimulatedWorld(Protocol):
    """What a tree's own actions act on, beside the nodes (the pilot's robot, battery and laser)."""

    #: The world's events and the values each takes: ``{"laser": ("broken", "repaired")}``.
    events: Mapping[str, tuple[str, ...]]

    def attach(self, system: MissionSystem) -> dict[str, Any]:
        """Couple the world to the run's system; the runtime objects the tree's setup gets."""

    def advance(self) -> None:
        """Called after each step of the run's time."""

    def event(self, name: str, value: str) -> None:
        """Make one of :attr:`events` happen; ``ValueError`` when it cannot be made now."""


def load_world(reference: str) -> SimulatedWorld:
    """``NAME()`` of the module ``MODULE`` for ``"MODULE:NAME"``; ``ValueError`` saying what is wrong."""
    module_name, _, name = reference.partition(":")
    if not module_name or not name:
        raise ValueError(f"world {reference!r} is not MODULE:NAME (e.g. sm_bt.trees.pilot.world:PilotWorld)")
    try:
        factory = getattr(importlib.import_module(module_name), name)
    except ImportError as error:
        raise ValueError(f"world {reference!r}: cannot import {module_name} ({error})") from None
    except AttributeError:
        raise ValueError(f"world {reference!r}: {module_name} has no {name}") from None
    world = factory()
    if not all(hasattr(world, member) for member in ("events", "attach", "advance", "event")):
        raise ValueError(f"world {reference!r} is not a world (events, attach, advance, event)")
    return world  # type: ignore[no-any-return]


@dataclass(frozen=True)
class Event:
    at: float
    kind: str
    args: dict[str, Any]
    line: int


@dataclass(frozen=True)
class Expectation:
    """``at`` (seconds) with ``modes``; ``never`` (``at`` None); or the ``tree``'s end."""

    line: int
    at: float | None = None
    modes: dict[str, StateMode] = field(default_factory=dict)
    never: dict[str, StateMode] = field(default_factory=dict)
    tree: str | None = None


@dataclass(frozen=True)
class Scenario:
    path: str
    events: tuple[Event, ...]
    expectations: tuple[Expectation, ...]

    def own_processes(self) -> set[str]:
        """The nodes whose process the events crash, end or restart: on ROS each runs alone."""
        return {event.args["node"] for event in self.events if event.kind in _NODE_EVENTS}


def scenario_setup(path: str | os.PathLike[str]) -> tuple[dict[str, str], list[TreeIssue]]:
    """What the scenario at ``path`` names to be run with (:data:`SETUP`: file paths made relative
    to the working folder), and what is wrong with that."""
    name = str(path)
    try:
        document = yaml.compose(Path(path).read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return {}, []  # load_scenario says what is wrong with the file
    setup: dict[str, str] = {}
    issues: list[TreeIssue] = []
    for key, value in document.value if isinstance(document, yaml.MappingNode) else ():
        if key.value in SETUP:
            if not isinstance(value, yaml.ScalarNode):
                issues.append(TreeIssue(name, value.start_mark.line + 1, f"{key.value} is a file's name or a number"))
                continue
            text = str(value.value)
            relative = os.path.normpath(Path(path).parent / text)
            if key.value in ("tree", "stubs") or (key.value == "model" and os.path.exists(relative)):
                text = relative
            setup[key.value] = text
    return setup, issues


def load_scenario(path: str | os.PathLike[str], model: Model,
                  world_events: Mapping[str, tuple[str, ...]] | None = None) -> tuple[Scenario, list[TreeIssue]]:
    """The scenario of the file at ``path``, read against ``model`` (and the events of its
    world, :attr:`SimulatedWorld.events`), and every mistake in it."""
    reader = _Reader(str(path), model, world_events or {})
    return reader.read(), reader.issues


class _Reader:
    def __init__(self, path: str, model: Model, world_events: Mapping[str, tuple[str, ...]]) -> None:
        self.path = path
        self.model = model
        self.world_events = world_events
        self.issues: list[TreeIssue] = []

    def wrong(self, node: yaml.Node | None, message: str) -> None:
        self.issues.append(TreeIssue(self.path, node.start_mark.line + 1 if node is not None else 0, message))

    def read(self) -> Scenario:
        empty = Scenario(self.path, (), ())
        try:
            document = yaml.compose(Path(self.path).read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
        except OSError as error:
            self.wrong(None, f"cannot read it: {error.strerror or error}")
            return empty
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            self.issues.append(TreeIssue(self.path, mark.line + 1 if mark else 0,
                                         f"not YAML: {getattr(error, 'problem', error)}"))
            return empty
        if not isinstance(document, yaml.MappingNode):
            self.wrong(document, "a scenario is a mapping with events: and expect:")
            return empty
        events: list[Event] = []
        expectations: list[Expectation] = []
        for key, value in document.value:
            if key.value == "events":
                events = [event for node in self._list(value) if (event := self._event(node)) is not None]
            elif key.value == "expect":
                expectations = [expected for node in self._list(value)
                                if (expected := self._expectation(node)) is not None]
            elif key.value not in SETUP:
                sections = ("events", "expect", *SETUP)
                self.wrong(key, f"no section {key.value!r}{did_you_mean(str(key.value), sections)} "
                                f"(sections: {', '.join(sections)})")
        return Scenario(self.path, tuple(sorted(events, key=lambda e: e.at)), tuple(expectations))

    def _list(self, node: yaml.Node) -> list[yaml.Node]:
        if not isinstance(node, yaml.SequenceNode):
            self.wrong(node, "a list is expected here (- {at: ..., ...})")
            return []
        return list(node.value)

    def _fields(self, node: yaml.Node) -> dict[str, yaml.Node] | None:
        if not isinstance(node, yaml.MappingNode):
            self.wrong(node, "a mapping is expected here ({at: SECONDS, ...})")
            return None
        return {str(key.value): value for key, value in node.value}

    def _seconds(self, node: yaml.Node) -> float | None:
        try:
            seconds = float(node.value)
        except (TypeError, ValueError):
            seconds = -1.0
        if not seconds >= 0:
            self.wrong(node, f"at is seconds of the run (0 or more), not {node.value!r}")
            return None
        return seconds

    def _node(self, node: yaml.Node) -> str | None:
        name = str(node.value)
        if not isinstance(self.model.parts.get(name), NodePart):
            nodes = [n.name for n in self.model.nodes]
            self.wrong(node, f"{name!r} is not a node of the model{did_you_mean(name, nodes)}")
            return None
        return name

    def _event(self, node: yaml.Node) -> Event | None:
        fields = self._fields(node)
        if fields is None:
            return None
        line = node.start_mark.line + 1
        kinds = [key for key in fields if key != "at"]
        if "at" not in fields or len(kinds) != 1:
            self.wrong(node, f"an event is {{at: SECONDS, KIND: ...}} with one kind of {', '.join(EVENTS)}")
            return None
        kind, value = kinds[0], fields[kinds[0]]
        at = self._seconds(fields["at"])
        if kind not in EVENTS:
            self.wrong(node, f"no event {kind!r}{did_you_mean(kind, EVENTS)} (events: {', '.join(EVENTS)})")
            return None
        args = self._event_args(kind, value)
        return None if at is None or args is None else Event(at, kind, args, line)

    def _event_args(self, kind: str, value: yaml.Node) -> dict[str, Any] | None:
        if kind in _NODE_EVENTS:
            node = self._node(value)
            return None if node is None else {"node": node}
        if kind == "request":
            wanted = self._modes(value, system_modes=True)
            return None if wanted is None else {"modes": wanted}
        if kind == "world":
            return self._world_event(value)
        fields = self._fields(value)
        if fields is None:
            return None
        needs = {"fail_next": ("node", "transition"), "hang_next": ("node", "transition"),
                 "reject_parameters": ("node", "reason"), "set_parameter": ("node", "name", "value")}[kind]
        if set(fields) != set(needs):
            self.wrong(value, f"{kind} takes {', '.join(needs)}")
            return None
        node = self._node(fields["node"])
        if node is None:
            return None
        args: dict[str, Any] = {"node": node}
        if "transition" in fields:
            label = str(fields["transition"].value)
            if label not in REQUESTABLE_LABELS:
                hint = did_you_mean(label, REQUESTABLE_LABELS)
                self.wrong(fields["transition"], f"{label!r} is not a transition{hint} "
                                                 f"(transitions: {', '.join(REQUESTABLE_LABELS)})")
                return None
            args["transition"] = transition_by_label(label, State.UNCONFIGURED)
        for name in ("reason", "name"):
            if name in fields:
                args[name] = None if fields[name].value in ("null", "~", "") else str(fields[name].value)
        if "value" in fields:
            args["value"] = yaml.safe_load(yaml.serialize(fields["value"]))
        return args

    def _world_event(self, node: yaml.Node) -> dict[str, Any] | None:
        fields = self._fields(node)
        if fields is None:
            return None
        if not self.world_events:
            self.wrong(node, "a world event needs the scenario's world (world: MODULE:NAME)")
            return None
        if len(fields) != 1:
            self.wrong(node, "a world event is {NAME: VALUE}, one at a time")
            return None
        (name, value), = fields.items()
        if name not in self.world_events:
            names = list(self.world_events)
            self.wrong(node, f"the world has no event {name!r}{did_you_mean(name, names)} (events: {', '.join(names)})")
            return None
        values = self.world_events[name]
        if str(value.value) not in values:
            self.wrong(value, f"{name} is one of {', '.join(values)}, not {value.value!r}"
                              f"{did_you_mean(str(value.value), values)}")
            return None
        return {"name": name, "value": str(value.value)}

    def _modes(self, node: yaml.Node, *, system_modes: bool = False) -> dict[str, StateMode] | None:
        fields = self._fields(node)
        if fields is None:
            return None
        found: dict[str, StateMode] = {}
        for part, value in fields.items():
            if part not in self.model.parts:
                self.wrong(value, f"no part {part!r}{did_you_mean(part, self.model.parts)}")
                return None
            text = str(value.value)
            try:
                found[part] = StateMode(State.ACTIVE, text) if system_modes else StateMode.parse(text)
            except ValueError as error:
                self.wrong(value, f"{part}: {error}")
                return None
            mode = found[part].mode
            if mode is not None and mode not in self.model.parts[part].modes:
                modes = self.model.parts[part].modes
                self.wrong(value, f"{part} has no mode {mode!r}{did_you_mean(mode, modes)} (modes: {', '.join(modes)})")
                return None
        return found

    def _expectation(self, node: yaml.Node) -> Expectation | None:
        fields = self._fields(node)
        if fields is None:
            return None
        line = node.start_mark.line + 1
        if "tree" in fields and len(fields) == 1:
            end = str(fields["tree"].value).upper()
            if end not in _TREE_ENDS:
                self.wrong(fields["tree"], f"tree ends as one of {', '.join(_TREE_ENDS)}, not {fields['tree'].value!r}")
                return None
            return Expectation(line, tree=end)
        if "never" in fields and len(fields) == 1:
            never = self._modes(fields["never"])
            return None if never is None else Expectation(line, never=never)
        if set(fields) == {"at", "modes"}:
            at, modes = self._seconds(fields["at"]), self._modes(fields["modes"])
            return None if at is None or modes is None else Expectation(line, at=at, modes=modes)
        self.wrong(node, "an expectation is {at: SECONDS, modes: {PART: STATE[.MODE]}}, {never: {PART: "
                         "STATE[.MODE]}} or {tree: SUCCESS|FAILURE|RUNNING}")
        return None


def holds(actual: Any, wanted: StateMode) -> bool:
    """Does the part's ``actual`` match ``wanted`` (its state; and its mode, when one is given)?"""
    return bool(actual.state is wanted.state and (wanted.mode is None or actual.mode == wanted.mode))


class Checks:
    """A scenario applied to a run: :meth:`at` after every tick (the events due, the expectations
    due), :meth:`end` with the tree's final status; ``failures`` says what did not hold, with the
    scenario's line."""

    def __init__(self, scenario: Scenario, system: MissionSystem, world: SimulatedWorld | None = None,
                 on_failure: Callable[[str], None] | None = None) -> None:
        self.scenario = scenario
        self.system = system
        self.world = world
        #: Told each failure as it is found (the run's view lists it).
        self.on_failure = on_failure
        #: The run's time of the first failure (``sm-bt view --at``).
        self.first_failure_at: float | None = None
        self._now = 0.0
        self.pending = list(scenario.events)
        self.due = sorted((e for e in scenario.expectations if e.at is not None), key=lambda e: e.at or 0.0)
        self.failures: list[str] = []
        self.passed: list[str] = []
        self._broken: set[tuple[int, str]] = set()

    def at(self, now: float) -> None:
        self._now = now
        while self.pending and self.pending[0].at <= now + 1e-9:
            self._apply(self.pending.pop(0))
        manager = self.system.manager
        while self.due and (self.due[0].at or 0.0) <= now + 1e-9:
            expectation = self.due.pop(0)
            for part, wanted in expectation.modes.items():
                actual = manager.actual(part)
                self._judge(expectation, holds(actual, wanted), f"at {expectation.at:g} s {part} is {actual}"
                            + ("" if holds(actual, wanted) else f", expected {wanted}"))
        for expectation in self.scenario.expectations:
            for part, unwanted in expectation.never.items():
                if (expectation.line, part) not in self._broken and holds(manager.actual(part), unwanted):
                    self._broken.add((expectation.line, part))
                    self._fail(f"{self._where(expectation)}: at {now:.2f} s {part} is {manager.actual(part)}, "
                               "which must never be")

    def end(self, status: str, now: float) -> None:
        self._now = now
        for expectation in self.due:  # never reached: the run ended before
            self._fail(f"{self._where(expectation)}: the run ended at {now:.2f} s, before {expectation.at:g} s")
        for expectation in self.scenario.expectations:
            if expectation.tree is not None:
                self._judge(expectation, status == expectation.tree, f"the tree ended {status}"
                            + ("" if status == expectation.tree else f", expected {expectation.tree}"))
            elif expectation.never:
                broken = {part for line, part in self._broken if line == expectation.line}
                if not broken:
                    self.passed.append(f"{self._where(expectation)}: never {self._describe(expectation.never)}")

    def _judge(self, expectation: Expectation, ok: bool, text: str) -> None:
        if ok:
            self.passed.append(f"{self._where(expectation)}: {text}")
        else:
            self._fail(f"{self._where(expectation)}: {text}")

    def _fail(self, text: str) -> None:
        self.failures.append(text)
        if self.first_failure_at is None:
            self.first_failure_at = self._now
        if self.on_failure is not None:
            self.on_failure(text)

    def _where(self, expectation: Expectation) -> str:
        return f"{self.scenario.path}:{expectation.line}"

    @staticmethod
    def _describe(modes: dict[str, StateMode]) -> str:
        return ", ".join(f"{part} {mode}" for part, mode in modes.items())

    def _apply(self, event: Event) -> None:
        try:
            self._carry_out(event)
        except (ValueError, KeyError) as error:  # e.g. crashing a node that is not running
            self._fail(f"{self.scenario.path}:{event.line}: the {event.kind} at {event.at:g} s could not be made: "
                       f"{error}")

    def _carry_out(self, event: Event) -> None:
        system, args = self.system, event.args
        if event.kind in _NODE_EVENTS:
            getattr(system, event.kind)(args["node"])
        elif event.kind in _NODE_TRANSITION_EVENTS:
            transition: Transition = args["transition"]
            getattr(system, event.kind)(args["node"], transition)
        elif event.kind == "reject_parameters":
            system.reject_parameters(args["node"], args["reason"])
        elif event.kind == "set_parameter":
            system.set_parameter(args["node"], args["name"], args["value"])
        elif event.kind == "world":
            if self.world is None:
                raise ValueError("the run has no world")
            self.world.event(args["name"], args["value"])
        else:
            for part, wanted in args["modes"].items():
                system.manager.change_mode(part, wanted.mode or "", requester="operator")
