"""The demo runs the pilot mission tree in the simulated world and tells the whole story."""

from __future__ import annotations

import functools
import io
import re
from pathlib import Path

import pytest
from rich.console import Console
from tree_helpers import PILOT_DEMO_STORY, assert_in_order

from sm_bt.cli import main
from sm_bt.trees.pilot.demo import Demo, Options


def run_demo(**options: object) -> tuple[int, str, Demo]:
    out = io.StringIO()
    demo = Demo(Options(speed=0, **options), Console(file=out, width=120, highlight=False))  # type: ignore[arg-type]
    code = demo.run()
    return code, out.getvalue(), demo


@functools.cache
def shared_run(tree: str) -> tuple[int, str, Demo]:
    """The default demo of ``tree``, run once for the tests that only read it (one pytest-xdist
    worker runs this module: tests/conftest.py)."""
    return run_demo(tree=tree)


@pytest.mark.parametrize("tree", ["pilot", "metacontrol"])
def test_demo_tells_the_whole_story(tree: str) -> None:
    code, text, demo = shared_run(tree)
    assert code == 0, text
    story = PILOT_DEMO_STORY
    # Two rounds: the robot drives to the station, and normal mode comes back after the recharge.
    assert_in_order(text, ["robot at recharge_station", "recharged: battery 1.00",
                           "== pilot is now active.f_normal_mode ==", "mission SUCCESS"])
    assert_in_order(text, story)
    # The monitor table and the tree are shown at key moments.
    assert re.search(r"pilot\s+active\s+active\(\*\)\s+f_degraded_mode\s+f_degraded_mode\(\*\)", text)
    assert "Patrol with contingencies" in text or "Patrol under metacontrol" in text
    # Both rounds, every waypoint of each, ending at the last one; a recharge is not a round.
    assert (demo.tally.rounds, demo.tally.waypoints) == (2, 14) and demo.tally.recharges >= 2
    assert_in_order(text, ["robot at wp_7", "patrol round 2 of 2 complete", "mission SUCCESS"])


def test_with_the_laser_rule_the_manager_degrades_and_holds_against_the_trees_routine_changes() -> None:
    """sm-bt demo --rules, the laser repaired late: the rule degrades the pilot and holds it; the
    tree's routine energy saving for a low battery is refused, naming the rule, and the tree
    recharges as the pilot is; once the scans are healthy the tree ends the hold."""
    code, text, demo = run_demo(rules=True, tree="rules", laser_repair_at=200.0)
    assert code == 0, text
    assert_in_order(text, [
        "laser failure",
        "!! rule degrade_from_normal: laser_resender is unconfigured -> active.f_degraded_mode",
        "## pilot held in active.f_degraded_mode by rule degrade_from_normal (priority 100), while laser_resender "
        "is unconfigured",
        "== pilot is now active.f_degraded_mode ==",
        "held by rule degrade_from_normal (priority 100): pilot, amcl",  # under the monitor's table
        "battery low",
        "<- change_mode pilot f_energy_saving_mode refused: pilot is held in active.f_degraded_mode by rule "
        "degrade_from_normal (priority 100) since",
        "robot at recharge_station",
        "laser repaired: scans healthy again",
        "## pilot no longer held by rule degrade_from_normal: superseded by request",
        "== pilot is now active.f_normal_mode ==",
        "mission SUCCESS"])
    # The rule switched, not the tree (this tree leaves that to the model's rule).
    assert [r.requester for r in demo.tally.requests if str(r.target) == "active.f_degraded_mode"] == [
        "rule degrade_from_normal"]


Line = tuple[float, str]


def narrative(text: str) -> list[Line]:
    """The demo's time-stamped lines, as (seconds, text)."""
    return [(float(m.group(1)), m.group(2)) for m in re.finditer(r"^\[\s*([\d.]+) s\] (.*)$", text, re.M)]


def first(lines: list[Line], pattern: str, start: int = 0) -> int:
    return next(i for i in range(start, len(lines)) if re.search(pattern, lines[i][1]))


@pytest.mark.parametrize("tree", ["pilot", "metacontrol"])
def test_the_narration_is_true_in_causal_order_and_names_who_asked(tree: str) -> None:
    code, text, _ = shared_run(tree)
    assert code == 0, text
    lines = narrative(text)
    assert [at for at, _ in lines] == sorted(at for at, _ in lines)  # never back in time
    said = [line for _, line in lines]
    started = {m.group(1): (i, m.group(2), m.group(3)) for i, line in enumerate(said)
               if (m := re.match(r"-> #(\d+) (.*) started \[(\w+)\]$", line))}
    assert started
    for number, (index, description, requester) in started.items():
        # The tree asks for the pilot's modes and states; recovery restores the laser node.
        assert requester == ("recovery" if description.startswith("restore ") else "tree"), said[index]
        done = [i for i, line in enumerate(said) if line.startswith(f"<- #{number} ")]
        assert len(done) == 1 and done[0] > index, f"#{number}: {done}"
    # Each request has its cause just before it, and each effect comes after its cause.
    for index, description, _ in started.values():
        cause = said[index - 1]
        if description.endswith("f_energy_saving_mode"):
            assert cause.startswith("battery low ("), cause
        elif description == "change_mode pilot f_degraded_mode":
            assert cause.startswith("!! gave up restoring laser_resender"), cause
        elif description.startswith("restore laser_resender"):
            assert cause.startswith("~~ laser_resender left its target"), cause
        elif description in ("change_to pilot active.f_normal_mode", "change_mode pilot f_normal_mode") \
                and index > 5:
            assert cause.startswith(("recharged", "laser repaired", "battery recovered")), cause
    for index, line in enumerate(said):
        if line.startswith("~~ laser_resender left its target"):
            since = max(i for i in range(index) if said[i].startswith(("laser failure", "<- #")))
            assert any(said[i].startswith("laser_resender fails by itself") for i in range(since, index)), \
                said[since:index + 1]
        if m := re.match(r"== pilot is now active\.(\w+) ==", line):
            last_done = max(i for i in range(index) if said[i].startswith("<- #"))
            assert said[last_done].endswith("succeeded in " + said[last_done].rsplit("in ", 1)[1])
            assert m.group(1) in said[last_done], (said[last_done], line)
    # The summary counts what was told.
    summary = text[text.index("\nSummary"):]
    waypoints = sum(1 for line in said if re.match(r"robot at wp_\d", line))
    recharges = sum(1 for line in said if line.startswith("recharged:"))
    rounds = sum(1 for line in said if re.match(r"patrol round \d of 2 complete", line))
    assert f"2 patrol round(s) ({waypoints} waypoints), {recharges} recharge(s)" in summary
    assert (rounds, waypoints) == (2, 14)
    asked = {requester: sum(1 for _, _, r in started.values() if r == requester) for requester in ("tree", "recovery")}
    assert f"tree requests: {asked['tree']} of {asked['tree']} succeeded" in summary
    assert f"recovery requests: {asked['recovery']} of {asked['recovery']} succeeded" in summary
    assert "user requests" not in summary


