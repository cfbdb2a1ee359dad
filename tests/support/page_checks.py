"""What the view's browser tests share: a headless Chromium that loads a page and gives back the DOM
it built (and a screenshot), the layout report the page writes with ?check (sm_bt/view/static/check.js),
the check that what a person must see is in view, and the fingerprints of the screenshots kept in docs/."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
import struct
import subprocess
import zlib
from pathlib import Path
from typing import Any

from sm_bt.trees import pilot
from sm_bt.view.server import STATIC

ROOT = Path(__file__).resolve().parents[2]
#: The screenshots (look at them).
SHOTS = ROOT / "build" / "view"
WRITE_DOCS_PNG = "SM_BT_WRITE_VIEW_PNG"


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    assert found, "no chromium on PATH: `make test` installs it (tools/ensure_chromium.sh)"
    return found


def browse(url: str, *, size: tuple[int, int] = (1280, 800), screenshot: Path | None = None) -> str:
    """The DOM the page built (and a screenshot of the window), once its work is done: Chromium's
    virtual time runs the page until nothing is pending (a live page is loaded with ?once: the run
    so far, then its stream closes)."""
    command = [chromium(), "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
               f"--window-size={size[0]},{size[1]}", "--virtual-time-budget=30000", "--dump-dom", url]
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        screenshot.unlink(missing_ok=True)
        command.insert(-2, f"--screenshot={screenshot}")
    dom = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert dom.returncode == 0, dom.stderr[-2000:]
    if screenshot is not None:
        assert screenshot.stat().st_size > 10_000, dom.stderr[-2000:]
    return dom.stdout


def layout_report(dom: str) -> dict[str, Any]:
    found = re.search(r'<script id="layout-report" type="application/json">(.*?)</script>', dom, re.S)
    assert found, "the page wrote no layout report (?check)"
    report: dict[str, Any] = json.loads(found.group(1))
    return report


def inside(box: list[int], outer: list[int]) -> bool:
    return box[0] >= outer[0] and box[1] >= outer[1] and box[2] <= outer[2] and box[3] <= outer[3]


def assert_nothing_cut(report: dict[str, Any], where: str, running: bool = True) -> None:
    """What a person must see is in view: see the module's docstring."""
    width, height = report["viewport"]
    view = [0, 0, width, height]
    assert report["document"][0] <= width, f"{where}: the page is wider than the window: {report['document']}"
    assert report["document"][1] <= height, f"{where}: the page is taller than the window: {report['document']}"
    if running:
        assert report["running"], f"{where}: no running behaviour drawn"
    for item in report["running"]:
        assert inside(item["box"], view) and inside(item["box"], item["clip"]), f"{where}: {item} out of view"
        assert item["font"] >= 11 and not item["elided"], f"{where}: {item} not readable"
    assert len(report["cells"]) >= 4 * 6, f"{where}: the mode table has no rows"
    for item in report["cells"]:
        assert inside(item["box"], view) and inside(item["box"], item["clip"]), f"{where}: {item} cut"
        assert not item["elided"], f"{where}: {item} cut"
    ticks = report["axis"]
    assert len(ticks) >= 3 and all(tick["name"].endswith(" s") for tick in ticks), f"{where}: no time axis: {ticks}"
    for item in ticks:
        assert inside(item["box"], view) and inside(item["box"], item["clip"]), f"{where}: {item} cut"
    assert report["current"], f"{where}: no events up to the tick shown"
    for item in report["current"]:
        assert inside(item["box"], view) and inside(item["box"], item["clip"]), f"{where}: {item} not in view"


def fingerprint(*files: Path) -> str:
    """The page's sources and the demo tree's shape: what docs/view.png shows (and ``files``)."""
    digest = hashlib.sha256()
    for path in sorted(STATIC.glob("*.*")):
        digest.update(path.name.encode() + path.read_bytes())
    root = pilot.create_root(2)
    digest.update(repr([(b.name, len(b.children)) for b in root.iterate()]).encode())
    for path in files:
        digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


KEY = b"sm-bt-view"


def with_text(png: bytes, text: str) -> bytes:
    """``png`` with a tEXt chunk (``sm-bt-view``: ``text``) before its end."""
    data = KEY + b"\0" + text.encode()
    chunk = struct.pack(">I", len(data)) + b"tEXt" + data + struct.pack(">I", zlib.crc32(b"tEXt" + data))
    end = png.rindex(b"IEND") - 4
    return png[:end] + chunk + png[end:]


def text_of(png: bytes) -> str | None:
    at = 8
    while at < len(png):
        (length,) = struct.unpack(">I", png[at:at + 4])
        kind, data = png[at + 4:at + 8], png[at + 8:at + 8 + length]
        if kind == b"tEXt" and data.startswith(KEY + b"\0"):
            return data[len(KEY) + 1:].decode()
        at += 12 + length
    return None
