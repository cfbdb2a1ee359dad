"""Previews: the plan a request would be carried out by, computed without doing anything.

:func:`preview` walks the same plan a request builds (:func:`~sm_bt.engine.plans.plan_tree`:
the model's switching order, one step per node) and says for every node what its driver would
send from where the node is: the mode's parameter set first when the node's values are not the
mode's, then each lifecycle transition on the planned path (:class:`~sm_bt.engine.drivers.NodeDriver`
does exactly that). It says which rules would start or stop matching once the change is done,
and, when the change cannot be made, why, in the words a refused request uses.

A preview is of a configuration: the manager's own (live), or one given (:func:`configuration`,
e.g. every node unconfigured), so that a model alone can be previewed offline.
"""

from __future__ import annotations

import functools
from collections import ChainMap
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from sm_bt.engine.actual import Actual, NodeObservation, out_of_reach
from sm_bt.engine.hierarchy import implied_targets
from sm_bt.engine.inference import Inference, infer_system
from sm_bt.engine.lifecycle import PlanError, plan
from sm_bt.engine.plans import PlanEntry, Shapes, plan_tree
from sm_bt.model.states import PRIMARY_STATES, State, StateMode
from sm_bt.model.types import Model, NodeMode, NodePart, ParamValue, Rule, SystemPart

#: A parameter that changes: (name, old value or None when the node does not report it, new value).
ParameterChange = tuple[str, "ParamValue | None", ParamValue]


def describe_change(change: ParameterChange) -> str:
    name, old, new = change
    return f"{name} {old!r} -> {new!r}"


class NodeSteps:
    """What a node's driver would send, in order (``calls``: "set parameters of mode FAST",
    "configure", "activate"), from ``start`` to ``goal``; ``parameters``: the values that change,
    worked out when first read (a preview of 10,000 nodes makes one of these per node)."""

    __slots__ = ("_changes", "_mode", "_observed", "_start", "calls", "goal", "node")

    def __init__(self, node: str, start: Actual | str, goal: str, calls: tuple[str, ...],
                 mode: NodeMode | None = None, observed: Mapping[str, ParamValue] | None = None) -> None:
        self.node, self._start, self.goal, self.calls = node, start, goal, calls
        self._mode, self._observed = mode, observed  # what the node reported then, when a set is sent
        self._changes: tuple[ParameterChange, ...] | None = None

    @property
    def changes(self) -> bool:
        return bool(self.calls)

    @property
    def start(self) -> str:
        """Where the node is, as a person reads it (``active.__DEFAULT__``, ``not seen yet``)."""
        return str(self._start)

    @property
    def parameters(self) -> tuple[ParameterChange, ...]:
        if self._changes is None:
            self._changes = ()
            if self._mode is not None and self._observed is not None:
                get = self._observed.get
                self._changes = tuple([(key, get(key), spec.value) for key, spec in self._mode.parameters.items()
                                       if get(key) != spec.value])
        return self._changes

    def __repr__(self) -> str:
        return f"NodeSteps({self.node!r}, {self.start!r} -> {self.goal!r}: {', '.join(self.calls)})"


@dataclass(frozen=True)
class SystemSteps:
    """A system's switching order: its stages, one after another, each run together."""

    system: str
    target: str
    stages: tuple[tuple[SystemSteps | NodeSteps, ...], ...]


