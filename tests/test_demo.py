"""The demo runs the pilot mission tree in the simulated world and tells the whole story."""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest
from rich.console import Console
from tree_helpers import PILOT_DEMO_STORY, assert_in_order

from sm_bt.cli import main
from sm_bt.demo import Demo, Options


def run_demo(**options: object) -> tuple[int, str, Demo]:
    out = io.StringIO()
    demo = Demo(Options(speed=0, **options), Console(file=out, width=120, highlight=False))  # type: ignore[arg-type]
    code = demo.run()
    return code, out.getvalue(), demo


@pytest.mark.parametrize("tree", ["pilot", "metacontrol"])
def test_demo_tells_the_whole_story(tree: str) -> None:
    code, text, demo = run_demo(tree=tree)
    assert code == 0, text
    story = PILOT_DEMO_STORY
    # Two cycles: the robot drives to the station, and normal mode comes back after the recharge.
    assert_in_order(text, ["robot at recharge_station", "recharged: battery 1.00",
                           "== pilot is now active.f_normal_mode ==", "mission SUCCESS"])
    assert_in_order(text, story)
    # The monitor table and the tree are shown at key moments.
    assert re.search(r"pilot\s+active\s+active\(\*\)\s+f_degraded_mode\s+f_degraded_mode\(\*\)", text)
    assert "Patrol with contingencies" in text or "Patrol under metacontrol" in text
    # A whole patrol and both recharges happened.
    assert demo.story.waypoints >= 7 and demo.story.recharges == 2


def test_degraded_mode_slows_the_robot_down() -> None:
    _, _, broken = run_demo(laser_failure_at=1.0, laser_repair_at=None, cycles=1)
    _, _, fine = run_demo(laser_failure_at=None, cycles=1)
    assert str(broken.manager.actual("pilot")) == "active.f_degraded_mode"
    # Same mission, but patrolling at 0.1 m/s instead of 0.3 m/s (both recharge at 0.1 m/s).
    assert broken.clock.now() > fine.clock.now() * 1.3


def test_without_laser_repair_the_mission_ends_degraded_as_expected() -> None:
    code, text, _ = run_demo(laser_failure_at=5.0, laser_repair_at=None, cycles=1)
    assert code == 0, text
    assert "pilot ends in active.f_degraded_mode; as expected" in text
    # Battery low while degraded: recharged in degraded mode (energy saving needs the laser).
    assert "f_energy_saving_mode" not in text.split("pilot is now active.f_degraded_mode")[1]


def test_failure_times_and_speed_are_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--speed", "0", "--laser-failure-at", "5", "--laser-repair-at", "20", "--cycles", "1"]) == 0
    out = capsys.readouterr().out
    assert re.search(r"\[\s+5\.\d\d s\] laser failure", out)
    assert re.search(r"\[\s+20\.\d\d s\] laser repaired", out)


def test_quiet_prints_only_the_summary(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--speed", "0", "--quiet", "--cycles", "1"]) == 0
    out = capsys.readouterr().out
    assert out.lstrip().startswith("Summary") and "laser failure" not in out


@pytest.mark.parametrize("argv", [["--speed", "-1"], ["--cycles", "0"], ["--laser-failure-at", "soon"],
                                  ["--tree", "nope"]])
def test_bad_options_are_usage_errors(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", *argv]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_the_xml_pilot_tree_runs_the_same_demo_as_the_python_one() -> None:
    from sm_bt.trees import pilot

    code, xml_text, xml_demo = run_demo(tree=str(pilot.XML))
    _, python_text, python_demo = run_demo(tree="pilot")
    assert code == 0, xml_text
    assert _told(xml_demo) == _told(python_demo)
    assert _summary(xml_text) == _summary(python_text)


def _told(demo: Demo) -> str:
    return re.sub(r"#\d+", "#", repr(demo.story))  # request numbers count the process's requests


def _summary(text: str) -> list[str]:
    lines = text.splitlines()
    return [line for line in lines[lines.index("Summary"):] if "wall" not in line]


def test_a_tree_file_with_mistakes_is_an_error_with_its_lines(capsys: pytest.CaptureFixture[str],
                                                              tmp_path: Path) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_text('<root>\n  <BehaviorTree ID="M">\n    <ChangeMode part="pilot" mode="f_fast"/>\n'
                   "  </BehaviorTree>\n</root>\n")
    assert main(["demo", "--speed", "0", "--tree", str(bad)]) == 1
    _, err = capsys.readouterr()
    assert err.startswith(f"{bad}:3: error: <ChangeMode 'ChangeMode'>: pilot has no mode 'f_fast'")
    assert "Traceback" not in err
