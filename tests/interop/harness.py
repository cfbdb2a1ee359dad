"""``make interop``: the same plain-rclpy scenarios against ``sm-bt manager`` and the reference's
``mode_manager``, on the same simulated nodes and model files, and a side-by-side report.

    SM_BT_REFERENCE=<prefix of tools/reference/build.sh> python tests/interop/harness.py [--out DIR] [--only NAME]

For every scenario and manager: the model's nodes start (``sm-bt sim-nodes``), then the
manager, then ``tests/interop/client.py`` (rclpy only) runs the scenario's steps in a process of
its own; everything is stopped by PID (SIGINT, then SIGKILL) and each run has a ROS domain of its
own. What the client saw goes to ``DIR/results.json``; ``DIR/report.md`` has a table per scenario
(the answer, when ``get_mode``/``get_state`` showed the change, when the event did) and the summary
that docs/reference.md quotes. The nodes' complaints (transitions they were sent in a state that has none)
and how each manager ended are counted as well.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from reference import ReferenceManager, reference_model, reference_prefix
from report import early_by, write_report
from ros_processes import ManagerProcess, NodeProcess

from sm_bt.model import NodePart, SystemPart, load_model
from sm_bt.ros.environment import prepare

HERE = Path(__file__).resolve().parent
CLIENT = HERE / "client.py"
CLIENT_TIMEOUT = 240.0
MANAGERS = ("sm-bt manager", "reference")
#: Nodes that the reference's launch tests run as plain nodes (parameters, no lifecycle).
PLAIN_NODES = {"system_modes__test__launchtest__two_mixed_nodes_modes.yaml": ("B",)}


@dataclass
class Scenario:
    name: str
    title: str
    model: Callable[[Path], Path]  # the model file, written into a scratch folder if need be
    steps: Callable[[Path], list[dict[str, Any]]]
    node_args: tuple[str, ...] = ()


def _mode(part: str, mode: str, **extra: Any) -> dict[str, Any]:
    return {"change_mode": part, "mode": mode, **extra}


def _state(part: str, transition: str, expect: str, **extra: Any) -> dict[str, Any]:
    return {"change_state": part, "transition": transition, "expect": expect, **extra}


def pilot_steps(_: Path) -> list[dict[str, Any]]:
    return [
        _state("pilot", "configure", "inactive"),
        _state("pilot", "activate", "active"),
        _mode("pilot", "f_normal_mode"),
        _mode("pilot", "f_performance_mode"),
        _mode("pilot", "f_normal_mode"),
        _mode("pilot", "f_energy_saving_mode"),
        _mode("pilot", "f_slow_mode"),  # the same entries as f_energy_saving_mode
        _mode("pilot", "f_normal_mode"),
        _mode("pilot", "f_normal_mode", window=2.0, quiet=True),  # redundant: nothing changes, no event
        _mode("pilot", "f_nrmal_mode", expect=None, window=1.5),  # not a mode
        _mode("controller_server", "FAST"),  # a node's mode, through the manager
        _mode("controller_server", "__DEFAULT__"),
        {"late_subscriber": "pilot", "window": 2.5},
        {"node_change_state": "laser_resender", "transition": "deactivate", "watch": "pilot", "window": 6.0},
        _mode("pilot", "f_normal_mode", window=5.0, quiet=True),  # sm_bt has restored it: redundant
        _mode("pilot", "f_degraded_mode", window=6.0),  # needs cleanup of laser_resender
        _mode("pilot", "f_normal_mode", window=5.0),
        _state("pilot", "deactivate", "inactive"),
        _state("pilot", "activate", "active", id=False),  # the label alone, id 0
    ]


def slow_pilot_steps(_: Path) -> list[dict[str, Any]]:
    """Changes that make nodes transition (2 s each), where a manager may claim a mode too soon."""
    return [
        _state("pilot", "configure", "inactive", window=10.0),
        _state("pilot", "activate", "active", window=10.0),
        _mode("pilot", "f_normal_mode", window=10.0),
        _mode("pilot", "f_performance_mode", window=10.0),
        _mode("pilot", "f_normal_mode", window=10.0),
        _mode("pilot", "f_degraded_mode", window=8.0),  # the reference never gets there
        _mode("pilot", "f_normal_mode", window=10.0),
        _state("pilot", "deactivate", "inactive", window=10.0),
        _state("pilot", "activate", "active", window=10.0),
        # sm_bt's activate went back to f_normal_mode (the reference's to __DEFAULT__): nothing to do.
        _mode("pilot", "f_normal_mode", window=10.0, quiet=True),
    ]


def every_mode_steps(model_path: Path) -> list[dict[str, Any]]:
    """Bring every top system up, then visit each mode of each system and node, back to the default."""
    model = load_model(model_path, strict=False)
    steps: list[dict[str, Any]] = []
    tops = [name for name in model.roots() if isinstance(model.parts[name], SystemPart)]
    for system in tops:
        # A system whose default mode wants a plain node (no lifecycle) inactive cannot be configured.
        plain = [part for part in model.nodes_under(system) if part in PLAIN_NODES.get(model_path.name, ())]
        steps += [_state(system, "configure", "inactive", window=3.0, fails=bool(plain)),
                  _state(system, "activate", "active", window=3.0)]
    for part in model.parts.values():
        modes = [mode for mode in part.modes if mode != part.default_mode]
        for mode in [*modes, "__DEFAULT__"] if modes else []:
            expect = part.default_mode if mode == "__DEFAULT__" else mode
            steps.append(_mode(part.name, mode, expect=expect, window=3.0))
    return steps


def scenarios(prefix: Path) -> list[Scenario]:
    found = [
        Scenario("pilot", "The pilot (models/pilot.yaml without its __order__ line)",
                 lambda folder: reference_model("pilot", folder), pilot_steps),
        Scenario("pilot-slow", "The pilot, every transition of every node taking 2 s (as Nav2's servers configure)",
                 lambda folder: reference_model("pilot", folder), slow_pilot_steps,
                 node_args=("--transition-delay", "2")),
    ]
    for model in sorted((prefix / "models").glob("*.yaml")):
        extra = ("--parameters-only", ",".join(PLAIN_NODES[model.name])) if model.name in PLAIN_NODES else ()
        found.append(Scenario(model.stem, f"The reference's own {model.name.replace('__', '/')}",
                              lambda _folder, m=model: m, every_mode_steps, node_args=extra))
    return found


def parts_of(model_path: Path) -> tuple[list[str], list[str]]:
    model = load_model(model_path, strict=False)
    return ([p.name for p in model.parts.values() if isinstance(p, SystemPart)],
            [p.name for p in model.parts.values() if isinstance(p, NodePart)])


def run_one(scenario: Scenario, manager: str, folder: Path, domain: int) -> dict[str, Any]:
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    model_path = scenario.model(folder)
    systems, nodes = parts_of(model_path)
    spec = folder / f"{scenario.name}.json"
    spec.write_text(json.dumps({"systems": systems, "nodes": nodes, "steps": scenario.steps(model_path)}))
    node_process = NodeProcess(str(model_path), *scenario.node_args)
    manager_process: NodeProcess = (ManagerProcess(str(model_path)) if manager == "sm-bt manager"
                                    else ReferenceManager(model_path))
    result: dict[str, Any] = {"scenario": scenario.name, "manager": manager, "domain": domain}
    started = time.monotonic()
    try:
        node_process.start()
        manager_process.start()
        client = subprocess.run([sys.executable, str(CLIENT), str(spec)], capture_output=True, text=True,
                                timeout=CLIENT_TIMEOUT, check=False)
        if client.returncode != 0:
            result["error"] = f"the client exited with {client.returncode}: {client.stderr[-2000:]}"
        else:
            result.update(json.loads(client.stdout))
        result["manager_alive_at_end"] = manager_process.alive
    except (subprocess.TimeoutExpired, AssertionError, RuntimeError) as error:
        result["error"] = f"{type(error).__name__}: {error}"
    finally:
        result["manager_exit"] = manager_process.stop()
        node_process.stop()
    result["seconds"] = round(time.monotonic() - started, 1)
    result["refused_by_nodes"] = sum("No transition matching" in line for line in node_process.stderr.splitlines())
    result["manager_stderr_tail"] = manager_process.stderr.splitlines()[-5:]
    return result


def sm_bt_mismatches(result: dict[str, Any]) -> list[str]:
    """Where ``sm-bt manager`` did not do what a step asks: every change accepted and shown by
    ``get_*`` and by its event (a redundant one, ``quiet``, by no event), never before the nodes
    got there, an unknown mode refused,
    a change that cannot be made (``fails``) refused or failed, a fault behind its back restored."""
    if "error" in result:
        return [result["error"]]
    if result["manager_exit"] != 0 or result["refused_by_nodes"]:
        return [f"exit {result['manager_exit']}, {result['refused_by_nodes']} transitions refused by the nodes"]
    wrong = []
    for index, step in enumerate(result["steps"]):
        spec = step["step"]
        if "late_subscriber" in spec:
            ok = any(topic == "mode_event" for _, topic, _ in step["heard"])
        elif "node_change_state" in spec:
            ok = len(step["answers"]) > 1 and step["answers"][-1][1] == step["system_mode_before"]
        elif spec.get("expect", "") is None:
            ok = step["answer"] is False
        elif spec.get("fails"):
            ok = step["shown_s"] is None
        else:
            ok = step["answer"] is True and step["shown_s"] is not None and (
                (step["told_s"] is None) if spec.get("quiet") else (step["told_s"] is not None))
        if ok and early_by(step) is not None:
            ok = False  # shown before the nodes got there
        if not ok:
            seen = {key: step.get(key) for key in ("answer", "shown_s", "told_s", "nodes_done_s")}
            wrong.append(f"step {index + 1} ({spec}): {json.dumps(seen)}")
    return wrong


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("build/interop"))
    parser.add_argument("--only", action="append", default=[], help="run only the scenarios of these names")
    parser.add_argument("--report-only", action="store_true",
                        help="run nothing: write the report again from OUT/results.json")
    args = parser.parse_args(argv)
    try:
        prefix = reference_prefix()
    except RuntimeError as error:
        print(f"interop: error: {error}", file=sys.stderr)
        return 2
    prepare(own_domain=True)
    base = int(os.environ["ROS_DOMAIN_ID"])
    args.out.mkdir(parents=True, exist_ok=True)
    chosen = [s for s in scenarios(prefix) if not args.only or s.name in args.only]
    results: list[dict[str, Any]] = []
    if args.report_only:
        results = json.loads((args.out / "results.json").read_text())
        chosen = [s for s in chosen if any(r["scenario"] == s.name for r in results)]
    with tempfile.TemporaryDirectory(prefix="sm_bt-interop-") as scratch:
        for index, scenario in enumerate([] if args.report_only else chosen):
            for offset, manager in enumerate(MANAGERS):
                domain = 10 + (base - 10 + 2 * index + offset) % 90
                print(f"interop: {scenario.name} on {manager} ...", file=sys.stderr, flush=True)
                result = run_one(scenario, manager, Path(scratch), domain)
                results.append(result)
                print(f"interop: {scenario.name} on {manager}: {result['seconds']} s"
                      + (f", {result['error']}" if "error" in result else ""), file=sys.stderr, flush=True)
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    text = write_report(results, {s.name: s.title for s in chosen})
    (args.out / "report.md").write_text(text)
    print(text)
    print(f"interop: the report is in {args.out / 'report.md'}, what the client saw in {args.out / 'results.json'}",
          file=sys.stderr)
    failed = False
    for result in results:
        if result["manager"] == "reference":
            if "error" in result:
                failed = True
                print(f"interop: {result['scenario']} on the reference: {result['error']}", file=sys.stderr)
            continue
        for problem in sm_bt_mismatches(result):
            failed = True
            print(f"interop: {result['scenario']} on sm-bt manager: {problem}", file=sys.stderr)
    print("interop: " + ("FAILED: sm-bt manager did not do what a scenario asks (above)" if failed
                         else "sm-bt manager did what every scenario asks"), file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
