"""The web view of a recorded demo, replayed, as a person sees it in a headless Chromium: at 1280x800,
1600x1000 and 1920x1080, at the moments that draw the most (what tests/support/page_checks.py checks), a
request's plan, the scrubber's end, a page load's weight, and docs/view.png.

docs/view.png is such a screenshot (the demo's laser failure being handled, 1280x800). It carries
a fingerprint of the page's sources and of the demo tree's shape (a PNG text chunk):
``SM_BT_WRITE_VIEW_PNG=1 pytest tests/view -k docs`` takes it again, and otherwise
test_docs_view_png_is_current fails once the page or the tree changed since it was taken.

The demo is recorded once for the module: tests/conftest.py runs the module in one pytest-xdist worker."""

from __future__ import annotations

import io
import os
import re
import struct
from collections.abc import Iterator

import pytest
from page_checks import (
    ROOT,
    SHOTS,
    WRITE_DOCS_PNG,
    assert_nothing_cut,
    browse,
    fingerprint,
    layout_report,
    text_of,
    with_text,
)
from rich.console import Console

from sm_bt.trees.pilot.demo import Demo, Options
from sm_bt.view import read_recording
from sm_bt.view.frames import Frame
from sm_bt.view.server import ViewServer

pytestmark = pytest.mark.browser

SIZES = ((1280, 800), (1600, 1000), (1920, 1080))
DOCS_PNG = ROOT / "docs" / "view.png"
#: the timeline zoomed into the first minute.
DOCS_MOMENT = "at=17.6&span=0,60"
#: Moments of the demo checked at every size: the laser failure being handled (many events, two
#: running branches), and the robot going to recharge in energy saving mode (the deepest branch).
MOMENTS = {"laser-failure": "at=17.6", "recharge": "at=60"}


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> list[Frame]:
    """The whole demo (two rounds, the laser failure) recorded at full speed."""
    path = tmp_path_factory.mktemp("view") / "demo.jsonl"
    demo = Demo(Options(speed=0.0, quiet=True, record=str(path)), Console(file=io.StringIO(), width=120))
    assert demo.run() == 0
    return read_recording(path)


@pytest.fixture(scope="module")
def replay(recording: list[Frame]) -> Iterator[ViewServer]:
    server = ViewServer(port=0, frames=recording)
    yield server
    server.close()


@pytest.mark.parametrize("size", SIZES, ids=[f"{w}x{h}" for w, h in SIZES])
def test_nothing_is_cut_on_a_screen_of(size: tuple[int, int], replay: ViewServer) -> None:
    for moment, query in MOMENTS.items():
        shot = SHOTS / f"{moment}-{size[0]}x{size[1]}.png"
        report = layout_report(browse(f"{replay.url}?check&{query}", size=size, screenshot=shot))
        assert_nothing_cut(report, f"{moment} at {size}")
        names = {item["name"] for item in report["running"]}
        if moment == "laser-failure":  # both running branches: the contingency and the patrol
            assert {"f_degraded_mode on divergence", "Patrol round"} <= names, names
            assert any("gave up" in item["name"] for item in report["current"]), report["current"]
        else:
            assert "To recharge station" in names, names


def test_a_requests_plan_is_shown_with_it_in_the_list_and_on_its_band(replay: ViewServer) -> None:
    dom = browse(f"{replay.url}?at=17.6")
    item = re.search(r'<li class="request[^"]*"[^>]*title="(change_mode pilot f_degraded_mode: [^"]*)"[^>]*>'
                     r'([^<]*)</li>', dom)
    assert item, "the degraded-mode request's plan is on its list item"
    assert "(3 calls)" in item.group(2) and "amcl: active.__DEFAULT__ -&gt; active.DEGRADED" in item.group(1)
    # Request numbers count in the whole test process: any number.
    assert re.search(r"<title>#\d+ change_mode pilot f_degraded_mode started \[tree\]\n"
                     r"change_mode pilot f_degraded_mode: 3 calls", dom), "and on its band's tooltip"


def test_the_page_follows_the_scrubber_to_the_end_of_a_replay(replay: ViewServer, recording: list[Frame]) -> None:
    dom = browse(replay.url + "?check", screenshot=SHOTS / "replay-end-1280x800.png")
    assert 'data-ended="true"' in dom, "the replay's end reached the page"
    assert re.search(r'<span id="ended" class="status" title="[^"]*">run over</span>', dom), "said, and shown"
    assert f'max="{len(recording) - 1}"' in dom, "the scrubber spans every recorded frame"
    report = layout_report(dom)
    assert_nothing_cut(report, "the end of the run", running=False)
    last = [event["text"] for frame in recording for event in frame.get("events", ())][-1]
    assert last[:40] in report["current"][-1]["name"], (last, report["current"])  # the list followed


def test_a_page_load_of_the_demo_weighs_under_3_mb(recording: list[Frame]) -> None:
    """Everything, the py_trees_js assets included (a browser caches those): format 1 sent 29 MB."""
    server = ViewServer(port=0, frames=recording)
    try:
        browse(server.url)
        sent = dict(server.sent)
    finally:
        server.close()
    assets = sum(size for path, size in sent.items() if path.startswith("/assets/"))
    assert sent["/events"] <= 1_000_000 and sum(sent.values()) <= 3_000_000, sent
    assert assets > 1_000_000, "the assets were loaded too"


def test_docs_view_png_is_current(replay: ViewServer) -> None:
    if os.environ.get(WRITE_DOCS_PNG):
        shot = SHOTS / "docs-1280x800.png"
        assert_nothing_cut(layout_report(browse(f"{replay.url}?check&{DOCS_MOMENT}", screenshot=shot)), "docs")
        DOCS_PNG.write_bytes(with_text(shot.read_bytes(), fingerprint()))
    png = DOCS_PNG.read_bytes()
    assert png[16:24] == struct.pack(">II", 1280, 800), "docs/view.png is a 1280x800 screenshot"
    assert text_of(png) == fingerprint(), (
        f"docs/view.png shows an older page or tree: take it again with {WRITE_DOCS_PNG}=1 "
        "pytest tests/view -k docs_view_png (and look at it)")
