"""The mode monitor: rows, rich and JSON rendering, the Monitor's refresh, and ``sm-bt monitor``."""

from __future__ import annotations

import io
import json
from typing import Any

import pytest
from model_files import bundled, fixture
from rich.console import Console
from rich.table import Table

from sm_bt.cli import main
from sm_bt.engine.events import Cause
from sm_bt.engine.lifecycle import Transition
from sm_bt.monitor import ERROR_STYLE, TRANSIENT_STYLE, Monitor, Row, render_rich, render_text, snapshot, to_json
from sm_bt.sim import SimulatedSystem


def by_part(rows: list[Row]) -> dict[str, Row]:
    return {row.part: row for row in rows}


def normal(rig: SimulatedSystem) -> None:
    """Configure the pilot and put it in f_normal_mode."""
    assert rig.finish(rig.manager.change_state("pilot", "configure")).succeeded
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded


def record(width: int = 120) -> Console:
    return Console(record=True, width=width)


def row_index(table: Table, part: str) -> int:
    """The index of ``part``'s row in ``table`` (section headings are rows too)."""
    names = [str(cell) for cell in table.columns[1].cells]
    return names.index(part)


# -- rows --------------------------------------------------------------------------------------


def test_rows_are_systems_then_nodes_each_sorted() -> None:
    rig = SimulatedSystem(fixture("nested"), rules=False, recovery=False)
    rows = snapshot(rig.manager)
    assert [(r.kind, r.part) for r in rows] == [
        ("system", "base"), ("system", "robot"), ("node", "arm"), ("node", "drive"), ("node", "lidar")]


def test_inferred_values_carry_the_marker_and_the_flags() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    rows = by_part(snapshot(rig.manager))
    assert (rows["pilot"].actual_state, rows["pilot"].raw_state, rows["pilot"].state_inferred) == \
        ("unconfigured(*)", "unconfigured", True)
    assert (rows["amcl"].actual_state, rows["amcl"].state_inferred) == ("unconfigured", False)
    assert rows["amcl"].target_state == "" and not rows["amcl"].diverges
    normal(rig)
    rows = by_part(snapshot(rig.manager))
    pilot = rows["pilot"]
    assert (pilot.target_state, pilot.actual_state, pilot.target_mode, pilot.actual_mode) == \
        ("active", "active(*)", "f_normal_mode", "f_normal_mode(*)")
    amcl = rows["amcl"]
    assert (amcl.actual_state, amcl.actual_mode, amcl.raw_mode, amcl.mode_inferred) == \
        ("active", "__DEFAULT__(*)", "__DEFAULT__", True)
    laser = rows["pointcloud_to_laser"]  # inactive: no mode, so nothing inferred about one
    assert (laser.actual_mode, laser.raw_mode, laser.mode_inferred) == ("", "", False)
    assert not any(row.diverges for row in rows.values())


def test_divergence_causes_in_flight_then_grace_then_fault() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.manager.change_state("pilot", "configure")
    rig.run(0.02)
    pilot = by_part(snapshot(rig.manager))["pilot"]
    assert (pilot.diverges, pilot.cause, pilot.error, pilot.since) == (True, Cause.IN_FLIGHT, False, 0.0)
    rig.run(1.0)
    assert rig.manager.change_mode("pilot", "f_normal_mode")
    rig.run(1.0)
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE)
    rig.run(0.5)
    rows = by_part(snapshot(rig.manager))
    assert (rows["laser_resender"].cause, rows["laser_resender"].error) == (Cause.GRACE, False)
    assert rows["laser_resender"].actual_state == "inactive"
    assert rows["amcl"].cause is None
    rig.run(3.0)
    rows = by_part(snapshot(rig.manager))
    assert (rows["laser_resender"].cause, rows["laser_resender"].error) == (Cause.FAULT, True)
    assert (rows["pilot"].cause, rows["pilot"].error) == (Cause.FAULT, True)
    assert "! laser_resender" in render_text(list(rows.values()))


def test_override_is_an_error_divergence() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    normal(rig)
    assert rig.finish(rig.manager.change_state("laser_resender", "deactivate")).succeeded
    rig.run(3.0)
    rows = by_part(snapshot(rig.manager))
    assert (rows["pilot"].cause, rows["pilot"].error) == (Cause.OVERRIDE, True)
    assert rows["laser_resender"].cause is None  # it is where it was asked to be


