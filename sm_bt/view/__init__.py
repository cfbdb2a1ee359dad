"""See a mission live in a browser: the tree (py_trees_js), the modes, the run, no ROS or Qt.

::

    view = attach_view(tree, manager)          # a post-tick handler on a py_trees BehaviourTree
    print("open", view.url)                    # http://127.0.0.1:<port>/
    ... tick ...
    view.close()

``attach_view(..., record="run.jsonl")`` also writes every frame to a file, which
``sm-bt view run.jsonl`` replays. The server listens on 127.0.0.1 unless ``host`` says otherwise.
Frames carry only what changed since the frame before (:mod:`sm_bt.view.frames`): the demo's
run is about 0.5 MB, and making them costs a tree a few microseconds a tick.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from pathlib import Path

import py_trees

from sm_bt.engine.manager import ModeManager
from sm_bt.view.frames import FrameMaker
from sm_bt.view.recording import Recorder, read_recording


class View:
    """A running view of one tree: ``url`` (when served), ``maker`` (makes the frames), ``finish()``
    (the run is over, the page stays), ``close()``."""

    def __init__(self, maker: FrameMaker, server: object | None, recorder: Recorder | None) -> None:
        self.maker = maker
        self.server = server
        self.recorder = recorder

    @property
    def url(self) -> str | None:
        return getattr(self.server, "url", None)

    def note(self, kind: str, text: str) -> None:
        """List an event of the run that is not the manager's (``"expectation"``: a scenario's
        expectation failed: the timeline marks it), in a frame of its own at once, so that the
        page shows it at the moment it happened."""
        self.maker.note(kind, text)
        self.maker.flush()

    def finish(self) -> None:
        """The run is over: no more frames; the page stays served and says so."""
        self.maker.flush()
        self.maker.close()
        finish = getattr(self.server, "finish", None)
        if finish is not None:
            finish()

    def stay(self, say: Callable[[str], None]) -> None:
        """The run is over (:meth:`finish`): ``say`` so with the address, then serve the page until
        Ctrl-C."""
        self.finish()
        with contextlib.suppress(KeyboardInterrupt):  # from the moment it says so (a fresh-clone run's
            say(f"run over; the view stays at {self.url} until Ctrl-C")  # Ctrl-C came in between)
            while True:
                time.sleep(3600)

    def close(self) -> None:
        self.maker.flush()
        self.maker.close()
        if self.recorder is not None:
            self.recorder.close()
        close = getattr(self.server, "close", None)
        if close is not None:
            close()


def attach_view(tree: py_trees.trees.BehaviourTree, manager: ModeManager, *, port: int | None = 0,
                host: str = "127.0.0.1", record: str | Path | None = None) -> View:
    """Serve ``tree`` and ``manager`` live on ``host``:``port`` (0: a free port; ``None``: do not
    serve) and/or record them to ``record`` (a ``.jsonl`` file)."""
    from sm_bt.view.server import ViewServer

    maker = FrameMaker(tree, manager)
    server = ViewServer(host, port) if port is not None else None
    recorder = Recorder(record) if record is not None else None
    for sink in (server, recorder):
        if sink is not None:
            maker.sinks.append(sink)
    return View(maker, server, recorder)


__all__ = ["View", "attach_view", "read_recording"]
