"""The reference manager (micro-ROS/system_modes' ``mode_manager``, C++) as a child process, for
``make interop``.

``tools/reference/build.sh`` builds it once per source hash and prints its prefix; ``make interop``
passes that prefix in ``SM_BT_REFERENCE``. Its process is stopped like every ROS process of the
tests: by PID, SIGINT, then SIGKILL (the reference aborts on SIGINT, which is its own business).
"""

from __future__ import annotations

import collections
import os
import re
import threading
from pathlib import Path
from typing import IO

from ros_processes import NodeProcess

from sm_bt import bundled
from sm_bt.model import load_model
from sm_bt.model.system_modes import ORDER_KEY

#: A system-mode entry the reference cannot read (it takes it for a part and crashes).
_ORDER_LINE = re.compile(rf"^\s*{ORDER_KEY}\s*:")


def reference_prefix() -> Path:
    """The built reference (``SM_BT_REFERENCE``); a clear error when it is not there."""
    prefix = os.environ.get("SM_BT_REFERENCE", "")
    if not prefix or not (Path(prefix) / "bin" / "mode_manager").is_file():
        raise RuntimeError("SM_BT_REFERENCE does not name a built reference manager "
                           f"({prefix or 'unset'}): run `make interop`, which builds it (tools/reference/build.sh)")
    return Path(prefix)


def reference_model(name: str, folder: Path) -> Path:
    """A model (bundled name or path) as the reference can read it: the same file without its
    ``__order__`` entries (an sm_bt extension; parts then switch all at once), written to ``folder``."""
    source = bundled.resolve(name)
    lines = source.read_text(encoding="utf-8").splitlines(keepends=True)
    target = folder / f"{source.stem}_reference.yaml"
    target.write_text("".join(line for line in lines if not _ORDER_LINE.match(line)), encoding="utf-8")
    return target


class ReferenceManager(NodeProcess):
    """``mode_manager --ros-args -p modelfile:=MODEL``: ready once its log lists the services of
    every part of the model (it serves nothing before that)."""

    def __init__(self, model: Path, prefix: Path | None = None, namespace: str = "/") -> None:
        super().__init__(str(model))
        self.command = [str((prefix or reference_prefix()) / "bin" / "mode_manager"), "--ros-args",
                        "-p", f"modelfile:={model}", "-r", f"__ns:={namespace}"]
        self._parts = len(load_model(model, strict=False).parts)
        self._listed = 0
        self._lock = threading.Lock()

    def _read(self, stream: IO[str], lines: collections.deque[str], watch_ready: bool) -> None:
        for line in stream:  # its log is on stderr: "[INFO] [...] [__mode_manager]:   - amcl/get_available_modes"
            lines.append(line.rstrip("\n"))
            if line.rstrip().endswith("/get_available_modes"):
                with self._lock:
                    self._listed += 1
                    if self._listed >= self._parts:
                        self._ready.set()
        stream.close()
