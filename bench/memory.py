"""P5: memory of the loaded model, and of model + manager + simulated backend, over what the process held before.

Each N runs in a fresh interpreter (``python -m bench.memory N``), so that nothing measured before
is counted: the starting point is its resident set (VmRSS) once everything is imported and the model
text is in memory; the model's figure is after loading it (text dropped, garbage collected), the
manager's after building a manager and a simulated backend over it.
"""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

from bench.figures import Figure

SIZES = (1000, 10_000)
QUICK_SIZES = (100,)
GOALS_MB = {1000: 50.0, 10_000: 400.0}
_ROOT = Path(__file__).resolve().parents[1]


def resident_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def child(nodes: int) -> dict[str, float]:
    """Runs in the fresh interpreter: the three resident-set readings, in MB."""
    from bench.generated import model_text
    from sm_bt.model.loader import load_model_text
    from sm_bt.sim import SimulatedSystem

    text = model_text(nodes)
    gc.collect()
    start = resident_mb()
    model = load_model_text(text, "generated.yaml")
    del text
    gc.collect()
    loaded = resident_mb()
    system = SimulatedSystem(model, history=False, record=False)
    gc.collect()
    built = resident_mb()
    assert system.manager.model is model
    return {"start": start, "model": loaded - start, "model_and_manager": built - start}


def run(quick: bool) -> list[Figure]:
    figures = []
    for nodes in QUICK_SIZES if quick else SIZES:
        done = subprocess.run([sys.executable, "-m", "bench.memory", str(nodes)], cwd=_ROOT, capture_output=True,
                              text=True, timeout=600, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"memory child for N={nodes} failed: {done.stderr.strip().splitlines()[-1:]}")
        got = json.loads(done.stdout)
        details = {"N": nodes, "start_mb": round(got["start"], 1), "unit": "VmRSS, MB = 2^20 bytes"}
        figures.append(Figure("P5", f"model, N={nodes}", got["model"], "MB", details=details))
        figures.append(Figure("P5", f"model + manager + sim backend, N={nodes}", got["model_and_manager"], "MB",
                              GOALS_MB.get(nodes), details=details))
    return figures


if __name__ == "__main__":
    print(json.dumps(child(int(sys.argv[1]))))