@dataclass(frozen=True)
class Preview:
    """The plan of a change, from the configuration it was previewed in.

    ``plan``: the stages (a system's) or the node's steps; ``steps``: every node's, in plan
    order; ``unchanged``: the parts already where the change takes them; ``rules_start`` and
    ``rules_stop``: rules whose condition holds once the change is done and not now, and the
    other way round; ``refused``: why the change cannot be made now ("" when it can, in the
    words a refused request would use); ``waits``: what it would wait for (a node not seen yet,
    one in a transition)."""

    part: str
    target: str
    description: str
    shape: PlanEntry = field(repr=False)  # the plan's shape (plans.plan_tree): ``plan`` is made of it when read
    steps: tuple[NodeSteps, ...]
    unchanged: tuple[str, ...] = ()
    rules_start: tuple[str, ...] = ()
    rules_stop: tuple[str, ...] = ()
    refused: str = ""
    waits: tuple[str, ...] = ()

    @functools.cached_property
    def calls(self) -> int:
        """How many calls the manager would send."""
        return sum(len(step.calls) for step in self.steps)

    @property
    def possible(self) -> bool:
        return not self.refused

    @functools.cached_property
    def plan(self) -> SystemSteps | NodeSteps:
        """The stages (a system's, each the parts run together) or the node's steps."""
        return _tree(self.shape, {step.node: step for step in self.steps})

    def as_json(self) -> dict[str, Any]:
        def steps_json(entry: SystemSteps | NodeSteps) -> dict[str, Any]:
            if isinstance(entry, NodeSteps):
                return {"node": entry.node, "start": entry.start, "goal": entry.goal, "calls": list(entry.calls),
                        "parameters": [{"name": name, "old": old, "new": new} for name, old, new in entry.parameters]}
            return {"system": entry.system, "target": entry.target,
                    "stages": [[steps_json(member) for member in stage] for stage in entry.stages]}

        return {"part": self.part, "target": self.target, "description": self.description,
                "possible": self.possible, "refused": self.refused, "calls": self.calls,
                "plan": steps_json(self.plan),
                "unchanged": list(self.unchanged), "rules_start": list(self.rules_start),
                "rules_stop": list(self.rules_stop), "waits": list(self.waits)}

    def summary(self, nodes: int = 4) -> str:
        """One line: the calls, node by node (the first ``nodes`` that change), or why not."""
        if self.refused:
            return f"cannot be made now: {self.refused}"
        changing = [step for step in self.steps if step.changes]
        if not changing:
            return "nothing to do"
        shown = ", ".join(f"{step.node} " + "+".join(call.replace("set parameters of mode ", "set ")
                                                     for call in step.calls) for step in changing[:nodes])
        more = f" (+{len(changing) - nodes} more nodes)" if len(changing) > nodes else ""
        return f"{self.calls} call{'s' if self.calls != 1 else ''}: {shown}{more}"

    def lines(self) -> list[str]:
        """The preview as a person reads it: a line per stage and per node's steps."""
        head = f"{self.description}: " + (f"cannot be made now: {self.refused}" if self.refused else
                                          f"{self.calls} call{'s' if self.calls != 1 else ''}")
        out = [head]

        def walk(entry: SystemSteps | NodeSteps, depth: int) -> None:
            pad = "  " * depth
            if isinstance(entry, NodeSteps):
                if entry.changes:
                    out.append(f"{pad}{entry.node}: {entry.start} -> {entry.goal}: {', '.join(entry.calls)}")
                    out.extend(f"{pad}    {describe_change(change)}" for change in entry.parameters)
                else:
                    out.append(f"{pad}{entry.node}: {entry.goal} already")
                return
            out.append(f"{pad}{entry.system} -> {entry.target}")
            for index, stage in enumerate(entry.stages, 1):
                if len(entry.stages) > 1:
                    out.append(f"{pad}  stage {index}/{len(entry.stages)}")
                for member in stage:
                    walk(member, depth + (2 if len(entry.stages) > 1 else 1))

        if not self.refused:
            walk(self.plan, 1)
        out.extend(f"  waits: {text}" for text in self.waits)
        out.extend(f"  rule {name} would fire" for name in self.rules_start)
        out.extend(f"  rule {name} would no longer fire" for name in self.rules_stop)
        return out


class Configuration:
    """What a preview reads: node observations, targets and actuals (the manager's inference, one
    made by :func:`configuration`, or what :meth:`kept` kept of one)."""

    def __init__(self, inference: Inference, observations: Mapping[str, NodeObservation] | None = None,
                 actuals: Mapping[str, Actual] | None = None,
                 targets: Mapping[str, StateMode | None] | None = None) -> None:
        self.inference = inference
        #: Read-only views, for a preview's loop over every node (a kept configuration's own first).
        self.observations: Mapping[str, NodeObservation] = (
            ChainMap(dict(observations), inference.observations) if observations is not None  # type: ignore[arg-type]
            else inference.observations)
        self.actuals: Mapping[str, Actual] = (ChainMap(dict(actuals), inference.actuals)  # type: ignore[arg-type]
                                              if actuals is not None else inference.actuals)
        self._targets = dict(targets or {})

    def kept(self, parts: Iterable[str]) -> Configuration:
        """These parts as they are now, kept for a preview made later (the rest read live)."""
        inference, observations, actuals, targets = self.inference, {}, {}, {}
        for name in parts:
            if name in inference.observations:
                obs = inference.observations[name]
                # A copy: state and gone change in place; parameters are replaced, never updated.
                observations[name] = NodeObservation(obs.seen, obs.state, obs.parameters, obs.lifecycle, obs.gone)
            actuals[name] = inference.actuals[name]
            targets[name] = inference.target(name)
        return Configuration(inference, observations, actuals, targets)

    def observation(self, node: str) -> NodeObservation:
        return self.observations[node]

    def actual(self, part: str) -> Actual:
        return self.actuals[part]

    def target(self, part: str) -> StateMode | None:
        return self._targets[part] if part in self._targets else self.inference.target(part)


