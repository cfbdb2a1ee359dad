"""Scale: loading a model file against ``yaml.load(text, CSafeLoader)`` of the same text.

The loader does more than PyYAML (rcl's typing of every value, line numbers, validation and the
model's own structures), with libyaml's parser underneath; the figure is the ratio of the median
times, both measured here, alternating.
"""

from __future__ import annotations

import statistics
import time

import yaml

from bench.figures import Figure
from bench.generated import model_text
from sm_bt.model.loader import load_model_text

SIZES = (1000, 10_000)
QUICK_SIZES = (100,)
GOAL = 1.5


def run(quick: bool) -> list[Figure]:
    figures = []
    for nodes in QUICK_SIZES if quick else SIZES:
        text = model_text(nodes)
        repeats = 1 if quick else (5 if nodes <= 1000 else 3)
        ours, theirs = [], []
        for _ in range(repeats):
            start = time.perf_counter()
            yaml.load(text, yaml.CSafeLoader)  # the safe C loader: the floor
            theirs.append(time.perf_counter() - start)
            start = time.perf_counter()
            load_model_text(text, "generated.yaml")
            ours.append(time.perf_counter() - start)
        load, floor = statistics.median(ours), statistics.median(theirs)
        figures.append(Figure("scale", f"model loading / yaml CSafeLoader, N={nodes}", load / floor, "x", GOAL,
                              details={"N": nodes, "bytes": len(text), "load_s": round(load, 3),
                                       "csafeloader_s": round(floor, 3), "repeats": repeats}))
    return figures
