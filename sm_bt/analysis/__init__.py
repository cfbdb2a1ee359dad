"""Find the flaws of a mode model before the robot does (``sm-bt analyze``).

:func:`analyze` reads a model, and the mission trees that use it, for what a well-formed model
can still get wrong, each :class:`~sm_bt.analysis.findings.Finding` with its file and line:

* **reachability** (:mod:`~sm_bt.analysis.reach`): modes no request can reach, or only a direct
  request that the manager takes for an override;
* **inference** (:mod:`~sm_bt.analysis.ambiguity`): modes that the parts' configuration cannot
  tell apart;
* **rules** (:mod:`~sm_bt.analysis.rule_checks`): circles on a lasting fault, rules a mode change
  sets off half way;
* **faults** (:mod:`~sm_bt.analysis.faults`): every single node fault (or pair) from every mode of
  the top systems, run with the real engine on simulated nodes in virtual time: where each
  system ends, which rules fired, systems left diverged with no rule, rules that never fire;
* **trees** (:mod:`~sm_bt.analysis.tree_checks`): what a tree asks for that a fault makes
  unreachable while no contingency of it watches, and the modes no tree asks for.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sm_bt.analysis.ambiguity import ambiguity
from sm_bt.analysis.faults import Outcome, explore, fault_findings
from sm_bt.analysis.findings import Finding, Kind, Level, in_file_order
from sm_bt.analysis.reach import reachability, routes
from sm_bt.analysis.rule_checks import rule_findings
from sm_bt.analysis.tree_checks import TreeUse, tree_findings, tree_use
from sm_bt.model.types import Model

__all__ = ["Analysis", "Finding", "Kind", "Level", "analyze"]


@dataclass
class Analysis:
    """What :func:`analyze` found: the findings (errors first, then in file order) and every
    fault run's outcome (the table ``sm-bt analyze`` prints)."""

    model: Model
    findings: list[Finding]
    outcomes: list[Outcome] = field(default_factory=list)
    trees: list[TreeUse] = field(default_factory=list)
    #: From each start, each mode of each top system: its plan's calls, or why it cannot be made.
    routes: list[tuple[str, str, str, int | str]] = field(default_factory=list)

    @property
    def errors(self) -> list[Finding]:
        return [f for f in self.findings if f.level is Level.ERROR]

    def as_json(self) -> dict[str, Any]:
        return {"model": self.model.path,
                "trees": [{"path": use.path, "modes": [f"{part} {mode}" for part, mode in use.modes],
                           "transitions": [f"{part} {label}" for part, label in use.transitions],
                           "watches": sorted(part or "*" for part in use.watched)} for use in self.trees],
                "findings": [f.as_json() for f in self.findings],
                "faults": [{"start": o.start, "faults": [str(f) for f in o.faults],
                            "ends": {name: {"actual": actual, "diverged": why or None}
                                     for name, (actual, why) in o.ends.items()},
                            "rules": [{"rule": rule, "system": system, "target": target}
                                      for rule, system, target in o.rules],
                            "settled_after": o.settled_after} for o in self.outcomes],
                "routes": [{"from": start, "system": system, "mode": mode,
                            ("calls" if isinstance(plan, int) else "refused"): plan}
                           for start, system, mode, plan in self.routes]}


def analyze(model: Model, trees: Sequence[str | Path] = (), *, faults: int = 1) -> Analysis:
    """Analyse ``model`` (and ``trees``, tree files that check clean against it) with every set
    of up to ``faults`` node faults (0: none)."""
    uses = [tree_use(tree) for tree in trees]
    wanted = [key for use in uses for key in use.modes if key[0] in model.parts]
    outcomes = explore(model, faults, wanted) if faults > 0 else []
    findings = [*reachability(model), *ambiguity(model), *rule_findings(model),
                *fault_findings(model, outcomes), *tree_findings(model, uses, outcomes)]
    return Analysis(model, in_file_order(findings), outcomes, uses, routes(model))