def configuration(model: Model, nodes: Mapping[str, StateMode] | None = None,
                  default: State = State.UNCONFIGURED) -> Configuration:
    """A configuration of ``model`` to preview from: each node in ``nodes``' state (with its
    mode's parameter values, the default mode's when none is given), the others in ``default``
    with their default mode's values; every part's target its actual."""
    inference = Inference(model)
    given = dict(nodes or {})
    for node in model.nodes:
        value = given.get(node.name, StateMode(default))
        mode = node.modes[value.mode if value.mode is not None and value.mode in node.modes else node.default_mode]
        inference.node_appeared(node.name, value.state, mode.values())
    for name in model.parts:
        actual = inference.actual(name)
        if actual.state is not State.UNKNOWN:
            inference.set_target(name, StateMode(actual.state, actual.mode if actual.state is State.ACTIVE else None))
    return Configuration(inference)


def nodes_of(model: Model, targets: Mapping[str, StateMode]) -> dict[str, StateMode]:
    """The node states and modes that ``targets`` of some parts imply (``--from pilot=active.f_normal_mode``)."""
    found: dict[str, StateMode] = {}
    for part, target in targets.items():
        for name, value in implied_targets(model, part, target):
            if isinstance(model.parts[name], NodePart):
                found.setdefault(name, value)
    return found


def node_steps(name: str, obs: NodeObservation, state: State, mode: NodeMode | None,
               start: Actual | str) -> tuple[NodeSteps, str]:
    """What the node's driver would send to take it from ``obs`` to ``state`` (in ``mode`` when
    active), as :meth:`NodeDriver.advance` does, and why it could not ("" when it can); ``start``:
    where the node is, as a person reads it."""
    calls: tuple[str, ...] = ()
    observed = None
    if mode is not None and not mode.matches(obs.parameters):
        calls = (mode.set_label,)
        observed = obs.parameters  # never changed in place (Inference.node_parameters): what it was now
    why = ""
    if obs.state is not state and obs.state in PRIMARY_STATES:
        try:
            calls += tuple([edge.transition.label for edge in plan(obs.state, state)])
        except PlanError as error:
            why = f"{name}: {error}"
    goal = _LABELS[state] if mode is None else mode.active_label
    return NodeSteps(name, start, goal, calls, mode, observed), why


_LABELS = {state: state.label for state in State}


def preview(model: Model, config: Configuration, part: str, target: StateMode, description: str,
            refused: str = "", shapes: Shapes | None = None) -> Preview:
    """The preview of taking ``part`` to ``target`` (an active mode resolved) from ``config``;
    ``refused``: a reason found before planning (an invalid transition); ``shapes``: where the
    plan's shape may already be."""
    root, nodes = shapes.get(part, target) if shapes is not None else plan_tree(model, part, target)
    steps: dict[str, NodeSteps] = {}
    why: list[str] = [refused] if refused else []
    waits: list[str] = []
    parts, observations, actuals = model.parts, config.observations, config.actuals
    active, primary = State.ACTIVE, PRIMARY_STATES
    unchanged: list[str] = []
    for name, value, _ in nodes:
        spec: NodePart = parts[name]  # type: ignore[assignment]  # a plan's leaves are nodes
        obs = observations[name]
        state = value.state
        mode = spec.modes[value.mode or spec.default_mode] if state is active else None
        reach = ""
        if not obs.seen or obs.gone or obs.state not in primary:  # not the usual case: say why it waits or not
            reach = out_of_reach(name, obs, value)
            if reach:
                why.append(reach)
            elif not obs.seen:
                waits.append(f"{name} to appear")
            elif obs.state is not State.FINALIZED:
                waits.append(f"{name} to end its transition ({obs.state.label})")
        step, cannot = node_steps(name, obs, state, mode, actuals[name] if obs.seen else "not seen yet")
        steps[name] = step
        if cannot and not reach:
            why.append(cannot)
        elif not step.calls and obs.seen and not obs.gone and obs.state in primary:
            unchanged.append(name)
    targets = _targets(root)
    unchanged.extend(name for name, value in targets.items()
                     if name not in steps and _there(actuals[name], value, model))
    start_rules, stop_rules = _rules(model, config, targets)
    return Preview(part, str(target), description, root, tuple(steps.values()), tuple(unchanged),
                   start_rules, stop_rules, "; ".join(why), tuple(waits))


