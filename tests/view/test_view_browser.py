"""The web view as a person sees it: a real headless Chromium loads the page while the demo runs (the
recorded demo replayed is tests/view/test_view_replay.py), and what a person must see without scrolling
is checked from the boxes the page measured in the DOM it built (?check, see sm_bt/view/static/check.js
and tests/support/page_checks.py): the running behaviours' names (>= 11 px, not cut), every cell of the
mode table, the time axis and the events of the tick shown, inside the viewport and inside what clips
them, and a document no wider or taller than the viewport. Chromium's 1280x800 window gives the page
1280x713 (its own bars take the rest, as on a laptop), which is checked; the screenshots, of the whole
window, go to build/view/ (look at them).

docs/mission-failed.png is such a screenshot: the run of a scenario whose expectation failed (`sm-bt
test`), opened at the failing moment as `sm-bt view --at` opens it. It carries a fingerprint of the
page's sources and of the scenario's files (a PNG text chunk): ``SM_BT_WRITE_VIEW_PNG=1 pytest tests/view
-k failed_expectation`` takes it again, and otherwise the test fails once they changed since."""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from page_checks import (
    ROOT,
    SHOTS,
    WRITE_DOCS_PNG,
    assert_nothing_cut,
    browse,
    fingerprint,
    inside,
    layout_report,
    text_of,
    with_text,
)
from rich.console import Console
from ros_processes import line_within

from sm_bt.trees.pilot.demo import Demo, Options
from sm_bt.trees.pilot.platforms import SimulatedPlatform
from sm_bt.view import View, attach_view, read_recording
from sm_bt.view.assets import ASSETS, NEEDED, from_wheel, kept_wheel, missing
from sm_bt.view.frames import Frame
from sm_bt.view.server import ViewServer

pytestmark = pytest.mark.browser

FAILED_PNG = ROOT / "docs" / "mission-failed.png"
EXAMPLES = ROOT / "docs" / "examples"


@pytest.fixture
def demo_thread() -> Iterator[tuple[Demo, View]]:
    """The demo running in a thread, with a view of its own (which outlives the run, so the page
    can still be loaded when the demo is done)."""
    demo = Demo(Options(speed=20.0, cycles=1, laser_failure_at=5.0), Console(file=io.StringIO(), width=120))
    view = attach_view(demo.tree, demo.manager, port=0)
    runner = threading.Thread(target=demo.run, name="demo", daemon=True)
    runner.start()
    yield demo, view
    assert isinstance(demo.platform, SimulatedPlatform)
    demo.platform.speed = 0.0  # nobody looks at the rest of the run: no pacing (12 s less)
    runner.join(120.0)
    view.close()


def test_the_page_shows_the_running_tree_the_modes_and_the_events_during_the_demo(
        demo_thread: tuple[Demo, View]) -> None:
    _, view = demo_thread
    assert view.url is not None and isinstance(view.server, ViewServer)
    deadline = time.monotonic() + 60.0
    while not any(event["kind"] == "divergence" and "(fault" in event["text"]
                  for frame in view.server.history() for event in frame.get("events", ())):
        assert time.monotonic() < deadline, "no fault divergence in the demo's frames"
        time.sleep(0.2)
    dom = browse(view.url + "?once&check", screenshot=SHOTS / "live-1280x800.png")
    report = layout_report(dom)
    assert_nothing_cut(report, "live")
    running = {item["name"] for item in report["running"]}
    assert {"Pilot", "Patrol with contingencies", "Patrol"} <= running, running
    assert '<tr data-part="pilot" class="system' in dom
    assert "active.<wbr>f_<wbr>" in dom.split('data-part="pilot"', 1)[1].split("</tr>", 1)[0]  # wraps there if it must
    assert '<li class="divergence' in dom and "(fault" in dom
    assert 'data-once="true"' in dom


