"""``sm-bt test SCENARIO...``: scenarios that name their model, tree and stubs, judged one by one,
summed up as pytest does, and written as JUnit XML for CI."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from test_scenario import SCENARIO, STUBS, TREE

from sm_bt.cli import main
from sm_bt.view import read_recording

ROOT = Path(__file__).parents[2]


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
        f"  the run: sm-bt view {runs / 'bad.jsonl'} --at 4.1"]
    assert lines[4].startswith("1 passed, 1 failed in ")
    assert sorted(path.name for path in runs.iterdir()) == ["bad.jsonl"]  # a failed one's run is kept
    frames = read_recording(runs / "bad.jsonl")
    assert frames[0]["time"] == 0.0 and frames[-1]["time"] >= 4.0  # the whole run, to its end
    # The failure is in the run's events, at its time, for the view to list and mark on the timeline.
    assert [(event["time"], event["text"]) for frame in frames for event in frame.get("events", ())
            if event["kind"] == "expectation"] == [(4.1, f"{bad}:11: the tree ended SUCCESS, expected FAILURE")]
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


def test_the_pilots_stories_ship_as_scenarios_and_pass(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    shipped = sorted((ROOT / "trees" / "pilot" / "scenarios").glob("*.yaml"))
    assert [path.name for path in shipped] == ["battery.yaml", "laser_failure.yaml", "laser_rule.yaml"]
    code = main(["test", *map(str, shipped), "--runs", str(tmp_path / "runs")])
    out, _ = capsys.readouterr()
    assert code == 0, out
    assert [line.split(":")[0] for line in out.splitlines()[:3]] == [f"PASSED {path}" for path in shipped]
    # The world's laser matters: never repaired, the pilot stays degraded and the expectation says so.
    # (These variants stop at 50 s, past the expectation that tells: the rest of a run is 850 s of ticks.)
    never_repaired = tmp_path / "laser_failure.yaml"
    never_repaired.write_text(shipped[1].read_text().replace("tree: ../pilot.xml", f"tree: {shipped[1].parent.parent}"
                                                             "/pilot.xml").replace(
        "  - {at: 40.0, world: {laser: repaired}}\n", "").replace("until: 900", "until: 50"))
    code = main(["test", str(never_repaired), "--runs", str(tmp_path / "runs")])
    out, _ = capsys.readouterr()
    assert code == 1
    assert f"  {never_repaired}:13: at 45 s pilot is active.f_degraded_mode, expected active.f_normal_mode" in out, out
    # The rule's hold matters: the tree asking for normal mode at its own priority stays degraded.
    own_priority = tmp_path / "laser_rule.yaml"
    own_priority.write_text(shipped[2].read_text().replace("tree: ../pilot.xml", f"tree: {tmp_path}/pilot.xml")
                            .replace("until: 900", "until: 50"))
    (tmp_path / "pilot.xml").write_text((shipped[2].parent.parent / "pilot.xml").read_text().replace(
        ' priority="100"', ""))
    code = main(["test", str(own_priority), "--runs", str(tmp_path / "runs")])
    out, _ = capsys.readouterr()
    assert code == 1
    assert f"  {own_priority}:16: at 45 s pilot is active.f_degraded_mode, expected active.f_normal_mode" in out, out