def _there(actual: Actual, wanted: StateMode, model: Model) -> bool:
    mode = wanted.mode or (model.parts[actual.part].default_mode if wanted.state is State.ACTIVE else None)
    return actual.is_(StateMode(wanted.state, mode))


def _entries(root: PlanEntry) -> list[PlanEntry]:
    """Every entry of a plan's shape, each system before the entries below it (no recursion: a
    hierarchy may be deep)."""
    order: list[PlanEntry] = []
    stack = [root]
    while stack:
        entry = stack.pop()
        order.append(entry)
        for stage in entry[2] or ():
            stack.extend(stage)
    return order


def _targets(root: PlanEntry) -> dict[str, StateMode]:
    return {entry[0]: entry[1] for entry in _entries(root)}


def _tree(root: PlanEntry, steps: Mapping[str, NodeSteps]) -> SystemSteps | NodeSteps:
    """The plan's shape as the preview's stages."""
    made: dict[int, SystemSteps | NodeSteps] = {}
    for entry in reversed(_entries(root)):  # parts below first
        name, value, stages = entry
        made[id(entry)] = steps[name] if stages is None else SystemSteps(
            name, str(value), tuple(tuple(made[id(member)] for member in stage) for stage in stages if stage))
    return made[id(root)]


def _rules(model: Model, config: Configuration, targets: Mapping[str, StateMode]) -> tuple[tuple[str, ...],
                                                                                           tuple[str, ...]]:
    """Rules whose condition starts, and stops, holding once every part in ``targets`` is there."""
    after: dict[str, Actual] = {}

    def actual_after(name: str) -> Actual:
        if name in after:
            return after[name]
        spec = model.parts[name]
        if name in targets:
            value = targets[name]
            mode = value.mode or (spec.default_mode if value.state is State.ACTIVE else None)
            result = Actual(name, value.state, mode if value.state is State.ACTIVE else None)
        elif isinstance(spec, SystemPart) and any(child in targets or _above(model, child, targets)
                                                  for child in spec.parts):
            result = infer_system(spec, actual_after, config.target(name))
        else:
            result = config.actual(name)
        after[name] = result
        return result

    def holds(rule: Rule, target: StateMode | None, actual: Actual) -> bool:
        return target == rule.if_target and actual.meets(rule.if_part_state)

    start: list[str] = []
    stop: list[str] = []
    for system in model.systems:
        for rule in system.rules:
            now = holds(rule, config.target(system.name), config.actual(rule.if_part))
            later = holds(rule, targets.get(system.name, config.target(system.name)), actual_after(rule.if_part))
            if later and not now:
                start.append(f"{rule.name} ({system.name}: {rule.if_part} is {rule.if_part_state} -> "
                             f"{rule.new_target})")
            elif now and not later:
                stop.append(rule.name)
    return tuple(start), tuple(stop)


def _above(model: Model, part: str, targets: Mapping[str, StateMode]) -> bool:
    """Does a part in ``targets`` sit below ``part``?"""
    spec = model.parts[part]
    stack = list(spec.parts) if isinstance(spec, SystemPart) else []
    seen: set[str] = set()
    while stack:
        name = stack.pop()
        if name in targets:
            return True
        if name in seen:
            continue
        seen.add(name)
        child = model.parts[name]
        if isinstance(child, SystemPart):
            stack.extend(child.parts)
    return False
