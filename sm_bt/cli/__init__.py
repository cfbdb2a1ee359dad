"""The ``sm-bt`` command line: one module per command, the table of commands in :mod:`sm_bt.cli.app`.

``sm_bt.cli.main`` is the console script's entry point (``python -m sm_bt.cli`` runs it too).
"""

from __future__ import annotations

from sm_bt.cli.app import COMMANDS, main

__all__ = ["COMMANDS", "main"]
