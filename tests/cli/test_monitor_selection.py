"""The monitor on models with more parts than a screen: a selection of rows, a summary, JSON diffs."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_generator import flat_system_text, model_from_text
from rich.console import Console

from sm_bt.cli import main
from sm_bt.engine.manager import ModeManager
from sm_bt.monitor import Monitor, Selection, render_text, to_json
from sm_bt.monitor_rows import shown as shown_parts
from sm_bt.sim import SimulatedSystem

NODES = 300


@pytest.fixture
def rig() -> SimulatedSystem:
    system = SimulatedSystem(model_from_text(flat_system_text(NODES)), rules=False, recovery=False)
    assert system.finish(system.manager.change_mode("robot", "FAST")).succeeded
    return system


def shown(monitor: Monitor) -> list[str]:
    return [row.part for row in monitor.current()[0]]


def test_a_limit_shows_errors_first_then_other_divergences_then_the_rest_in_display_order(
        rig: SimulatedSystem) -> None:
    monitor = Monitor(rig.manager, io.StringIO(), selection=Selection(limit=5))
    rows, summary = monitor.current()
    assert [row.part for row in rows] == ["robot", "n00", "n01", "n02", "n03"]
    assert (summary.parts, summary.systems, summary.nodes, summary.diverging, summary.shown) == (301, 1, 300, 0, 5)
    rig.backend.set_parameter("n250", "speed", 9.0)  # n250 leaves its mode, and robot with it
    rig.run(0.5)  # within the grace period: divergences, not errors yet
    rows, summary = monitor.current()
    assert [row.part for row in rows] == ["robot", "n00", "n01", "n02", "n250"]
    assert (summary.diverging, summary.errors) == (2, 0)
    rig.backend.set_parameter("n120", "speed", 9.0)
    rig.run(3.0)  # both are errors now
    assert shown(monitor) == ["robot", "n00", "n01", "n120", "n250"]
    assert monitor.current()[1].errors == 3
    monitor.close()


def test_patterns_and_diverging_narrow_the_rows_and_the_summary_still_counts_every_part(
        rig: SimulatedSystem) -> None:
    monitor = Monitor(rig.manager, io.StringIO(), selection=Selection(("n1?", "robot"), diverging=True))
    assert shown(monitor) == []
    assert monitor.current()[1].describe() == "301 parts (1 system, 300 nodes): none diverges; 0 shown"
    rig.backend.set_parameter("n15", "speed", 9.0)
    rig.backend.set_parameter("n150", "speed", 9.0)  # diverges, but does not match n1?
    rig.run(3.0)
    assert shown(monitor) == ["robot", "n15"]
    assert monitor.current()[1].describe() == "301 parts (1 system, 300 nodes): 3 diverge, 3 errors; 2 shown"
    everything = Monitor(rig.manager, io.StringIO(), selection=Selection(("n1?",)))
    assert shown(everything) == [f"n1{i}" for i in range(10)]


def test_a_refresh_reads_only_the_shown_parts_that_changed(rig: SimulatedSystem,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monitor = Monitor(rig.manager, io.StringIO(), selection=Selection(limit=10))
    monitor.refresh()
    read: list[str] = []
    status = ModeManager.status

    def counted(manager: ModeManager, part: str):  # type: ignore[no-untyped-def]
        read.append(part)
        return status(manager, part)

    monkeypatch.setattr(ModeManager, "status", counted)
    rig.backend.set_parameter("n200", "speed", 9.0)
    assert monitor.refresh()
    assert sorted(read) == ["n200", "robot"]  # n200 shows now (it diverges); robot changed; nothing else
    read.clear()
    assert not monitor.refresh() and read == []


def test_summary_under_the_table_only_when_parts_are_left_out(rig: SimulatedSystem) -> None:
    console = Console(record=True, width=120)
    Monitor(rig.manager, console, selection=Selection(limit=3)).print_table()
    text = console.export_text()
    assert "301 parts (1 system, 300 nodes): none diverges; 3 shown" in text
    assert "n02" not in text and "n01" in text
    rows, summary = Monitor(rig.manager, io.StringIO(), selection=Selection(limit=3)).current()
    assert render_text(rows, summary).splitlines()[-1] == " 301 parts (1 system, 300 nodes): none diverges; 3 shown"
    console = Console(record=True, width=120)
    Monitor(rig.manager, console).print_table()
    assert "shown" not in console.export_text()


def test_json_changes_carry_only_what_changed_and_what_left(rig: SimulatedSystem) -> None:
    stream = io.StringIO()
    monitor = Monitor(rig.manager, stream, selection=Selection(diverging=True), changes=True)
    monitor.refresh()
    rig.backend.set_parameter("n07", "speed", 9.0)
    monitor.refresh()
    rig.backend.set_parameter("n07", "speed", 2.0)
    rig.run(0.1)
    monitor.refresh()
    first, fault, healed = (json.loads(line) for line in stream.getvalue().splitlines())
    assert first["parts"] == [] and first["summary"]["parts"] == 301 and "left" not in first
    assert [entry["part"] for entry in fault["parts"]] == ["robot", "n07"] and fault["left"] == []
    assert healed["parts"] == [] and healed["left"] == ["robot", "n07"]
    assert to_json([], 0.0) == {"time": 0.0, "parts": []}


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["monitor", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_rows_parts_and_changes(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    model = tmp_path / "flat.yaml"
    model.write_text(flat_system_text(NODES))
    code, out, err = run_cli(capsys, str(model), "--change", "robot=FAST", "--once", "--speed", "0")
    assert (code, err) == (0, "")
    assert len(re.findall(r"^ *n\d+ ", out, re.MULTILINE)) == 99  # robot, and 99 nodes
    assert "301 parts (1 system, 300 nodes): none diverges; 100 shown" in out
    code, out, err = run_cli(capsys, str(model), "--change", "robot=FAST", "--once", "--speed", "0",
                             "--part", "n29?", "--rows", "4")
    assert [line.split()[0] for line in out.splitlines() if line.strip().startswith("n29")] == [
        "n290", "n291", "n292", "n293"]
    code, out, err = run_cli(capsys, str(model), "--change", "robot=FAST", "--change", "n05=__DEFAULT__",
                             "--speed", "0", "--json", "--changes")
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines[0]["parts"]) == 301 and len(lines[-1]["parts"]) <= 2
    rows = {}
    for line in lines:  # the diffs, applied in order, make what a whole line would show
        rows.update({entry["part"]: entry for entry in line["parts"]})
    code, out, err = run_cli(capsys, str(model), "--change", "robot=FAST", "--change", "n05=__DEFAULT__",
                             "--speed", "0", "--json")
    whole = json.loads(out.splitlines()[-1])
    assert list(rows.values()) == whole["parts"] and lines[-1]["summary"] == whole["summary"]


def test_cli_bad_selections_are_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "pilot", "--changes")
    assert code == 2 and "--changes is for --json lines" in err and out == ""
    code, out, err = run_cli(capsys, "pilot", "--part", "amcll*", "--json")
    assert code == 2 and err.startswith("sm-bt monitor: error: --part amcll*: matches no part of pilot")
    code, out, err = run_cli(capsys, "pilot", "--rows", "0")
    assert code == 2 and "'0' must be 1 or more" in err.replace("0 must", "'0' must")


def test_the_rest_fills_a_limit_from_the_top_of_the_hierarchy_down() -> None:
    from model_files import fixture

    system = SimulatedSystem(fixture("nested"), rules=False, recovery=False)  # robot > base > drive, lidar; arm
    assert shown(Monitor(system.manager, io.StringIO(), selection=Selection(limit=2))) == ["base", "robot"]
    assert shown(Monitor(system.manager, io.StringIO(), selection=Selection(limit=3))) == ["base", "robot", "arm"]


@st.composite
def _selection_cases(draw: st.DrawFn) -> tuple[list[str], list[str], dict[str, bool], Selection]:
    names = draw(st.lists(st.text("abc", min_size=1, max_size=3), min_size=1, max_size=25, unique=True))
    fill = draw(st.permutations(names))
    diverging = draw(st.dictionaries(st.sampled_from([*names, "elsewhere"]), st.booleans(), max_size=len(names) // 2))
    patterns = draw(st.lists(st.sampled_from(["a*", "?b", "c", "*"]), max_size=2))
    # Mostly a limit below the number of parts: where the order of what is shown matters.
    limit = draw(st.none() | st.integers(1, max(1, len(names) - 1)) | st.integers(1, len(names) + 5))
    selection = Selection(tuple(patterns), draw(st.booleans()), limit)
    return names, list(fill), diverging, selection


@given(_selection_cases())
@examples(300)
def test_a_selection_shows_what_its_rules_say(case: tuple[list[str], list[str], dict[str, bool], Selection]) -> None:
    """Against the rules written out plainly: the matching parts (only the diverging ones if asked),
    and over the limit errors first, then other divergences (each in display order), then the
    rest from the top of the hierarchy down; shown in display order."""
    names, top_down, diverging, selection = case
    candidates = selection.names(names)
    place = {part: index for index, part in enumerate(candidates)}
    fill = [place[part] for part in top_down if part in place]
    expected = [part for part in candidates if not selection.diverging or part in diverging]
    if selection.limit is not None and len(expected) > selection.limit:
        def rank(part: str) -> tuple[int, int]:
            if part in diverging:
                return (0 if diverging[part] else 1, place[part])
            return (2, top_down.index(part))
        expected = sorted(sorted(expected, key=rank)[:selection.limit], key=place.__getitem__)
    assert shown_parts(candidates, place, fill, diverging, selection) == expected
