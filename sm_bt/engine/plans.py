"""Execution plans: what a target asks of each node, in the model's switching order.

A plan is a tree of jobs: a :class:`NodeJob` takes one node to its goal (through the node's
:class:`~sm_bt.engine.drivers.NodeDriver`); :class:`Sequence` runs the stages of a switching
order one after another, :class:`Parallel` the parts of one stage together. Progress is pushed,
not polled: a step that reaches its goal tells its parent, which starts what comes next. Every
hand-over goes through the run's agenda (``defer``), so nothing recurses however deep the
hierarchy is, and the work per node report is proportional to what it changes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, cast

from sm_bt.engine.drivers import Goal, NodeDriver
from sm_bt.engine.hierarchy import child_targets
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, SystemPart


class Run(Protocol):
    """The execution a plan belongs to."""

    @property
    def active(self) -> bool:
        """False once the execution finished: late hand-overs are then ignored."""

    def defer(self, action: Callable[[], None]) -> None:
        """Run ``action`` once the current one is over (the manager's agenda)."""

    def driver(self, node: str) -> NodeDriver: ...

    def plan_done(self) -> None: ...

    def plan_failed(self, reason: str) -> None: ...


class _Over:
    """The run of a dismantled plan: over, so that a late hand-over to one of its jobs is ignored."""

    active = False

    def defer(self, action: Callable[[], None]) -> None:
        pass

    def driver(self, node: str) -> NodeDriver:
        raise RuntimeError(f"a dismantled plan drives no node ({node})")

    def plan_done(self) -> None:
        pass

    def plan_failed(self, reason: str) -> None:
        pass


OVER: Run = _Over()


class Job:
    parent: _Composite | None = None
    done = False

    def __init__(self, run: Run) -> None:
        self.run = run

    def start(self) -> None:
        raise NotImplementedError

    def dismantle(self) -> None:
        """Its execution is over for good: drop the links up the tree and to the execution, so that
        the plan holds no reference cycle and is freed as soon as nothing refers to it, rather than
        by the garbage collector some time later (a big request's plan is tens of megabytes)."""
        self.parent = None
        self.run = OVER

    def _finished(self) -> None:
        self.done = True
        parent = self.parent
        if parent is None:
            self.run.defer(self.run.plan_done)
        else:
            self.run.defer(lambda: parent.child_done(self))


class NodeJob(Job):
    """Take ``node`` to ``goal``; once there, watch it until the execution ends."""

    def __init__(self, run: Run, node: str, goal: Goal) -> None:
        super().__init__(run)
        self.node = node
        self._goal = goal
        self.started = False

    @property
    def goal(self) -> Goal:
        return self._goal

    @property
    def reached_goal(self) -> bool:
        return self.done

    def start(self) -> None:
        if self.run.active:
            self.started = True
            self.run.driver(self.node).assign(self)

    def reached(self) -> None:
        if self.run.active and not self.done:
            self._finished()

    def failed(self, reason: str) -> None:
        if self.run.active:
            self.run.plan_failed(reason)

    def release(self) -> None:
        self.run.driver(self.node).release(self)


class _Composite(Job):
    def __init__(self, run: Run) -> None:
        super().__init__(run)
        self.children: list[Job] = []

    def child_done(self, child: Job) -> None:
        raise NotImplementedError

    def dismantle(self) -> None:
        stack: list[Job] = [self]  # a loop, not recursion: a hierarchy may be thousands deep
        while stack:
            job = stack.pop()
            if isinstance(job, _Composite):
                stack.extend(job.children)
                job.children = []
            Job.dismantle(job)


class Sequence(_Composite):
    """Children one after another (the stages of ``system``'s switching order)."""

    index = 0
    system = ""

    def start(self) -> None:
        self._next()

    def child_done(self, child: Job) -> None:
        if self.run.active:
            self.index += 1
            self._next()

    def _next(self) -> None:
        if self.index < len(self.children):
            self.run.defer(self.children[self.index].start)
        else:
            self._finished()


class Parallel(_Composite):
    """Children all at once (one stage)."""

    left = 0

    def start(self) -> None:
        self.left = len(self.children)
        if not self.children:
            self._finished()
        for child in self.children:
            self.run.defer(child.start)

    def child_done(self, child: Job) -> None:
        if self.run.active:
            self.left -= 1
            if self.left == 0:
                self._finished()


#: A plan's shape: ``(part, target, stages)``, ``stages`` ``None`` for a node, else the system's
#: stages in order, each a list of the entries run together.
PlanEntry = tuple[str, StateMode, "list[list[PlanEntry]] | None"]


def plan_tree(model: Model, part: str, target: StateMode,
              only: frozenset[str] | None = None) -> tuple[PlanEntry, list[PlanEntry]]:
    """The shape of the plan taking ``part`` to ``target``, and its node entries in plan order.

    A system's target becomes its switching order's stages, each the parts run together; going to
    a non-active state, the parts are taken down in the reverse order of the default mode's
    stages. A node shared by two systems appears once, at its first place (the one
    :func:`~sm_bt.engine.hierarchy.implied_targets` gives its target). With ``only``, only those
    nodes (in the same order; the others are left out). The one place that decides the order:
    :func:`build_plan` makes jobs of it, previews read it.
    """
    nodes: list[PlanEntry] = []
    seen: set[str] = set()
    top: list[PlanEntry] = []
    # Top-down without recursion: each entry is a part to expand and the list it joins (pushed
    # reversed, so every list fills in model order).
    stack: list[tuple[str, StateMode, list[PlanEntry]]] = [(part, target, top)]
    while stack:
        name, value, into = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        spec = model.parts[name]
        if isinstance(spec, NodePart):
            if only is not None and name not in only:
                continue
            entry: PlanEntry = (name, value, None)
            nodes.append(entry)
            into.append(entry)
            continue
        wanted = dict(child_targets(spec, value))
        stages: list[list[PlanEntry]] = []
        into.append((name, value, stages))
        pending: list[tuple[str, StateMode, list[PlanEntry]]] = []
        for stage in _stages(spec, value):
            members = [child for child in stage if child in wanted]
            if members:
                together: list[PlanEntry] = []
                stages.append(together)
                pending.extend((child, wanted[child], together) for child in members)
        stack.extend(reversed(pending))
    return top[0], nodes


class Shapes:
    """The plan shapes of the last few (part, target) asked for: a model's shapes never change,
    and a preview, then the request it previewed, ask for the same one (at 10,000 nodes a shape
    takes about 10 ms to make)."""

    def __init__(self, model: Model, size: int = 4) -> None:
        self.model = model
        self.size = size
        self._kept: dict[tuple[str, StateMode], tuple[PlanEntry, list[PlanEntry]]] = {}

    def get(self, part: str, target: StateMode) -> tuple[PlanEntry, list[PlanEntry]]:
        key = (part, target)
        shape = self._kept.pop(key, None)
        if shape is None:
            shape = plan_tree(self.model, part, target)
            while len(self._kept) >= self.size:
                del self._kept[next(iter(self._kept))]  # the least recently asked for
        self._kept[key] = shape
        return shape


def build_plan(model: Model, run: Run, part: str, target: StateMode,
               only: frozenset[str] | None = None, shapes: Shapes | None = None) -> tuple[Job, list[NodeJob]]:
    """The plan taking ``part`` to ``target`` (:func:`plan_tree`'s shape as jobs: a
    :class:`Sequence` of a system's stages, each a :class:`Parallel` of its parts, a
    :class:`NodeJob` per node), and its steps in plan order; ``shapes``: where a shape may
    already be (not with ``only``)."""
    root, nodes = shapes.get(part, target) if shapes is not None and only is None else \
        plan_tree(model, part, target, only)
    made: dict[int, Job] = {}
    steps: list[NodeJob] = []
    for name, value, _ in nodes:
        spec = cast(NodePart, model.parts[name])
        mode = spec.modes[value.mode or spec.default_mode] if value.state is State.ACTIVE else None
        step = NodeJob(run, name, Goal(value.state, mode))
        steps.append(step)
    for entry, step in zip(nodes, steps, strict=True):
        made[id(entry)] = step
    top: Job | None = None
    stack: list[tuple[PlanEntry, _Composite | None]] = [(root, None)]
    while stack:
        entry, into = stack.pop()
        stages = entry[2]
        job: Job
        if stages is None:
            job = made[id(entry)]
        else:
            sequence = Sequence(run)
            sequence.system = entry[0]
            for stage in stages:
                parallel = Parallel(run)
                parallel.parent = sequence
                sequence.children.append(parallel)
                stack.extend((member, parallel) for member in reversed(stage))
            job = sequence
        if into is None:
            top = job
        else:
            job.parent = into
            into.children.append(job)
    assert top is not None
    return top, steps


def _stages(spec: SystemPart, target: StateMode) -> tuple[tuple[str, ...], ...]:
    if target.state is State.ACTIVE:
        return spec.modes[target.mode or spec.default_mode].stages
    return tuple(reversed(spec.modes[spec.default_mode].stages))