def test_long_part_and_mode_names_wrap_instead_of_being_cut() -> None:
    long = "active.a_mode_with_an_unusually_long_and_descriptive_name_" + "x" * 20
    modes = [{"part": f"{kind}_with_a_rather_long_name_{index}", "kind": kind, "target": long,
              "actual": long + "_y", "inferred": True, "cause": "in_flight", "error": False}
             for index, kind in enumerate(("system", "node", "node", "node", "node"))]
    behaviours = {"r": {"id": "r", "name": "Root", "status": "RUNNING", "colour": "#FFA500", "details": "...",
                        "data": {}, "children": ["c"]},
                  "c": {"id": "c", "name": "Change to a long mode", "status": "RUNNING", "colour": "#555555",
                        "details": long, "data": {"Feedback": ""}}}
    frames: list[Frame] = [{"tick": 1, "time": 0.0, "status": "RUNNING", "key": True, "behaviours": behaviours,
                            "visited": ["r", "c"], "blackboard": {}, "modes": modes,
                            "events": [{"time": 0.0, "kind": "request", "part": modes[0]["part"],
                                        "text": f"#1 change_mode {modes[0]['part']} {long} started [tree]",
                                        "request": 1, "done": False, "ok": None}]}]
    server = ViewServer(port=0, frames=frames)
    try:
        report = layout_report(browse(server.url + "?check", screenshot=SHOTS / "long-names-1280x800.png"))
    finally:
        server.close()
    assert_nothing_cut(report, "long names")