# -- rich --------------------------------------------------------------------------------------


def test_rich_table_shows_sections_values_markers_and_legend() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    normal(rig)
    table = render_rich(snapshot(rig.manager), title="the pilot")
    console = record()
    console.print(table)
    text = console.export_text()
    lines = text.splitlines()
    assert "the pilot" in lines[0]
    order = [name for name in ("systems", "pilot", "nodes", "amcl", "pointcloud_to_laser")
             if any(line.split()[:1] == [name] for line in lines)]
    assert order == ["systems", "pilot", "nodes", "amcl", "pointcloud_to_laser"]
    starts = {name: next(i for i, line in enumerate(lines) if line.split()[:1] == [name]) for name in order}
    assert starts["systems"] < starts["pilot"] < starts["nodes"] < starts["amcl"] < starts["pointcloud_to_laser"]
    pilot = lines[starts["pilot"]].split()
    assert pilot == ["pilot", "active", "active(*)", "f_normal_mode", "f_normal_mode(*)"]
    assert lines[starts["amcl"]].split() == ["amcl", "active", "active", "__DEFAULT__", "__DEFAULT__(*)"]
    assert "(*) inferred" in text and "! error" in text and "~ settling" in text
    assert all(row.style is None for row in table.rows)  # nothing diverges


def test_rich_rows_are_styled_by_divergence() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    normal(rig)
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE)
    rig.run(0.5)
    table = render_rich(snapshot(rig.manager))
    laser = row_index(table, "laser_resender")
    assert table.rows[laser].style == TRANSIENT_STYLE
    assert str(list(table.columns[0].cells)[laser]) == "~"
    assert table.rows[row_index(table, "amcl")].style is None

    rig.run(3.0)
    table = render_rich(snapshot(rig.manager))
    for part in ("laser_resender", "pilot"):
        index = row_index(table, part)
        assert table.rows[index].style == ERROR_STYLE
        assert str(list(table.columns[0].cells)[index]) == "!"
    console = record()
    console.print(table)
    styled = console.export_text(styles=True, clear=False)
    assert "\x1b[1;31m" in styled  # bold red reaches the terminal
    assert "laser_resender" in console.export_text()


# -- JSON --------------------------------------------------------------------------------------


def test_json_snapshot_shape_and_round_trip() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    normal(rig)
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE)
    rig.run(3.0)
    data = to_json(snapshot(rig.manager), rig.clock.now())
    assert json.loads(json.dumps(data)) == data
    assert data["time"] == pytest.approx(rig.clock.now())
    parts = {entry["part"]: entry for entry in data["parts"]}
    assert [entry["part"] for entry in data["parts"]][:2] == ["pilot", "amcl"]
    assert set(parts["amcl"]) == {"part", "kind", "target_state", "target_mode", "actual_state", "actual_mode",
                                  "state_inferred", "mode_inferred", "divergence", "held_by"}
    assert parts["amcl"] == {
        "part": "amcl", "kind": "node", "target_state": "active", "target_mode": "__DEFAULT__",
        "actual_state": "active", "actual_mode": "__DEFAULT__", "state_inferred": False, "mode_inferred": True,
        "divergence": None, "held_by": None,
    }
    laser = parts["laser_resender"]
    assert (laser["actual_state"], laser["actual_mode"], laser["mode_inferred"]) == ("inactive", None, False)
    assert laser["divergence"]["cause"] == "fault" and laser["divergence"]["error"] is True
    assert 0 < laser["divergence"]["since"] < rig.clock.now()
    pilot = parts["pilot"]
    assert (pilot["kind"], pilot["state_inferred"], pilot["divergence"]["cause"]) == ("system", True, "fault")


def test_json_times_are_seconds_since_the_start_of_the_run() -> None:
    """On ROS the clock is monotonic time since boot: 'since' was raw clock time while 'time' was
    relative to the run's start. Both count from the epoch now."""
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    normal(rig)
    fault_at = rig.clock.now()
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE)
    rig.run(3.0)
    epoch = 1.0
    data = to_json(snapshot(rig.manager), rig.clock.now(), epoch)
    laser = next(entry for entry in data["parts"] if entry["part"] == "laser_resender")
    assert data["time"] == pytest.approx(rig.clock.now() - epoch)
    assert fault_at - epoch <= laser["divergence"]["since"] < data["time"]


