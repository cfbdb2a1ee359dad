"""What a failed request leaves behind, by its failure policy: stay, roll back, or a safe mode.

* ``"stay"``: the nodes stay where the failure left them (the reference's behaviour, the default).
* ``"rollback"``: every node the request moved is brought back to the lifecycle state and the
  parameter values it had before the request, in the reverse of the plan's order (a system's
  stages last first, each stage's nodes together); the request ends ``rolled back: <reason>``,
  or ``rollback failed (<what>): <reason>``.
* ``"mode:<name>"``: the request's part is asked for its mode ``<name>`` (a declared safe mode);
  the request ends with its reason and says so.

Only a request that failed by itself is handled so: a step that failed, or its timeout. One that
was preempted by a newer request, withdrawn, or ended by the manager's close leaves the nodes to
whoever owns them now.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from sm_bt.engine.actual import NodeObservation
from sm_bt.engine.drivers import Goal
from sm_bt.engine.plans import Job, NodeJob, Parallel, Run, Sequence, _Composite
from sm_bt.model.states import State
from sm_bt.model.types import Location, Model, NodeMode, NodePart, ParamSpec, ParamValue

POLICIES = ("stay", "rollback")
#: The prefix of the safe-mode policy: ``"mode:f_degraded_mode"``.
MODE_POLICY = "mode:"


def check_policy(policy: str) -> str:
    """``policy`` if it is one (``ValueError`` saying which there are otherwise)."""
    if policy in POLICIES or (policy.startswith(MODE_POLICY) and len(policy) > len(MODE_POLICY)):
        return policy
    raise ValueError(f"on_failure={policy!r} is not a failure policy: use 'stay', 'rollback' or 'mode:<name>' "
                     "(a mode of the request's part)")


@dataclass(frozen=True)
class Before:
    """A node as it was when a request began: its state and the model's parameters' values."""

    state: State
    parameters: Mapping[str, ParamValue]

    @classmethod
    def of(cls, node: NodePart, obs: NodeObservation) -> Before:
        names = node.modes[node.default_mode].parameters
        return cls(obs.state, {name: obs.parameters[name] for name in names if name in obs.parameters})

    def holds(self, obs: NodeObservation) -> bool:
        """Is the node there again?"""
        return obs.state is self.state and all(obs.parameters.get(name) == value
                                               for name, value in self.parameters.items())

    def goal(self, node: str, request: int) -> Goal:
        """The goal that takes the node back: its state, and its values set whatever the state
        (a node's parameters are set in any state)."""
        where = Location(f"(before request #{request})", 0)
        mode = NodeMode(f"before #{request}", {name: ParamSpec(name, value, where)
                                                for name, value in self.parameters.items()}, where)
        return Goal(self.state, mode)


def snapshot(model: Model, nodes: frozenset[str], observation: Mapping[str, NodeObservation]) -> dict[str, Before]:
    """Where ``nodes`` are now (those seen and reachable: the others cannot be put back)."""
    found: dict[str, Before] = {}
    for name in nodes:
        obs = observation[name]
        part = model.parts[name]
        if obs.seen and not obs.gone and obs.state.is_primary and isinstance(part, NodePart):
            found[name] = Before.of(part, obs)
    return found


def reverse_plan(run: Run, original: Job, goals: Mapping[str, Goal]) -> tuple[Job, list[NodeJob]]:
    """``original`` mirrored for the nodes of ``goals``: a system's stages last first, each stage's
    nodes together (no recursion: a hierarchy may be deep)."""
    steps: list[NodeJob] = []

    def copy(job: Job) -> Job:
        if isinstance(job, NodeJob):
            step = NodeJob(run, job.node, goals[job.node])
            steps.append(step)
            return step
        return Sequence(run) if isinstance(job, Sequence) else Parallel(run)

    top = copy(original) if not isinstance(original, NodeJob) or original.node in goals else Parallel(run)
    stack: list[tuple[Job, Job]] = [(original, top)]
    while stack:
        source, made = stack.pop()
        if not isinstance(source, _Composite) or not isinstance(made, _Composite):
            continue
        children = reversed(source.children) if isinstance(source, Sequence) else source.children
        for child in children:
            if isinstance(child, NodeJob) and child.node not in goals:
                continue
            mirrored = copy(child)
            mirrored.parent = made
            made.children.append(mirrored)
            stack.append((child, mirrored))
    if isinstance(top, Sequence):
        top.system = getattr(original, "system", "")
    return top, steps
