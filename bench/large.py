"""Scale at plant size: 100,000 simulated nodes (the generated model, systems of 10, nested).

Each figure comes from a fresh interpreter (``python -m bench.large N PART``), so that its resident
set is this model's alone. CPU time (``process_time``) of each step, as ``sm-bt manager`` runs:

* load: :func:`~sm_bt.model.loader.load_model_text` and then one full collection (what the process
  pays for the objects it made), against ``yaml.load(text, CSafeLoader)`` and its collection, in a
  process of its own;
* construction: the manager over the loaded (and frozen) model and its simulated nodes (the nodes
  themselves made before), with every node's first report, then
  :func:`~sm_bt.model.gc_tuning.freeze_long_lived` (as ``sm-bt manager`` does once it is built);
* bring-up: one ``change_mode`` from unconfigured to active, until done; a whole-system mode
  change; each with the simulated nodes' own work included (they run in this process, no delays);
* admission: a request's check against 100 holds;
* a fault as the simulated backend reports it (a node leaves its mode and comes back, flipping
  every system above it), the manager's handling included, and its growth from 1,000 nodes; the
  manager's part alone and a node event of the change, as :mod:`bench.scale` times them;
* resident memory: the process's peak (``ru_maxrss``), the model text included.
"""

from __future__ import annotations

import gc
import json
import resource
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from bench.figures import Figure

SIZE, QUICK_SIZE = 100_000, 2_000
LOAD_GOAL = 1.5  # over CSafeLoader
CONSTRUCTION_GOAL, BRING_UP_GOAL, CHANGE_GOAL = 5.0, 20.0, 10.0  # s of CPU
ADMISSION_GOAL_MS = 1.0
RSS_GOAL_MB = 1536.0  # 1.5 GB = 1.5 x 2^30 bytes
#: A fault, the simulated backend's report included (µs), and its growth from 1,000 nodes.
FAULT_GOAL_US, FAULT_GROWTH_GOAL = 50.0, 1.3
FAULT_EVENTS, GROWTH_SIZE = 2000, 1000
GROWTH_PROCESSES = 3  # of the small side: the median of their faults
_ROOT = Path(__file__).resolve().parents[1]


def _cpu(action: Callable[[], object]) -> float:
    start = time.process_time()
    action()
    return time.process_time() - start


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def child_baseline(nodes: int) -> dict[str, float]:
    import yaml

    from bench.generated import model_text

    text = model_text(nodes)

    def load() -> None:
        yaml.load(text, yaml.CSafeLoader)  # nothing kept: its garbage is collected below
        gc.collect()

    return {"csafeloader": _cpu(load)}


def child_manager(nodes: int) -> dict[str, float]:
    from bench.generated import ROOT, model_text, shape
    from bench.scale import Rig, admission, fault_events
    from sm_bt.model.gc_tuning import freeze_long_lived
    from sm_bt.model.loader import load_model_text
    from sm_bt.model.states import State

    holder: dict[str, Any] = {"text": model_text(nodes)}
    out: dict[str, float] = {"bytes": len(holder["text"])}

    def load() -> None:
        holder["model"] = load_model_text(holder.pop("text"), "generated.yaml")
        gc.collect()

    out["load"] = _cpu(load)
    model = holder.pop("model")
    gc.freeze()  # as sm-bt manager keeps it: the construction's collection below walks its own objects

    rig = Rig(model, State.UNCONFIGURED)  # its nodes are made before its clock starts
    out["construction"] = rig.construction + _cpu(freeze_long_lived)
    manager, clock, listener = rig.manager, rig.backend.clock, rig.listener
    assert listener is not None

    out["bring_up"] = _cpu(lambda: rig.drive(manager.change_mode(ROOT, "__DEFAULT__")))
    listener.times.clear()
    listener.on = True
    out["change"] = _cpu(lambda: rig.drive(manager.change_mode(ROOT, "FAST")))
    listener.on = False
    out["change_event"] = statistics.median(listener.times)
    out["fault_manager"] = statistics.median(fault_events(rig, FAULT_EVENTS))
    out["fault"] = fault_event(rig.backend, shape(nodes)[0].nodes)
    out["admission"] = admission(manager, clock)
    out["peak_mb"] = _peak_mb()
    return out


