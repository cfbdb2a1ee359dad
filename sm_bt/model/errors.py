"""The loader's error type: every problem found, each with file, line and what to change."""

from __future__ import annotations

from collections.abc import Sequence

from sm_bt.model.types import ModelIssue


class ModelError(Exception):
    """A model file could not be loaded.

    ``issues`` holds every error found (not only the first), each with its location;
    ``str(error)`` prints them one per line as ``file:line: error: message``.
    """

    def __init__(self, issues: Sequence[ModelIssue]) -> None:
        self.issues: tuple[ModelIssue, ...] = tuple(issues)
        super().__init__("\n".join(str(issue) for issue in self.issues))
