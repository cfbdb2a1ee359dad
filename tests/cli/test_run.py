"""``sm-bt run MODEL TREE.xml``: a mission tree with stand-ins and stubs on simulated nodes, its
narration, its summary and its exit status."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import urllib.request
from pathlib import Path

import pytest
from ros_processes import line_within

from sm_bt.cli import main

TREE = """<root main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <PipelineSequence name="Mission">
      <ChangeMode part="pilot" mode="f_normal_mode" timeout="10"/>
      <FollowPath path="{path}"/>
      <IsStuck/>
    </PipelineSequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="FollowPath"><input_port name="path"/></Action>
  </TreeNodesModel>
</root>
"""


def run(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    path = tmp_path / "mission.xml"
    path.write_text(TREE)
    return path


def _stubs(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "stubs.yaml"
    path.write_text(text)
    return path


def test_a_mission_with_stubs_runs_to_its_end_and_says_what_happened(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, tree: Path) -> None:
    stubs = _stubs(tmp_path, "FollowPath: {status: running, for: 2.0, then: success}\nIsStuck: {status: success}\n")
    code, out, err = run(capsys, "run", "pilot", tree, "--stubs", stubs, "--speed", "0")
    assert (code, out) == (0, f"{tree}: SUCCESS at 2.10 s\n"), err
    lines = [re.sub(r"#\d+", "#N", line) for line in err.splitlines()]  # request ids count per process
    assert lines[0] == "    0.00 s  request #N change_mode pilot f_normal_mode started [tree]"
    assert "    0.10 s  request #N change_mode pilot f_normal_mode succeeded in 0.10 s" in lines
    assert lines[-1] == "    2.10 s  Mission SUCCESS"
    # --quiet: the summary alone
    assert run(capsys, "run", "pilot", tree, "--stubs", stubs, "--speed", "0", "--quiet") == (
        0, f"{tree}: SUCCESS at 2.10 s\n", "")


def test_a_failing_mission_exits_1_and_one_that_runs_on_stops_at_until(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, tree: Path) -> None:
    code, out, _ = run(capsys, "run", "pilot", tree, "--stubs", _stubs(tmp_path, "IsStuck: {status: failure}\n"),
                       "--speed", "0", "--quiet")
    assert (code, out) == (1, f"{tree}: FAILURE at 0.10 s\n")
    code, out, _ = run(capsys, "run", "pilot", tree, "--stubs", _stubs(tmp_path, "IsStuck: {status: running}\n"),
                       "--speed", "0", "--quiet", "--until", "3")
    assert (code, out) == (0, f"{tree}: RUNNING at 3.00 s (stopped at --until 3 s)\n")


def test_mistakes_in_the_tree_or_the_stubs_are_all_said_and_exit_1(
        capsys: pytest.CaptureFixture[str], tmp_path: Path, tree: Path) -> None:
    code, out, err = run(capsys, "run", "pilot", tree, "--speed", "0")  # IsStuck: neither declared nor stubbed
    assert (code, out) == (1, "")
    assert err.splitlines() == [f"{tree}:6: error: unknown node <IsStuck> (declare it in <TreeNodesModel> to run it "
                                "as a stand-in, or pass its class in registry=)", f"{tree}: failed (1 error)"]
    stubs = _stubs(tmp_path, "IsStuck: {status: fine}\nFollowPth: {status: success}\n")
    code, out, err = run(capsys, "run", "pilot", tree, "--stubs", stubs)
    assert (code, out) == (1, "")
    assert err.splitlines() == [f"{stubs}:1: error: IsStuck: status must be one of success, failure, running, not "
                                "'fine'", f"{stubs}: failed (1 error)"]


def test_check_takes_the_stubs_too(capsys: pytest.CaptureFixture[str], tmp_path: Path, tree: Path) -> None:
    stubs = _stubs(tmp_path, "IsStuck: {status: failure}\n")
    code, out, err = run(capsys, "check", "pilot", tree, "--stubs", stubs)
    assert (code, err) == (0, "") and out.splitlines()[-1] == f"{tree}: ok against pilot"
    assert run(capsys, "check", "pilot", tree)[0] == 1  # without them, IsStuck is unknown
    code, _, err = run(capsys, "check", "pilot", tree, "--stubs", _stubs(tmp_path, "IsStuck: {stat: failure}\n"))
    assert code == 1 and f"{stubs}: failed (1 error)" in err.splitlines()


def test_record_writes_the_run_for_sm_bt_view(capsys: pytest.CaptureFixture[str], tmp_path: Path, tree: Path) -> None:
    from sm_bt.view import read_recording

    stubs = _stubs(tmp_path, "FollowPath: {status: running, for: 2.0, then: success}\nIsStuck: {status: success}\n")
    recording = tmp_path / "run.jsonl"
    code, _, err = run(capsys, "run", "pilot", tree, "--stubs", stubs, "--speed", "0", "--quiet", "--record", recording)
    assert code == 0, err
    assert len(read_recording(recording)) >= 21  # a frame per tick: 2.1 s at 10 Hz


def test_view_serves_the_run_and_stays_until_ctrl_c(tmp_path: Path, tree: Path) -> None:
    stubs = _stubs(tmp_path, "IsStuck: {status: success}\n")
    process = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "run", "pilot", str(tree), "--stubs", str(stubs),
                                "--speed", "0", "--quiet", "--view", "0"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        first = line_within(process.stderr, 60.0, "sm-bt run --view: the view's address")
        assert first.startswith("view: http://127.0.0.1:"), first
        url = first.split(": ", 1)[1].strip()
        assert line_within(process.stderr, 60.0, "sm-bt run --view: the run's end") == (
            f"run over; the view stays at {url} until Ctrl-C\n")
        with urllib.request.urlopen(url, timeout=5) as page:
            assert page.status == 200
    finally:
        process.send_signal(signal.SIGINT)
        try:
            out, _ = process.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            out, _ = process.communicate(timeout=5)
    assert process.returncode == 0 and out == f"{tree}: SUCCESS at 0.10 s\n"