def test_json_has_nulls_before_any_target() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    entry = to_json(snapshot(rig.manager), 0.0)["parts"][0]
    assert (entry["part"], entry["target_state"], entry["target_mode"], entry["actual_mode"]) == \
        ("pilot", None, None, None)


# -- Monitor -----------------------------------------------------------------------------------


def test_monitor_renders_only_when_something_changed() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    console = record()
    monitor = Monitor(rig.manager, console, title="pilot")
    assert monitor.refresh() is True  # the first view
    assert monitor.refresh() is False
    rig.run(1.0)  # nothing happens to the nodes
    assert monitor.refresh() is False
    assert monitor.renders == 1
    request = rig.manager.change_state("pilot", "configure")
    assert monitor.dirty and monitor.renders == 1  # the callback only marks; nothing is drawn in it
    rig.finish(request)
    assert monitor.refresh() is True
    assert monitor.refresh() is False
    assert monitor.renders == 2
    text = console.export_text()
    assert text.count("pilot at t =") == 2
    assert "unconfigured(*)" in text and "inactive(*)" in text
    monitor.print_table()  # on demand, changed or not
    assert monitor.renders == 3
    monitor.close()
    rig.finish(rig.manager.change_state("pilot", "activate"))
    assert not monitor.dirty  # no longer following the manager


def test_monitor_json_lines_one_per_change() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    stream = io.StringIO()
    monitor = Monitor(rig.manager, stream)
    assert monitor.json
    with monitor.live():  # nothing to keep in place: lines as usual
        monitor.refresh()
        rig.finish(rig.manager.change_state("pilot", "configure"))
        monitor.refresh()
        monitor.refresh()
        rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
        monitor.refresh()
    lines = stream.getvalue().splitlines()
    assert len(lines) == 3 == monitor.renders
    states = [by_state(json.loads(line))["pilot"] for line in lines]
    assert states == [("unconfigured", None), ("inactive", None), ("active", "f_normal_mode")]


def by_state(data: dict[str, Any]) -> dict[str, tuple[str, str | None]]:
    return {entry["part"]: (entry["actual_state"], entry["actual_mode"]) for entry in data["parts"]}


def test_monitor_live_updates_in_place_and_leaves_the_last_table() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    console = record()
    monitor = Monitor(rig.manager, console, title="pilot")
    with monitor.live():
        assert monitor.renders == 1
        rig.finish(rig.manager.change_state("pilot", "configure"))
        assert monitor.refresh() is True
        assert monitor.refresh() is False
    assert monitor.renders == 2
    text = console.export_text()
    assert text.count("pilot at t =") == 1  # not a terminal: Live shows the final view once
    assert "inactive(*)" in text and "unconfigured" not in text


# -- sm-bt monitor -----------------------------------------------------------------------------


