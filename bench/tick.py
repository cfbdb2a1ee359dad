"""P4: what sm_bt behaviours add to a tick, against plain py_trees leaves in the same tree shape.

Each tree has 50 leaves under one composite. The baseline is ``py_trees.behaviours.Success`` (a leaf
whose update only returns SUCCESS); the sm_bt trees hold condition behaviours that hold (a
``ModeIs``/``WaitForMode`` per node of a 50-node model, every node active in its default mode),
so every leaf is ticked on every tick. The root is ticked with ``tick_once()``, without the
``BehaviourTree`` wrapper's visitors, so the ratio is the behaviours' own cost at its sharpest.
Baseline and sm_bt trees alternate in the same process; the figure is the ratio of their best
(minimum) times over several repeats, gc disabled while timing.
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable

import py_trees

from bench.figures import Figure
from bench.generated import model_text, shape
from sm_bt.behaviours import ModeIs, WaitForMode
from sm_bt.engine.manager import ModeManager
from sm_bt.model.loader import load_model_text
from sm_bt.model.states import State
from sm_bt.sim import SimulatedSystem

LEAVES = 50
GOAL = 1.3

Leaf = Callable[[int, str], py_trees.behaviour.Behaviour]


def _manager() -> tuple[ModeManager, tuple[str, ...]]:
    model = load_model_text(model_text(LEAVES), "generated.yaml")
    system = SimulatedSystem(model, transition_delay=0.0, parameter_delay=0.0, initial_state=State.ACTIVE,
                             history=False, record=False)
    return system.manager, shape(LEAVES)[0].nodes


def _tree(composite: Callable[[list[py_trees.behaviour.Behaviour]], py_trees.behaviour.Behaviour],
          leaf: Leaf, nodes: tuple[str, ...], manager: ModeManager) -> py_trees.behaviour.Behaviour:
    root = composite([leaf(i, node) for i, node in enumerate(nodes)])
    for behaviour in root.iterate():
        if isinstance(behaviour, (ModeIs, WaitForMode)):
            behaviour.setup(manager=manager)
        else:
            behaviour.setup()
    return root


def _best(root: py_trees.behaviour.Behaviour, ticks: int, repeats: int) -> float:
    """Seconds per tick, the best of ``repeats`` runs of ``ticks`` ticks."""
    best = float("inf")
    for _ in range(repeats):
        gc.disable()
        start = time.perf_counter()
        for _ in range(ticks):
            root.tick_once()
        best = min(best, time.perf_counter() - start)
        gc.enable()
    return best / ticks


def run(quick: bool) -> list[Figure]:
    manager, nodes = _manager()
    ticks, repeats = (50, 3) if quick else (200, 7)

    def sequence(children: list[py_trees.behaviour.Behaviour]) -> py_trees.behaviour.Behaviour:
        return py_trees.composites.Sequence("seq", memory=False, children=children)

    def parallel(children: list[py_trees.behaviour.Behaviour]) -> py_trees.behaviour.Behaviour:
        return py_trees.composites.Parallel("par", policy=py_trees.common.ParallelPolicy.SuccessOnAll(),
                                            children=children)

    def plain(i: int, node: str) -> py_trees.behaviour.Behaviour:
        return py_trees.behaviours.Success(f"leaf{i}")

    def mode_is(i: int, node: str) -> py_trees.behaviour.Behaviour:
        return ModeIs(f"mode_is{i}", node, "__DEFAULT__")

    def wait_for(i: int, node: str) -> py_trees.behaviour.Behaviour:
        return WaitForMode(f"wait{i}", node, "__DEFAULT__")

    cases = (("Sequence of 50 ModeIs", sequence, mode_is), ("Parallel of 50 ModeIs", parallel, mode_is),
             ("Sequence of 50 satisfied WaitForMode", sequence, wait_for))
    figures = []
    for label, composite, leaf in cases:
        baseline_tree = _tree(composite, plain, nodes, manager)
        sm_tree = _tree(composite, leaf, nodes, manager)
        baseline_tree.tick_once()
        sm_tree.tick_once()
        if sm_tree.status is not py_trees.common.Status.SUCCESS:
            raise RuntimeError(f"{label}: the sm_bt tree is {sm_tree.status.value}, not SUCCESS: "
                               f"{[b.feedback_message for b in sm_tree.iterate() if b.feedback_message][:1]}")
        baseline = sm = float("inf")
        for _ in range(3):  # alternate, so that both see the same machine
            baseline = min(baseline, _best(baseline_tree, ticks, repeats))
            sm = min(sm, _best(sm_tree, ticks, repeats))
        figures.append(Figure("P4", f"tick of a {label} / plain leaves", sm / baseline, "x", GOAL,
                              details={"sm_bt_us": round(sm * 1e6, 1), "baseline_us": round(baseline * 1e6, 1),
                                       "baseline": "py_trees.behaviours.Success", "ticked": "root.tick_once()"}))
    return figures
