"""``sm-bt analyze``: the whole command on the pilot with its tree and every pair of faults, and
the single-fault analysis of a generated model of 1,000 nodes, wall time, one run each after a
warm-up (the analysis is deterministic: its work does not vary between runs).

Measured two ways: the command in a process of its own (what a user waits for, start-up and
loading included) and :func:`sm_bt.analysis.analyze` in this process."""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from bench.figures import Figure
from bench.generated import model_text
from sm_bt.analysis import analyze
from sm_bt.bundled import path as bundled_path
from sm_bt.model.loader import load_model, load_model_text

ROOT = Path(__file__).resolve().parents[1]
PILOT_GOAL_S = 5.0
GENERATED_GOAL_S = 60.0


def _seconds(action: Callable[[], object]) -> float:
    start = time.perf_counter()
    action()
    return time.perf_counter() - start


def run(quick: bool) -> list[Figure]:
    tree = ROOT / "trees" / "pilot" / "pilot.xml"
    command = [sys.executable, "-m", "sm_bt.cli", "analyze", "pilot_rules", str(tree), "--faults", "2"]
    pilot = load_model(bundled_path("pilot_rules"))
    analyze(pilot, [tree], faults=2)  # warm-up (imports, caches)
    in_process = _seconds(lambda: analyze(pilot, [tree], faults=2))
    whole = _seconds(lambda: subprocess.run(command, cwd=ROOT, capture_output=True, check=False, timeout=600))
    runs = len(analyze(pilot, [tree], faults=2).outcomes)
    figures = [
        Figure("analysis", "sm-bt analyze pilot_rules pilot.xml --faults 2, its own process", whole, "s",
               PILOT_GOAL_S, details={"fault runs": runs}),
        Figure("analysis", "the same analysis in this process", in_process, "s", PILOT_GOAL_S,
               details={"fault runs": runs}),
    ]
    nodes = 100 if quick else 1000
    generated = load_model_text(model_text(nodes), f"generated-{nodes}.yaml")
    seconds = _seconds(lambda: analyze(generated, faults=1))
    figures.append(Figure("analysis", f"single-fault analysis of a generated model, N={nodes}", seconds, "s",
                          GENERATED_GOAL_S if nodes == 1000 else None,
                          details={"fault runs": len(analyze(generated, faults=1).outcomes),
                                   "how": "alike nodes run once (sm_bt.analysis.symmetry)"}))
    return figures
