"""``make bench``'s harness, run as a smoke test: small sizes, every module but the ROS one.

The figures' values are not checked here (they depend on the machine); what is checked is that
the harness reports every module's figures with their goals, keeps a failing module as a failed
row without losing the others, writes the JSON record and the plot, and that its exit status says
whether every goal was met.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def bench(out: Path, only: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "bench", "--quick", "--only", only, "--out", str(out)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300, check=False)


def test_quick_run_prints_the_table_and_writes_json_and_plot(tmp_path: Path) -> None:
    done = bench(tmp_path, "scale,memory,model_load,large,tick")
    assert done.returncode in (0, 1), done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    header, rule, *rows = done.stdout.strip().splitlines()
    assert header == "| goal | figure | value | goal | met |" and rule == "|---|---|---|---|---|"
    groups = {row.split("|")[1].strip() for row in rows}
    assert {"scale", "P3", "P5", "P4"} <= groups
    assert any("whole-system mode change, N=250" in row for row in rows)
    assert any("peak resident memory, N=2000" in row for row in rows)  # large, at its quick size

    record = json.loads((tmp_path / "results.json").read_text())
    assert record["quick"] is True and record["failed_modules"] == []
    assert record["machine"]["cpus"] >= 1 and record["machine"]["python"]
    figures = record["figures"]
    assert len(figures) == len(rows)
    for figure in figures:
        assert {"group", "name", "value", "unit", "goal", "op", "details", "met"} <= set(figure)
        assert figure["value"] > 0, figure
    # The exit status is the verdict of the goals.
    assert done.returncode == (1 if any(f["met"] is False for f in figures) else 0)

    png = (tmp_path / "scaling.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_a_failing_module_is_a_failed_row_and_the_others_still_run(tmp_path: Path) -> None:
    done = bench(tmp_path, "no_such_module,memory")
    assert done.returncode == 1
    assert "| - | no_such_module failed | LookupError: no benchmark module 'no_such_module'" in done.stdout
    assert "| P5 | model + manager + sim backend, N=100 |" in done.stdout
    record = json.loads((tmp_path / "results.json").read_text())
    assert [f["module"] for f in record["failed_modules"]] == ["no_such_module"]
    assert "no scaling figures: no plot" in done.stderr


@pytest.mark.ros
def test_the_baseline_reads_the_stamp_of_a_serialized_parameter_event() -> None:
    """The ROS module's baseline reads only the stamp (and, with sm_bt.ros.cdr, the node's name) of each
    /parameter_events message."""
    from rcl_interfaces.msg import Parameter, ParameterEvent
    from rclpy.serialization import serialize_message

    from bench.ros_baseline import _event_stamp

    for name, sec in (("/bench_n17", 1_700_000_000), ("/a", 0), ("/ns/" + "x" * 300, -5)):
        message = ParameterEvent(node=name, changed_parameters=[Parameter(name="speed")])
        message.stamp.sec, message.stamp.nanosec = sec, 123
        assert _event_stamp(serialize_message(message)) == sec + 123e-9
