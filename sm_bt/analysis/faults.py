"""Faults: what rules and recovery make of every single node fault (and every pair, with
``faults=2``), run with the real engine on simulated nodes in virtual time.

From each mode of each top system (and of each node of no system), each node in turn (or each
pair of nodes) suffers a fault:

* ``crash``: it stops answering (reported gone after the backend's ``vanish_after``);
* ``fails``: an active node fails by itself (deactivating, error processing, unconfigured), as
  the pilot's laser does on broken scans, and stays broken: every configure of it fails;
* ``stops``: an active node deactivates by itself (inactive), and stays so: every activate fails;
* ``lost``: its process ends (reported gone at once).

The run goes on until the manager is quiet; the outcome is where each system ends (mode, and
whether it stays diverged), which rules fired, and how long it took. A system left diverged with
no rule reacting is a warning; rules that switch a system back and forth are an error; a rule
that no explored fault makes fire is a warning.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from sm_bt.analysis.findings import Finding, Kind, Level
from sm_bt.analysis.reach import top_parts
from sm_bt.analysis.symmetry import alike_nodes
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.requests import Origin, Request
from sm_bt.model.states import State
from sm_bt.model.types import Model, SystemPart
from sm_bt.sim import SimulatedSystem

FAULT_KINDS = ("crash", "fails", "stops", "lost")
#: Virtual seconds a run may take after its faults before it counts as not settling.
LIMIT = 300.0
#: Virtual seconds without an event (and no request in flight) that count as settled.
QUIET = 5.0
#: Virtual seconds between looks at a run (a broken node's next configure is failed again at each).
STEP = 0.1


@dataclass(frozen=True)
class Fault:
    node: str
    kind: str

    def __str__(self) -> str:
        return f"{_NOUN[self.kind]} of {self.node}"


_NOUN = {"crash": "crash", "fails": "failure", "stops": "deactivation", "lost": "loss"}
#: The transition a lasting fault keeps failing.
_LASTING = {"fails": Transition.CONFIGURE, "stops": Transition.ACTIVATE}


@dataclass
class Outcome:
    """One run: from ``start`` (system, mode), ``faults`` happened; where each system ended."""

    system: str
    mode: str
    faults: tuple[Fault, ...]
    #: Each system's actual at the end, and its divergence then ("" when on target).
    ends: dict[str, tuple[str, str]] = field(default_factory=dict)
    #: The rules that fired, in order, with the system's new target.
    rules: list[tuple[str, str, str]] = field(default_factory=list)
    settled_after: float | None = None
    #: The changes asked for (by trees) that cannot be made at the end, with why.
    blocked: dict[tuple[str, str], str] = field(default_factory=dict)
    #: Nodes alike the faulty one (a single fault): the same fault of each ends the same way.
    like: tuple[str, ...] = ()

    @property
    def start(self) -> str:
        return f"{self.system}=active.{self.mode}"

    def line(self) -> str:
        ends = "; ".join(f"{name} {actual}" + (f" (diverged: {why})" if why else "")
                         for name, (actual, why) in self.ends.items())
        fired = ", ".join(f"{rule} -> {target}" for rule, _, target in self.rules) or "no rule"
        after = f"{self.settled_after:.1f} s" if self.settled_after is not None else f"not settled in {LIMIT:g} s"
        return f"{self.start}, {' + '.join(map(str, self.faults))}: {ends}; {fired}; {after}"


def explore(model: Model, faults: int = 1, wanted: Iterable[tuple[str, str]] = ()) -> list[Outcome]:
    """Every run: each mode of each top system, each set of ``faults`` faults on distinct nodes;
    ``wanted``: changes (part, mode) whose possibility at the end of each run is noted."""
    outcomes = []
    asked = sorted(set(wanted))
    classes = alike_nodes(model)
    for system in top_parts(model):
        for mode in model.parts[system].modes:
            for chosen in _fault_sets(model, faults, classes):
                outcome = _run(model, system, mode, chosen, asked)
                if outcome is not None:
                    if len(chosen) == 1:
                        outcome.like = tuple(classes.get(chosen[0].node, ()))
                    outcomes.append(outcome)
    return outcomes


def _fault_sets(model: Model, size: int, classes: dict[str, list[str]]) -> Iterator[tuple[Fault, ...]]:
    """Single faults of one node of each class of alike ones (``classes``, by their first node:
    :mod:`~sm_bt.analysis.symmetry`), then every pair of faults on two nodes."""
    for node in classes:
        for kind in FAULT_KINDS:
            yield (Fault(node, kind),)
    if size > 1:
        single = [Fault(node.name, kind) for node in model.nodes for kind in FAULT_KINDS]
        for chosen in itertools.combinations(single, 2):
            if chosen[0].node != chosen[1].node:
                yield chosen


def _run(model: Model, system: str, mode: str, faults: tuple[Fault, ...],
         wanted: list[tuple[str, str]]) -> Outcome | None:
    sim = SimulatedSystem(model)
    manager = sim.manager
    if not sim.finish(manager.change_mode(system, mode)).succeeded:
        return None  # not reachable: reachability says why
    outcome = Outcome(system, mode, faults)
    for fault in faults:
        if fault.kind in _LASTING and sim.backend.node(fault.node).state is not State.ACTIVE:
            return None  # only an active node fails or deactivates by itself
    began = sim.now()
    seen = len(sim.events)
    for fault in faults:
        if fault.kind == "stops":
            sim.backend.trigger(fault.node, Transition.DEACTIVATE)
        else:
            {"crash": sim.crash, "fails": sim.fail, "lost": sim.vanish}[fault.kind](fault.node)
    lasting = [(fault.node, _LASTING[fault.kind]) for fault in faults if fault.kind in _LASTING]
    last = began
    while sim.now() - began < LIMIT:
        for node, transition in lasting:  # still broken: the transition that would mend it fails too
            sim.fail_next(node, transition)
        sim.run(STEP)
        if len(sim.events) > seen:
            last = sim.events[-1].time
            seen = len(sim.events)
        if not manager.requests() and sim.now() - last >= QUIET:
            outcome.settled_after = last - began
            break
    fired: dict[int, Request] = {}  # the rules' requests, in the order they started
    for event in sim.events:
        request = event.request
        if event.time >= began and request is not None and request.origin is Origin.RULE and not request.refused:
            fired.setdefault(request.id, request)
    outcome.rules = [(request.requester.removeprefix("rule "), request.part, str(request.target))
                     for request in fired.values()]
    for name, part in model.parts.items():
        if isinstance(part, SystemPart):
            divergence = manager.divergence(name)
            why = "" if divergence is None or not divergence.is_error else (divergence.reason or divergence.cause.value)
            outcome.ends[name] = (str(manager.actual(name)), why)
    for asked, mode_name in wanted:
        plan = manager.preview(asked, mode_name)
        if not plan.possible:
            outcome.blocked[(asked, mode_name)] = plan.refused
    sim.close()
    return outcome


def fault_findings(model: Model, outcomes: list[Outcome]) -> list[Finding]:
    findings: list[Finding] = []
    unhandled: dict[tuple[str, tuple[str, ...]], list[Outcome]] = {}
    for outcome in outcomes:
        for name, (_, why) in outcome.ends.items():
            if why and not any(system == name for _, system, _ in outcome.rules):
                unhandled.setdefault((name, tuple(f.node for f in outcome.faults)), []).append(outcome)
        switches = [target for _, system, target in outcome.rules if system == outcome.system]
        if len(switches) >= 2 and len(set(switches)) < len(switches):
            findings.append(Finding(
                Kind.RULE_PING_PONG, Level.ERROR, model.parts[outcome.system].location,
                f"rules switch {outcome.system} back and forth after a {' + '.join(map(str, outcome.faults))} in "
                f"{outcome.mode}", " -> ".join(f"{target} (rule {rule})" for rule, system, target in outcome.rules
                                               if system == outcome.system)))
    for (name, nodes), runs in unhandled.items():
        if len(nodes) > 1 and any((name, (node,)) in unhandled for node in nodes):
            continue  # one of the faults alone does it: the smaller example is reported
        by_kinds: dict[str, list[Outcome]] = {}  # which faults, from which modes
        for run in runs:
            by_kinds.setdefault(" + ".join(_NOUN[f.kind] for f in run.faults), []).append(run)
        by_modes: dict[tuple[str, ...], list[str]] = {}
        for combination, alike in by_kinds.items():
            by_modes.setdefault(tuple(dict.fromkeys(run.mode for run in alike)), []).append(combination)
        for modes, kinds in by_modes.items():
            first = next(run for run in runs if run.mode == modes[0]
                         and " + ".join(_NOUN[f.kind] for f in run.faults) == kinds[0])
            like = first.like if len(nodes) == 1 else ()
            others = (f" (or of {like[0]}, a node like it)" if len(like) == 1 else
                      f" (or of {len(like)} nodes like it: {', '.join(like[:3])}{', ...' if len(like) > 3 else ''})")
            what = f"a {' or '.join(kinds)} of {' and '.join(nodes)}" + (others if like else "")
            findings.append(Finding(
                Kind.FAULT_UNHANDLED, Level.WARNING, model.parts[name].location,
                f"{what} leaves {name} diverged and no rule of it reacts (from {', '.join(modes)})",
                f"{first.start}, {' + '.join(map(str, first.faults))}: {name} ends {first.ends[name][0]} "
                f"({first.ends[name][1]})"))
    for part in model.parts.values():
        for rule in part.rules:
            tried = [o for o in outcomes if o.system == rule.system or o.system in _ancestors(model, rule.system)]
            if tried and not any(fired == rule.name and system == rule.system for o in tried
                                 for fired, system, _ in o.rules):
                findings.append(Finding(
                    Kind.RULE_NEVER_FIRES, Level.WARNING, rule.location,
                    f"rule {rule.name} of {rule.system} fired in none of {len(tried)} runs with faults "
                    f"({', '.join(_NOUN[kind] for kind in FAULT_KINDS)}) of its nodes: it waits for "
                    f"{rule.if_part} to be {rule.if_part_state} while {rule.system} is {rule.if_target}"))
    return findings


def _ancestors(model: Model, part: str) -> set[str]:
    found: set[str] = set()
    frontier = [part]
    while frontier:
        child = frontier.pop()
        for name, system in model.parts.items():
            if isinstance(system, SystemPart) and child in system.parts and name not in found:
                found.add(name)
                frontier.append(name)
    return found
