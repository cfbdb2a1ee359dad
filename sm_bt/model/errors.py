"""sm_bt's exceptions: their root, the loader's error (every problem found, each with file, line and
what to change), and a request that the model shows to be a mistake."""

from __future__ import annotations

from collections.abc import Sequence

from sm_bt.model.types import ModelIssue


class Error(Exception):
    """The root of every exception sm_bt raises on purpose: ``except sm_bt.Error`` catches them all."""


class ModelError(Error):
    """A model file could not be loaded.

    ``issues`` holds every error found (not only the first), each with its location;
    ``str(error)`` prints them one per line as ``file:line: error: message``.
    """

    def __init__(self, issues: Sequence[ModelIssue]) -> None:
        self.issues: tuple[ModelIssue, ...] = tuple(issues)
        super().__init__("\n".join(str(issue) for issue in self.issues))


class RequestError(Error, ValueError):
    """A call that the model alone shows to be a mistake: a part or mode it does not have, an empty
    mode name, a transition or state that does not exist. Raised at once, with what the model has
    (the closest name first). What depends on the running system (a node out of reach or
    finalized, a transition not valid where the part is now) is a refused request instead."""