def test_a_failed_expectation_is_listed_and_marked_at_its_moment(tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The documentation's scenario with one expectation changed, as docs/mission-tests.md tells."""
    from sm_bt.cli import main

    for name in ("nav_mission.xml", "nav_stubs.yaml", "nav_scenario.yaml"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    scenario = tmp_path / "nav_scenario.yaml"
    scenario.write_text(scenario.read_text().replace("{at: 3.5, modes: {pilot: active.f_slow_mode,",
                                                     "{at: 3.5, modes: {pilot: active.f_degraded_mode,"))
    monkeypatch.chdir(tmp_path)  # the scenario's name as a person types it
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["test", "nav_scenario.yaml", "--runs", "runs"]) == 1
    found = re.search(r"the run: sm-bt view (\S+) --at ([\d.]+)", out.getvalue())
    assert found, out.getvalue()
    server = ViewServer(port=0, frames=read_recording(found[1]))
    try:
        shot = SHOTS / "mission-failed-1280x800.png"
        dom = browse(f"{server.url}?check&at={found[2]}", screenshot=shot)
    finally:
        server.close()
    report = layout_report(dom)
    assert_nothing_cut(report, "a failed expectation")
    assert report["current"][-1]["name"].startswith("3.50 s  nav_scenario.yaml:12: at 3.5 s"), report["current"]
    assert '<li class="expectation now" data-index=' in dom, "listed as the newest event of the moment shown"
    assert '<line x1=' in dom and 'class="expectation"' in dom, "the timeline marks the failure"
    files = fingerprint(*(EXAMPLES / name for name in ("nav_mission.xml", "nav_stubs.yaml",
                                                              "nav_scenario.yaml")))
    if os.environ.get(WRITE_DOCS_PNG):
        FAILED_PNG.write_bytes(with_text(shot.read_bytes(), files))
    png = FAILED_PNG.read_bytes()
    assert png[16:24] == struct.pack(">II", 1280, 800), "docs/mission-failed.png is a 1280x800 screenshot"
    assert text_of(png) == files, (
        f"docs/mission-failed.png shows an older page or scenario: take it again with {WRITE_DOCS_PNG}=1 "
        "pytest tests/view -k failed_expectation (and look at it)")


def test_the_demo_serves_its_view_when_asked() -> None:
    out = io.StringIO()
    demo = Demo(Options(speed=0.0, cycles=1, view=0), Console(file=out, width=120))
    assert demo.view is not None and demo.view.url is not None
    with urllib.request.urlopen(demo.view.url, timeout=5.0) as answer:
        assert answer.status == 200 and b"sm_bt view" in answer.read()
    assert demo.run() == 0
    assert f"view: {demo.view.url}" in out.getvalue()


def test_a_quiet_demo_with_a_view_says_where_and_that_it_stays() -> None:
    """`sm-bt demo --view --quiet`: the address first, the summary, then why the command goes on
    (and how to end it), while the page says the run is over; Ctrl-C ends it quietly."""
    script = Path(sys.executable).with_name("sm-bt")
    demo = subprocess.Popen([str(script), "demo", "--speed", "0", "--quiet", "--cycles", "1", "--view", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [line_within(demo.stdout, 60.0, "sm-bt demo --view: its first lines") for _ in range(2)]
        assert lines[0].startswith("view: http://127.0.0.1:"), lines
        url = lines[0].split()[1]
        while not lines[-1].startswith("run over") and lines[-1]:
            lines.append(line_within(demo.stdout, 60.0, "sm-bt demo --view: the run's end"))
        assert lines[-1].strip() == f"run over; the view stays at {url} until Ctrl-C", lines
        assert any(line.startswith("Summary") for line in lines)
        dom = browse(url + "?check")  # no ?once: the page learns that the run is over from the server
        assert 'data-ended="true"' in dom and re.search(r'<span id="ended" class="status" title="[^"]*">', dom)
        assert layout_report(dom)["frames"] > 100
        demo.send_signal(signal.SIGINT)
        _, err = demo.communicate(timeout=30)
    finally:
        if demo.poll() is None:
            demo.kill()
    assert demo.returncode == 0 and "Traceback" not in err, err


def test_the_assets_come_whole_from_the_wheel() -> None:
    assert missing() == [], "python -m sm_bt.view.assets (make) extracts them"
    wheel = kept_wheel()
    assert wheel is not None, "the install step keeps the wheel it extracted them from"
    files = from_wheel(wheel)  # Qt's resource format decoded without Qt: 9 files, byte for byte
    assert sorted(files) == sorted(NEEDED) and sum(map(len, files.values())) == 1_215_399
    assert files["py_trees-0.6.js"].startswith(b"/*!\n * A library for rendering, with jointjs, a behaviour tree")
    assert all((ASSETS / name).read_bytes() == content for name, content in files.items())


def test_who_holds_a_part_is_a_column_of_the_modes_table_while_one_does(tmp_path: Path) -> None:
    """sm-bt demo --rules: while the laser rule holds degraded mode, the table says so on each
    held part; before the laser fails, nobody holds anything and the column is not there."""
    recording = tmp_path / "rules.jsonl"
    demo = Demo(Options(speed=0.0, cycles=1, rules=True, tree="rules", laser_repair_at=200.0, quiet=True,
                        record=str(recording)), Console(file=io.StringIO(), width=120))
    assert demo.run() == 0
    server = ViewServer(port=0, frames=read_recording(recording))
    try:
        held = browse(f"{server.url}?check&at=60", screenshot=SHOTS / "held-1280x800.png")
        before = browse(f"{server.url}?check&at=10")
    finally:
        server.close()
    assert_nothing_cut(layout_report(held), "the held-by column")
    assert '<table id="modes" class="holding">' in held
    assert held.count('<td class="held">rule degrade_from_normal (priority 100)</td>') == 5  # pilot and its 4 nodes
    assert '<table id="modes" class="">' in before or '<table id="modes">' in before
    assert '<td class="held">rule' not in before


def _nested_model_text(nodes: int, fanout: int = 10) -> str:
    """``nodes`` nodes (modes __DEFAULT__ and FAST) in systems of ``fanout``, nested up to ``root``."""
    names = [f"n{i}" for i in range(nodes)]
    text, level, depth = [], names, 0
    for name in names:
        text.append(f"{name}:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n"
                    "        ros__parameters:\n          speed: 1.0\n      FAST:\n        ros__parameters:\n"
                    "          speed: 2.0\n")
    while len(level) > 1:
        depth += 1
        groups = [level[i:i + fanout] for i in range(0, len(level), fanout)]
        level = ["root"] if len(groups) == 1 else [f"s{depth}_{i}" for i in range(len(groups))]
        for system, group in zip(level, groups, strict=True):
            parts = "".join(f"      {part}\n" for part in group)
            modes = "".join(f"      {mode}:\n" + "".join(f"        {part}: active.{mode}\n" for part in group)
                            for mode in ("__DEFAULT__", "FAST"))
            text.append(f"{system}:\n  ros__parameters:\n    type: system\n    parts:\n{parts}    modes:\n{modes}")
    return "".join(text)


def test_a_model_of_thousands_of_parts_shows_what_matters_and_how_many_there_are(tmp_path: Path) -> None:
    """2,000 nodes: the table shows the parts that diverge, then the top of the hierarchy, with a
    line that counts them all; the list leaves out what the requests explain and sums up the
    divergences beyond a frame's share; nothing is cut at 1280x800."""
    import py_trees

    from sm_bt.behaviours import ChangeMode
    from sm_bt.model.loader import load_model_text
    from sm_bt.sim import SimulatedSystem

    system = SimulatedSystem(load_model_text(_nested_model_text(2000), "nested-2000.yaml"), rules=False,
                             recovery=False)
    root = py_trees.composites.Sequence("Mission", memory=True, children=[
        ChangeMode("Bring up", part="root", mode="__DEFAULT__"), ChangeMode("Go fast", part="root", mode="FAST"),
        py_trees.behaviours.Running("Patrol")])
    tree = py_trees.trees.BehaviourTree(root)
    tree.setup(manager=system.manager)
    path = tmp_path / "large.jsonl"
    view = attach_view(tree, system.manager, port=None, record=path)
    for tick in range(60):
        if tick == 40:  # a fault of 60 nodes, and of the 9 systems above them
            for node in range(1200, 1260):
                system.backend.set_parameter(f"n{node}", "speed", 9.0)
        tree.tick()
        system.run(0.1)
    view.close()
    frames = read_recording(path)
    assert max(len(frame.get("modes", ())) for frame in frames) <= 8
    assert any("more divergences started or ended" in event["text"]
               for frame in frames for event in frame.get("events", ()))
    server = ViewServer(port=0, frames=frames)
    try:
        dom = browse(f"{server.url}?check", screenshot=SHOTS / "large-model-1280x800.png")
    finally:
        server.close()
    assert_nothing_cut(layout_report(dom), "2,000 nodes")
    summary = re.search(r'<p id="modes-summary">([^<]*)</p>', dom)
    assert summary and summary.group(1) == "2,223 parts (223 systems, 2,000 nodes): 69 diverge; 8 shown", summary
    rows = re.findall(r'<tr data-part="([^"]+)"', dom)
    assert rows == ["root", "s1_120", "s1_121", "s1_122", "s1_123", "s1_124", "s1_125", "s2_12"], rows


def test_the_fleet_demos_view_shows_the_fleet_tree_and_a_band_per_robot_while_one_is_cut_off(
        tmp_path: Path) -> None:
    """sm-bt demo --fleet: at 5.5 s robot1 is cut off; the table has the fleet and both robots
    (robot1 unknown), the timeline a band for each, and the tree waits for the night."""
    from sm_bt.trees.fleet.demo import FleetDemo, FleetOptions

    recording = tmp_path / "fleet.jsonl"
    demo = FleetDemo(FleetOptions(speed=0.0, quiet=True, record=str(recording)), Console(file=io.StringIO()))
    assert demo.run() == 0
    server = ViewServer(port=0, frames=read_recording(recording))
    try:
        dom = browse(f"{server.url}?check&at=5.5", screenshot=SHOTS / "fleet-1280x800.png")
    finally:
        server.close()
    report = layout_report(dom)
    width, height = report["viewport"]
    assert report["document"][0] <= width and report["document"][1] <= height, report["document"]
    assert [item["name"] for item in report["running"]] == ["fleet shift", "until the night"], report["running"]
    for item in report["running"] + report["cells"] + report["axis"]:
        assert inside(item["box"], [0, 0, width, height]) and inside(item["box"], item["clip"]), item
        assert not item.get("elided"), item
    rows = re.findall(r'<tr data-part="(\w+)"[^>]*><td>\w+</td><td>[^<]*(?:<wbr>[^<]*)*</td><td>([^<]*)', dom)
    assert [part for part, _ in rows] == ["fleet", "robot1", "robot2"], rows
    assert dict(rows)["robot1"] == "unknown", rows
    bands = re.findall(r'<text [^>]*class="part">(\w+)</text>', dom)
    assert bands == ["fleet", "robot1", "robot2"], bands
