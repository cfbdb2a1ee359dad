"""Scale: loading model files of 100, 1,000 and 10,000 nodes, against PyYAML loading the same text.

The loader does more than PyYAML (rcl's typing of every value, line numbers, validation and the
model's own structures), with libyaml's parser underneath. Figures, all measured here:

* the ratio to ``yaml.load(text, CSafeLoader)`` (the baseline: libyaml building plain Python data);
* the ratio to ``yaml.safe_load(text)`` (PyYAML's default loader, what a plain script would use);
* the growth: time per byte at 10,000 nodes over time per byte at 100 nodes. Linear work keeps
  it near 1. It is measured with the garbage collector paused, because CPython's collector alone
  makes building millions of objects grow faster than linearly (CSafeLoader too: about 2x per
  byte from 1,000 to 10,000 nodes), which would hide the loader's own cost; the ratios to PyYAML
  keep the collector on, as users run them, and each load is timed with one full collection after
  it (the loader pauses the collector while it builds: :mod:`sm_bt.model.gc_tuning`).
"""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from functools import partial

import yaml

from bench.figures import Figure
from bench.generated import model_text
from sm_bt.model.loader import load_model_text

SIZES = (100, 1000, 10_000)
QUICK_SIZES = (100,)
GOAL = 1.5  # CSafeLoader ratio (the scale goal, for big files: from 1,000 nodes)
SAFE_LOAD_GOAL = 1.0  # no slower than PyYAML's own safe loader
GROWTH_GOAL = 1.5


def _seconds(action: Callable[[], object], *, collect: bool = True) -> float:
    enabled = gc.isenabled()
    if not collect:
        gc.disable()
    try:
        start = time.perf_counter()
        action()
        if collect:  # what the loader made is walked once here (it pauses the collector while it builds)
            gc.collect()
        return time.perf_counter() - start
    finally:
        if enabled:
            gc.enable()
        gc.collect()


def _repeats(nodes: int, quick: bool) -> int:
    return 1 if quick else {100: 21, 1000: 7}.get(nodes, 3)


def run(quick: bool) -> list[Figure]:
    figures = []
    per_byte: dict[int, float] = {}
    for nodes in QUICK_SIZES if quick else SIZES:
        text = model_text(nodes)
        repeats = _repeats(nodes, quick)
        ours, baseline, paused = [], [], []
        for _ in range(repeats):  # alternating, so that a slow moment of the machine hits both
            baseline.append(_seconds(partial(yaml.load, text, yaml.CSafeLoader)))  # the C safe loader
            ours.append(_seconds(partial(load_model_text, text, "generated.yaml")))
            paused.append(_seconds(partial(load_model_text, text, "generated.yaml"), collect=False))
        safe = _seconds(partial(yaml.safe_load, text))  # pure Python and slow: once
        load = statistics.median(ours)
        per_byte[nodes] = statistics.median(paused) / len(text)
        details = {"N": nodes, "bytes": len(text), "load_s": round(load, 4), "repeats": repeats}
        # A small file is mostly the loader's fixed cost per file (a few ms): reported, held to no goal.
        libyaml = statistics.median(baseline)
        figures.append(Figure("scale", f"model loading / yaml CSafeLoader, N={nodes}", load / libyaml,
                              "x", GOAL if nodes >= 1000 else None,
                              details={**details, "csafeloader_s": round(libyaml, 4)}))
        figures.append(Figure("scale", f"model loading / yaml.safe_load, N={nodes}", load / safe, "x",
                              SAFE_LOAD_GOAL, details={**details, "safe_load_s": round(safe, 4)}))
    if len(per_byte) > 1:
        small, large = min(per_byte), max(per_byte)
        figures.append(Figure("scale", f"model loading growth: time per byte, N={large:,} / N={small}",
                              per_byte[large] / per_byte[small], "x", GROWTH_GOAL,
                              details={f"us_per_byte_N{n}": round(s * 1e6, 3) for n, s in per_byte.items()}))
    return figures
