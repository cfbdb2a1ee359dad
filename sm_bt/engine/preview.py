"""Previews: the plan a request would be carried out by, computed without doing anything.

:func:`preview` walks the same plan a request builds (:func:`~sm_bt.engine.plans.build_plan`:
the model's switching order, one step per node) and says for every node what its driver would
send from where the node is: the mode's parameter set first when the node's values are not the
mode's, then each lifecycle transition on the planned path (:class:`~sm_bt.engine.drivers.NodeDriver`
does exactly that). It says which rules would start or stop matching once the change is done,
and, when the change cannot be made, why, in the words a refused request uses.

A preview is of a configuration: the manager's own (live), or one given (:func:`configuration`,
e.g. every node unconfigured), so that a model alone can be previewed offline.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from sm_bt.engine.actual import Actual, NodeObservation, out_of_reach
from sm_bt.engine.drivers import Goal, NodeDriver
from sm_bt.engine.hierarchy import implied_targets
from sm_bt.engine.inference import Inference, infer_system
from sm_bt.engine.lifecycle import PlanError, plan
from sm_bt.engine.plans import Job, NodeJob, Parallel, Sequence, build_plan
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, ParamValue, Rule, SystemPart


@dataclass(frozen=True)
class ParameterChange:
    name: str
    old: ParamValue | None  # None: the node does not report it
    new: ParamValue

    def __str__(self) -> str:
        return f"{self.name} {self.old!r} -> {self.new!r}"


@dataclass(frozen=True)
class NodeSteps:
    """What a node's driver would send, in order (``calls``: "set parameters of mode FAST",
    "configure", "activate"), from ``start`` to ``goal``; the values that change."""

    node: str
    start: str  # its state (and mode) now
    goal: str
    calls: tuple[str, ...]
    parameters: tuple[ParameterChange, ...] = ()

    @property
    def changes(self) -> bool:
        return bool(self.calls)


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
    plan: SystemSteps | NodeSteps | None
    steps: tuple[NodeSteps, ...]
    unchanged: tuple[str, ...] = ()
    rules_start: tuple[str, ...] = ()
    rules_stop: tuple[str, ...] = ()
    refused: str = ""
    waits: tuple[str, ...] = ()
    calls: int = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "calls", sum(len(step.calls) for step in self.steps))

    @property
    def possible(self) -> bool:
        return not self.refused

    def as_json(self) -> dict[str, Any]:
        def steps_json(entry: SystemSteps | NodeSteps) -> dict[str, Any]:
            if isinstance(entry, NodeSteps):
                return {"node": entry.node, "start": entry.start, "goal": entry.goal, "calls": list(entry.calls),
                        "parameters": [{"name": c.name, "old": c.old, "new": c.new} for c in entry.parameters]}
            return {"system": entry.system, "target": entry.target,
                    "stages": [[steps_json(member) for member in stage] for stage in entry.stages]}

        return {"part": self.part, "target": self.target, "description": self.description,
                "possible": self.possible, "refused": self.refused, "calls": self.calls,
                "plan": steps_json(self.plan) if self.plan is not None else None,
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
                    out.extend(f"{pad}    {change}" for change in entry.parameters)
                else:
                    out.append(f"{pad}{entry.node}: {entry.goal} already")
                return
            out.append(f"{pad}{entry.system} -> {entry.target}")
            for index, stage in enumerate(entry.stages, 1):
                if len(entry.stages) > 1:
                    out.append(f"{pad}  stage {index}/{len(entry.stages)}")
                for member in stage:
                    walk(member, depth + (2 if len(entry.stages) > 1 else 1))

        if self.plan is not None and not self.refused:
            walk(self.plan, 1)
        out.extend(f"  waits: {text}" for text in self.waits)
        out.extend(f"  rule {name} would fire" for name in self.rules_start)
        out.extend(f"  rule {name} would no longer fire" for name in self.rules_stop)
        return out


class Configuration:
    """What a preview reads: node observations, targets and actuals (the manager's inference, or
    one made by :func:`configuration`)."""

    def __init__(self, inference: Inference) -> None:
        self.inference = inference

    def observation(self, node: str) -> NodeObservation:
        return self.inference.observation(node)

    def actual(self, part: str) -> Actual:
        return self.inference.actual(part)

    def target(self, part: str) -> StateMode | None:
        return self.inference.target(part)


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


class _Offline:
    """A plan's run that never runs: :func:`build_plan` only needs one to make its jobs."""

    active = False

    def defer(self, action: Callable[[], None]) -> None:
        pass

    def driver(self, node: str) -> NodeDriver:
        raise AssertionError("a preview drives nothing")

    def plan_done(self) -> None:
        pass

    def plan_failed(self, reason: str) -> None:
        pass