def fault_event(backend: Any, nodes: Sequence[str], count: int = FAULT_EVENTS) -> float:
    """The median wall time of a fault as the simulated backend reports it: a node in the middle
    of the model leaves its mode (a parameter changed from outside) and comes back, ``count``
    times; each flips the node and every system above it, and the manager's handling is included."""
    node = nodes[len(nodes) // 2]
    settled = backend.node(node).parameters["speed"]
    times = []
    for index in range(count):
        start = time.perf_counter()
        backend.set_parameter(node, "speed", 99.0 if index % 2 == 0 else settled)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _child(nodes: int, part: str) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-m", "bench.large", str(nodes), part], cwd=_ROOT, capture_output=True,
                          text=True, timeout=900, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{part} child for N={nodes} failed: {done.stderr.strip().splitlines()[-1:]}")
    result: dict[str, float] = json.loads(done.stdout)
    return result


def run(quick: bool) -> list[Figure]:
    nodes = QUICK_SIZE if quick else SIZE
    ours = _child(nodes, "manager")
    # The small side's fault moves between processes by more than the large side's (22.6-24 µs at
    # 1,000 nodes, 30.2-30.6 µs at 100,000): the median of a few processes, each one's shown.
    small_faults = [_child(GROWTH_SIZE if not quick else 100, "manager")["fault"]
                    for _ in range(1 if quick else GROWTH_PROCESSES)]
    small_fault = statistics.median(small_faults)
    libyaml = _child(nodes, "baseline")["csafeloader"]
    common: dict[str, Any] = {"N": nodes, "cpu": "process_time", "gc": "frozen once built (as sm-bt manager)"}
    goal = (lambda value: value) if not quick else (lambda value: None)
    return [
        Figure("scale", f"model loading / yaml CSafeLoader, N={nodes}", ours["load"] / libyaml, "x", goal(LOAD_GOAL),
               details={**common, "load_s": round(ours["load"], 2), "csafeloader_s": round(libyaml, 2),
                        "bytes": ours["bytes"], "how": "each with one full collection after"}),
        Figure("scale", f"ModeManager construction, ready to run, N={nodes}", ours["construction"], "s",
               goal(CONSTRUCTION_GOAL), details={**common, "includes": "first reports, freeze_long_lived()"}),
        Figure("scale", f"bring-up, one change_mode, N={nodes}", ours["bring_up"], "s", goal(BRING_UP_GOAL),
               details=common),
        Figure("scale", f"whole-system mode change, N={nodes}", ours["change"], "s", goal(CHANGE_GOAL), details=common),
        Figure("holds", f"admission check of a request, 100 holds, N={nodes}", ours["admission"] * 1e3, "ms",
               goal(ADMISSION_GOAL_MS), details=common),
        # The names of bench.scale's P3 rows, so that the plot carries them on to N=100,000.
        Figure("P3", f"node event during a mode change, median, N={nodes}", ours["change_event"] * 1e6, "µs",
               details=common),
        Figure("P3", f"fault event flipping a node and its systems, median, N={nodes}", ours["fault_manager"] * 1e6,
               "µs", details={**common, "events": FAULT_EVENTS, "what": "the manager's part"}),
        Figure("P3", f"fault event with the simulated backend's report, median, N={nodes}", ours["fault"] * 1e6, "µs",
               goal(FAULT_GOAL_US), details={**common, "events": FAULT_EVENTS, "clock": "perf_counter"}),
        Figure("P3", f"fault event growth, N={nodes} / N={GROWTH_SIZE if not quick else 100}",
               ours["fault"] / small_fault, "x", goal(FAULT_GROWTH_GOAL),
               details={"small_us": round(small_fault * 1e6, 1), "large_us": round(ours["fault"] * 1e6, 1),
                        "small_us_per_process": [round(fault * 1e6, 1) for fault in small_faults]}),
        Figure("P5", f"peak resident memory, N={nodes}", ours["peak_mb"], "MB", goal(RSS_GOAL_MB),
               details={**common, "what": "ru_maxrss of the process: text, load, manager, bring-up, change"}),
    ]


if __name__ == "__main__":
    count, which = int(sys.argv[1]), sys.argv[2]
    print(json.dumps(child_manager(count) if which == "manager" else child_baseline(count)))
