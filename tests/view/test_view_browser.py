"""The web view as a person sees it: a real headless Chromium loads the page while the demo runs
(and a recorded run replayed), and the DOM it built must show the tree's behaviours, the pilot's
mode and a divergence. Screenshots go to build/view/ (look at them). The server itself: 404 and
405 for what it does not serve, and a browser that stops reading never holds up the ticks."""

from __future__ import annotations

import io
import shutil
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest
from rich.console import Console

from sm_bt.trees.pilot.demo import Demo, Options
from sm_bt.trees.pilot.platforms import SimulatedPlatform
from sm_bt.view import View, attach_view, read_recording
from sm_bt.view.assets import ASSETS, NEEDED, from_wheel, kept_wheel, missing
from sm_bt.view.server import ViewServer

pytestmark = pytest.mark.browser

SHOTS = Path(__file__).resolve().parents[2] / "build" / "view"


def _chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    assert found, "no chromium on PATH: `make test` installs it (tools/ensure_chromium.sh)"
    return found


def _browse(url: str, *, screenshot: Path | None = None, live: bool = True) -> str:
    """The DOM the page built (and a screenshot of it), once its work is done: Chromium's virtual
    time runs the page until nothing is pending, so a live page is loaded as ``/?once`` (the run so
    far, then its stream closes)."""
    if live:
        url += "?once"
    base = [_chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--window-size=1600,1000", "--virtual-time-budget=30000"]
    dom = subprocess.run([*base, "--dump-dom", url], capture_output=True, text=True, timeout=90)
    assert dom.returncode == 0, dom.stderr[-2000:]
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        shot = subprocess.run([*base, f"--screenshot={screenshot}", url], capture_output=True, text=True,
                              timeout=90)
        assert shot.returncode == 0 and screenshot.stat().st_size > 10_000, shot.stderr[-2000:]
    return dom.stdout


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


def test_the_page_shows_the_tree_the_modes_and_a_divergence_during_the_demo(
        demo_thread: tuple[Demo, View]) -> None:
    _, view = demo_thread
    assert view.url is not None and isinstance(view.server, ViewServer)
    deadline = time.monotonic() + 60.0
    while not any(event["kind"] == "divergence" and "(fault" in event["text"]
                  for frame in view.server.history() for event in frame["events"]):
        assert time.monotonic() < deadline, "no fault divergence in the demo's frames"
        time.sleep(0.2)
    dom = _browse(view.url, screenshot=SHOTS / "live.png")
    for behaviour in ("Laser lost", "f_degraded_mode on divergence", "Patrol with contingencies", "To wp_1"):
        assert behaviour in dom, behaviour  # drawn by py_trees_js
    assert '<tr data-part="pilot" class="system' in dom
    assert "active.f_" in dom.split('data-part="pilot"', 1)[1].split("</tr>", 1)[0]
    assert '<li class="divergence">' in dom and "(fault" in dom
    assert 'data-once="true"' in dom


def test_the_demo_serves_its_view_when_asked() -> None:
    out = io.StringIO()
    demo = Demo(Options(speed=0.0, cycles=1, view=0), Console(file=out, width=120))
    assert demo.view is not None and demo.view.url is not None
    with urllib.request.urlopen(demo.view.url, timeout=5.0) as answer:
        assert answer.status == 200 and b"sm_bt view" in answer.read()
    assert demo.run() == 0
    assert f"view: {demo.view.url}" in out.getvalue()


def test_a_recorded_run_replays_with_every_tick(tmp_path: Path) -> None:
    recording = tmp_path / "run.jsonl"
    demo = Demo(Options(speed=0.0, cycles=1, record=str(recording)), Console(file=io.StringIO(), width=120))
    assert demo.run() == 0
    frames = read_recording(recording)
    assert frames[-1]["status"] == "SUCCESS"
    server = ViewServer(port=0, frames=frames)
    try:
        dom = _browse(server.url, screenshot=SHOTS / "replay.png", live=False)
    finally:
        server.close()
    assert 'data-ended="true"' in dom, "the replay's end reached the page"
    assert "SUCCESS (run over)" in dom
    assert f'max="{len(frames) - 1}"' in dom, "the scrubber spans every recorded tick"
    assert "f_energy_saving_mode" in dom and "Recharge" in dom


def test_the_server_refuses_what_it_does_not_serve() -> None:
    server = ViewServer(port=0, frames=[])
    try:
        for path, method, code in (("nope", "GET", 404), ("assets/../view.js", "GET", 404),
                                   ("assets/secret.js", "GET", 404), ("", "POST", 405), ("events", "DELETE", 405)):
            request = urllib.request.Request(server.url + path, method=method, data=b"" if method == "POST" else None)
            with pytest.raises(urllib.error.HTTPError) as answered:
                urllib.request.urlopen(request, timeout=5.0)
            assert answered.value.code == code, (path, method)
            assert b"Traceback" not in answered.value.read()
        with urllib.request.urlopen(server.url + "frames.json", timeout=5.0) as answer:
            assert answer.status == 200 and answer.read() == b'{"live": false, "frames": []}'
    finally:
        server.close()


def test_a_browser_that_stops_reading_never_holds_up_publishing() -> None:
    server = ViewServer(port=0)
    host, port = server.url.split("//")[1].rstrip("/").split(":")
    stalled = socket.create_connection((host, int(port)), timeout=5.0)
    try:
        stalled.sendall(b"GET /events HTTP/1.1\r\nHost: x\r\n\r\n")  # and never reads
        frame = {"tick": 0, "time": 0.0, "tree": {"padding": "x" * 20_000}, "modes": [], "events": []}
        done = threading.Event()

        def publish() -> None:
            for tick in range(3000):  # ~60 MB: far more than the socket buffers hold
                server.publish({**frame, "tick": tick})
            done.set()

        threading.Thread(target=publish, daemon=True).start()
        assert done.wait(60.0), "publish blocked on a browser that does not read"
    finally:
        stalled.close()
        server.close()


def test_the_assets_come_whole_from_the_wheel() -> None:
    assert missing() == [], "python -m sm_bt.view.assets (make) extracts them"
    wheel = kept_wheel()
    assert wheel is not None, "the install step keeps the wheel it extracted them from"
    files = from_wheel(wheel)  # Qt's resource format decoded without Qt: 9 files, byte for byte
    assert sorted(files) == sorted(NEEDED) and sum(map(len, files.values())) == 1_215_399
    assert files["py_trees-0.6.js"].startswith(b"/*!\n * A library for rendering, with jointjs, a behaviour tree")
    assert all((ASSETS / name).read_bytes() == content for name, content in files.items())