def node_steps(part: NodePart, obs: NodeObservation, goal: Goal) -> tuple[NodeSteps, str]:
    """What the node's driver would send to take it from ``obs`` to ``goal`` (as
    :meth:`NodeDriver.advance` does), and why it could not ("" when it can)."""
    start = _describe(part, obs)
    calls: list[str] = []
    changes: tuple[ParameterChange, ...] = ()
    mode = goal.mode if goal.state is State.ACTIVE else None
    if mode is not None and not mode.matches(obs.parameters):
        calls.append(f"set parameters of mode {mode.name}")
        changes = tuple(ParameterChange(name, obs.parameters.get(name), value) for name, value in mode.values().items()
                        if obs.parameters.get(name) != value)
    why = ""
    if obs.state.is_primary and obs.state is not goal.state:
        try:
            calls.extend(edge.transition.label for edge in plan(obs.state, goal.state))
        except PlanError as error:
            why = f"{part.name}: {error}"
    return NodeSteps(part.name, start, str(goal), tuple(calls), changes), why


def _describe(part: NodePart, obs: NodeObservation) -> str:
    if not obs.seen:
        return "not seen yet"
    if obs.state is not State.ACTIVE:
        return obs.state.label
    mode = next((name for name, spec in part.modes.items() if spec.matches(obs.parameters)), None)
    return f"active.{mode}" if mode is not None else "active (no mode)"


def preview(model: Model, config: Configuration, part: str, target: StateMode, description: str,
            refused: str = "") -> Preview:
    """The preview of taking ``part`` to ``target`` (an active mode resolved) from ``config``;
    ``refused``: a reason found before planning (an invalid transition)."""
    implied = implied_targets(model, part, target)
    root, jobs = build_plan(model, _Offline(), part, target)
    steps: dict[str, NodeSteps] = {}
    why: list[str] = [refused] if refused else []
    waits: list[str] = []
    for job in jobs:
        obs = config.observation(job.node)
        spec = model.parts[job.node]
        assert isinstance(spec, NodePart)
        reach = out_of_reach(job.node, obs, StateMode(job.goal.state))
        if reach:
            why.append(reach)
        elif not obs.seen:
            waits.append(f"{job.node} to appear")
        elif not obs.state.is_primary:
            waits.append(f"{job.node} to end its transition ({obs.state.label})")
        steps[job.node], cannot = node_steps(spec, obs, job.goal)
        if cannot and not reach:
            why.append(cannot)
    unchanged = tuple(name for name, value in implied if _there(config.actual(name), value, model))
    start, stop = _rules(model, config, dict(implied))
    return Preview(part, str(target), description, _tree(root, steps, dict(implied)), tuple(steps.values()),
                   unchanged, start, stop, "; ".join(why), tuple(waits))


def _there(actual: Actual, wanted: StateMode, model: Model) -> bool:
    mode = wanted.mode or (model.parts[actual.part].default_mode if wanted.state is State.ACTIVE else None)
    return actual.is_(StateMode(wanted.state, mode))


def _tree(root: Job, steps: Mapping[str, NodeSteps], targets: Mapping[str, StateMode]) -> SystemSteps | NodeSteps:
    """The plan's jobs as the preview's stages (systems by their ``system`` name)."""
    if isinstance(root, NodeJob):
        return steps[root.node]
    assert isinstance(root, Sequence)
    stages = []
    for stage in root.children:
        assert isinstance(stage, Parallel)
        stages.append(tuple(_tree(member, steps, targets) for member in stage.children))
    return SystemSteps(root.system, str(targets[root.system]), tuple(stages))


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
        return target == rule.if_target and actual.is_(rule.if_part_state)

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