def test_tree_dumps_show_feedback_only_for_what_the_tick_visited_and_conditions_in_words() -> None:
    _, text, _ = shared_run("pilot")
    dumps = [line for line in text.splitlines() if re.match(r"^\s*(-->|\[o\]|\[-\]|\{-\}|\{o\}|/_/|-\^-) ", line)]
    assert dumps
    for line in dumps:
        # A status marker goes with every feedback message: a behaviour not ticked shows none.
        assert " -- " not in line or re.search(r"\[[*✓✕-]\] -- ", line), line
    assert not [line for line in dumps if " is True" in line or " is False" in line]
    assert any(re.search(r"Battery OK\? \[✓\] -- battery level 0\.\d\d ≥ 0\.5", line) for line in dumps)


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
    _, python_text, python_demo = shared_run("pilot")
    assert code == 0, xml_text
    assert _told(xml_demo) == _told(python_demo)
    assert _summary(xml_text) == _summary(python_text)


def _told(demo: Demo) -> str:
    return re.sub(r"#\d+", "#", repr(demo.tally))  # request numbers count the process's requests


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


def test_the_demo_piped_to_a_file_is_plain_unwrapped_text(tmp_path: Path) -> None:
    import subprocess
    import sys

    out = tmp_path / "demo.txt"
    with out.open("w") as file:
        done = subprocess.run([sys.executable, "-m", "sm_bt.cli", "demo", "--speed", "0", "--cycles", "1"],
                              stdout=file, stderr=subprocess.PIPE, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    lines = out.read_text(encoding="utf-8").splitlines()
    assert not [line for line in lines if "\x1b" in line]  # no colour codes
    assert not [line for line in lines if line != line.rstrip()]  # no trailing spaces
    # Long lines stay whole: the failure line and the summary's modes are longer than any terminal width.
    summary_modes = next(line for line in lines if line.startswith("  pilot modes: "))
    assert len(summary_modes) > 120 and summary_modes.endswith(")")
    assert any(len(line) > 120 and line.endswith("-> unconfigured)") for line in lines)


#: What the fleet's shift tells, in order: the day shift through each robot's own manager, robot1
#: cut off and lost, the fleet's rule, the heal, robot1 restored by its own manager, the night, the
#: end of the shift (request numbers left out: they count every request of the process).
FLEET_STORY = (
    "fleet -> change_mode fleet __DEFAULT__ started [tree]",
    "robot1's manager -> change_mode pilot __DEFAULT__ started [fleet]",
    "fleet <- change_mode fleet __DEFAULT__ succeeded",
    "robot1 is cut off from the fleet (its own manager and nodes go on)",
    "fleet ~~ robot1: target active.__DEFAULT__, actual unknown (fault: no answer from the manager of robot1",
    "fleet !! rule robot1_lost: robot1 is unknown -> active.NIGHT",
    "robot1 is reachable again",
    "robot1's manager -> change_mode pilot f_energy_saving_mode started [fleet]",
    "fleet ~~ robot1 is back on target active.f_energy_saving_mode",
    "fleet -> change_state fleet deactivate started [tree]",
    "shift SUCCESS",
    "fleet modes: active.__DEFAULT__ (0.3 s) -> active.NIGHT (7.4 s)",
    "robots, by their own managers: robot1 inactive, robot2 inactive; as the fleet sees them: robot1 inactive, "
    "robot2 inactive",
    "as expected",
)


def test_the_fleet_demo_tells_a_shift_with_a_robot_cut_off_and_healed(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--fleet", "--speed", "0"]) == 0
    assert_in_order(re.sub(r"#\d+ ", "", capsys.readouterr().out), FLEET_STORY)


def test_the_fleet_demo_takes_none_of_the_pilot_demos_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--fleet", "--cycles", "3", "--rules"]) == 2
    assert "--fleet runs the fleet's shift: --cycles, --rules belong to the pilot demo" in capsys.readouterr().err


def test_a_fleet_shift_whose_robot_never_comes_back_is_told_not_as_expected() -> None:
    from sm_bt.trees.fleet.demo import FleetDemo, FleetOptions

    out = io.StringIO()
    assert FleetDemo(FleetOptions(speed=0.0, heal_at=None), Console(file=out, width=200)).run() == 1
    text = out.getvalue()
    assert "shift FAILURE" in text and "NOT as expected" in text, text
