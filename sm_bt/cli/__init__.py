"""The ``sm-bt`` command line: one module per command, the table of commands in :mod:`sm_bt.cli.app`.

``sm_bt.cli.main`` is the console script's entry point (``python -m sm_bt.cli`` runs it too). The
commands are loaded inside it, so that a Ctrl-C while they load (a second or more on a busy
machine) ends the command as one during its run does, not with a traceback.
"""

from __future__ import annotations

import sys
from typing import Any

__all__ = ["COMMANDS", "main"]


def main(argv: list[str] | None = None) -> int:
    """Run ``sm-bt`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    try:
        from sm_bt.cli.app import main as run
    except KeyboardInterrupt:
        print("sm-bt: interrupted", file=sys.stderr)
        return 130
    return run(argv)


def __getattr__(name: str) -> Any:
    if name == "COMMANDS":  # the table of commands, loaded when asked for
        from sm_bt.cli.app import COMMANDS

        return COMMANDS
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
