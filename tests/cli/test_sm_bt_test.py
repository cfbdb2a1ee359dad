"""``sm-bt test SCENARIO...``: scenarios that name their model, tree and stubs, judged one by one,
summed up as pytest does, and written as JUnit XML for CI."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from test_scenario import SCENARIO, STUBS, TREE

from sm_bt.cli import main
from sm_bt.view import read_recording


def _write(tmp_path: Path, name: str, scenario: str) -> Path:
    (tmp_path / "mission.xml").write_text(TREE)
    (tmp_path / "stubs.yaml").write_text(STUBS)
    path = tmp_path / name
    path.write_text("model: pilot\ntree: mission.xml\nstubs: stubs.yaml\n" + scenario)
    return path


def test_scenarios_are_run_judged_and_written_for_ci(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    good = _write(tmp_path, "good.yaml", SCENARIO)
    bad = _write(tmp_path, "bad.yaml", SCENARIO.replace("{tree: SUCCESS}", "{tree: FAILURE}"))
    junit, runs = tmp_path / "results.xml", tmp_path / "runs"
    code = main(["test", str(good), str(bad), "--junit", str(junit), "--runs", str(runs)])
    out, err = capsys.readouterr()
    assert (code, err) == (1, "")
    lines = out.splitlines()
    assert lines[:4] == [
        f"PASSED {good}: 5 of 5 expectations held; the tree SUCCESS at 4.10 s",
        f"FAILED {bad}: 4 of 5 expectations held; the tree SUCCESS at 4.10 s",
        f"  {bad}:11: the tree ended SUCCESS, expected FAILURE",
        f"  the run: sm-bt view {runs / 'bad.jsonl'}"]
    assert lines[4].startswith("1 passed, 1 failed in ")
    assert sorted(path.name for path in runs.iterdir()) == ["bad.jsonl"]  # a failed one's run is kept
    frames = read_recording(runs / "bad.jsonl")
    assert frames[0]["time"] == 0.0 and frames[-1]["time"] >= 4.0  # the whole run, to its end
    suite = ET.parse(junit).getroot()
    assert (suite.get("tests"), suite.get("failures")) == ("2", "1")
    cases = {case.get("name"): case for case in suite.iter("testcase")}
    assert cases[str(good)].find("failure") is None
    assert cases[str(bad)].find("failure").get("message") == f"{bad}:11: the tree ended SUCCESS, expected FAILURE"


def test_a_scenario_that_cannot_run_says_why(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "alone.yaml"
    path.write_text(SCENARIO)
    assert main(["test", str(path), "--runs", str(tmp_path / "runs")]) == 1
    assert capsys.readouterr().out.splitlines()[:3] == [
        f"FAILED {path}: cannot run it", f"  {path}: name the model to run it with (model: ...)",
        f"  {path}: name the tree to run it with (tree: ...)"]