def run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(["monitor", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_json_follows_the_requests(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "pilot", "--change", "pilot=configure", "--change", "pilot=f_normal_mode",
                             "--json", "--speed", "0")
    assert (code, err) == (0, "")
    snapshots = [json.loads(line) for line in out.splitlines()]
    assert len(snapshots) >= 3
    assert by_state(snapshots[0])["pilot"] == ("unconfigured", None)
    final = by_state(snapshots[-1])
    assert final["pilot"] == ("active", "f_normal_mode")
    assert final["amcl"] == ("active", "__DEFAULT__")
    assert final["pointcloud_to_laser"] == ("inactive", None)
    times = [s["time"] for s in snapshots]
    assert times == sorted(times)
    assert len({json.dumps(s["parts"]) for s in snapshots}) == len(snapshots)  # only changes are printed


def test_cli_unknown_mode_is_a_usage_error_before_anything_runs(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "pilot", "--change", "pilot=configure", "--change", "pilot=nope",
                             "--json", "--once", "--speed", "0")
    assert code == 2
    assert err.startswith("sm-bt monitor: error: --change pilot=nope: 'nope' is neither a mode of pilot nor a "
                          "transition (modes: ")
    assert "f_normal_mode" in err and "Traceback" not in err
    assert out == ""  # refused up front: not even the first request ran


def test_cli_unknown_part_and_bad_values(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run_cli(capsys, "pilot", "--change", "nobody=configure", "--speed", "0", "--once")
    assert code == 2 and "no part 'nobody' in pilot" in err and "Traceback" not in err
    code, _, err = run_cli(capsys, "pilot", "--change", "pilot", "--speed", "0")
    assert code == 2 and "not PART=MODE" in err
    code, _, err = run_cli(capsys, "pilot", "--speed", "-1")
    assert code == 2 and "--speed" in err
    code, _, err = run_cli(capsys, "no_such_model", "--speed", "0")
    assert code == 1 and "no bundled model of that name" in err


def test_cli_once_prints_exactly_one_table(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "pilot", "--change", "pilot=configure", "--change", "pilot=f_normal_mode",
                             "--once", "--speed", "0")
    assert (code, err) == (0, "")
    assert out.count("pilot at t =") == 1
    assert out.count("(*) inferred") == 1
    pilot = next(line for line in out.splitlines() if line.split()[:2] == ["pilot", "active"])
    assert pilot.split() == ["pilot", "active", "active(*)", "f_normal_mode", "f_normal_mode(*)"]


def test_cli_without_a_terminal_prints_a_table_per_change(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "pilot", "--change", "pilot=configure", "--duration", "5", "--speed", "0")
    assert code == 0
    # The start, and configured: five virtual seconds of nothing else add no table.
    assert out.count("pilot at t =") == 2
    assert "pilot at t = 0.00 s" in out and "inactive(*)" in out


def test_cli_duration_too_short_fails(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(capsys, "pilot", "--change", "pilot=configure", "--change", "pilot=f_normal_mode",
                             "--duration", "0.01", "--json", "--once", "--speed", "0")
    assert code == 1
    assert "pilot=configure: not done when --duration ran out" in err
    assert "pilot=f_normal_mode: not requested, --duration ran out" in err
    assert json.loads(out)["time"] == pytest.approx(0.01)


def test_cli_help_mentions_ros_watching(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(capsys, "--help")
    assert code == 0
    assert "--ros" in out and "live ROS 2 nodes" in out
    assert "--change" in out and "--json" in out and "--once" in out


# -- the console: plain text on pipes, NO_COLOR on terminals ------------------------------------


def _printed(console_stream: io.StringIO) -> str:
    from sm_bt.monitor import terminal_console

    console = terminal_console(console_stream)
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    normal(rig)
    console.print("[  12.00 s] " + "a long narration line " * 20, style="bold red", markup=False)
    console.print(render_rich(snapshot(rig.manager), title="pilot"))
    return console_stream.getvalue()


def test_piped_output_is_plain_unwrapped_text_without_trailing_spaces() -> None:
    out = _printed(io.StringIO())
    assert "\x1b" not in out
    lines = out.splitlines()
    assert lines[0] == "[  12.00 s] " + ("a long narration line " * 20).rstrip()  # one line, however long
    assert not [line for line in lines if line != line.rstrip()]
    assert any(line.split() == ["amcl", "active", "active", "__DEFAULT__", "__DEFAULT__(*)"] for line in lines)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_gets_colour_unless_no_color_is_set(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setenv("TERM", "xterm-256color")
    assert "\x1b[31m" in _printed(_Terminal()) or "\x1b[1;31m" in _printed(_Terminal())
    monkeypatch.setenv("NO_COLOR", "1")
    coloured = _printed(_Terminal())
    assert "31m" not in coloured and "33m" not in coloured  # no red, no yellow (bold may stay)


def test_who_holds_which_parts_is_under_the_table() -> None:
    from sm_bt.sim import SimulatedSystem

    system = SimulatedSystem(bundled("pilot"))
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="metacontroller")
    system.finish(hold.request)
    text = render_text(snapshot(system.manager))
    assert text.splitlines()[-1] == (" held by metacontroller (priority 60): pilot, amcl, controller_server, "
                                     "laser_resender, pointcloud_to_laser")
    assert to_json(snapshot(system.manager), 0.0)["parts"][0]["held_by"] == "metacontroller (priority 60)"
    hold.release()
    assert "held by" not in render_text(snapshot(system.manager))
