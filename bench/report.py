"""What ``make bench`` shows and keeps: the table, the JSON record and the cost-vs-N plot."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.figures import Figure


def _shown(value: float) -> str:
    if value == 0 or 0.01 <= abs(value) < 100_000:
        return f"{value:.3g}" if abs(value) < 10 else f"{value:,.1f}".rstrip("0").rstrip(".")
    return f"{value:.3g}"


def table(figures: Sequence[Figure], failures: Sequence[tuple[str, str]]) -> str:
    """A markdown table: one row per figure (goal and whether it is met), then one per module
    that failed."""
    rows = ["| goal | figure | value | goal | met |", "|---|---|---|---|---|"]
    for figure in figures:
        goal = "" if figure.goal is None else f"{figure.op} {_shown(figure.goal)} {figure.unit}"
        met = {True: "yes", False: "**NO**", None: "-"}[figure.met]
        rows.append(f"| {figure.group} | {figure.name} | {_shown(figure.value)} {figure.unit} | {goal} | {met} |")
    for module, error in failures:
        rows.append(f"| - | {module} failed | {error} | | **NO** |")
    return "\n".join(rows)


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    model = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                timeout=5, check=False).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"cpus": os.cpu_count(), "cpu_model": model, "python": sys.version.split()[0],
            "platform": platform.platform(), "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "commit": commit}


def write_json(path: Path, figures: Sequence[Figure], failures: Sequence[tuple[str, str]],
               duration: float, quick: bool) -> None:
    record = {"machine": machine(), "quick": quick, "duration_s": round(duration, 1),
              "figures": [figure.as_json() for figure in figures],
              "failed_modules": [{"module": module, "error": error} for module, error in failures]}
    path.write_text(json.dumps(record, indent=2) + "\n")


#: The figures drawn against N: (group, name prefix) -> label. Names end in "N=<n>".
PLOTTED_SECONDS = {
    "whole-system mode change": "mode change",
    "bring-up, one change_mode": "bring-up (one request)",
    "bring-up, configure + activate": "bring-up (two requests)",
    "ModeManager construction": "construction",
}
PLOTTED_MICROSECONDS = {
    "node event during a mode change, median": "node event during a mode change (median)",
    "fault event flipping a node and its systems, median": "fault event flipping a branch (median)",
}


def _series(figures: Sequence[Figure], prefix: str) -> tuple[list[int], list[float]]:
    points = sorted((int(f.details["N"]), f.value) for f in figures
                    if f.name.startswith(prefix) and "N" in f.details)
    return [n for n, _ in points], [v for _, v in points]


def plot(path: Path, figures: Sequence[Figure]) -> bool:
    """Draw manager cost against N (log-log) into ``path``; False if there is nothing to draw."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seconds = {label: _series(figures, prefix) for prefix, label in PLOTTED_SECONDS.items()}
    micro = {label: _series(figures, prefix) for prefix, label in PLOTTED_MICROSECONDS.items()}
    if not any(ns for ns, _ in (*seconds.values(), *micro.values())):
        return False
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8))
    for label, (ns, values) in seconds.items():
        if ns:
            left.plot(ns, values, marker="o", label=label)
    left.set(xscale="log", yscale="log", xlabel="nodes (N)", ylabel="manager CPU time (s)",
             title="Whole-model requests, simulated nodes")
    for label, (ns, values) in micro.items():
        if ns:
            right.plot(ns, values, marker="o", label=label)
    right.set(xscale="log", xlabel="nodes (N)", ylabel="manager time per node event (µs)",
              title="One node event (must not grow with N)")
    right.set_ylim(bottom=0)
    for axes in (left, right):
        axes.grid(True, which="both", alpha=0.3)
        axes.legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
