"""Collects the loader's findings so that one run reports every problem, not only the first."""

from __future__ import annotations

import difflib
from collections.abc import Iterable

from sm_bt.model.errors import ModelError
from sm_bt.model.types import Location, ModelIssue, Severity


class Diagnostics:
    """Errors and warnings of one model file, each with its line."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.errors: list[ModelIssue] = []
        self.warnings: list[ModelIssue] = []

    def error(self, line: int, message: str) -> None:
        self.errors.append(ModelIssue(Location(self.file, line), Severity.ERROR, message))

    def warning(self, line: int, message: str) -> None:
        self.warnings.append(ModelIssue(Location(self.file, line), Severity.WARNING, message))

    def raise_if_errors(self) -> None:
        if self.errors:
            # Sorted by line (stable) so that the report reads top to bottom like the file.
            raise ModelError(sorted(self.errors, key=lambda issue: issue.location.line))

    def sorted_warnings(self) -> tuple[ModelIssue, ...]:
        return tuple(sorted(self.warnings, key=lambda issue: issue.location.line))


def did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest candidate, or ``""`` when nothing is close."""
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def quoted_list(names: Iterable[str]) -> str:
    """``"'a', 'b'"``, or ``"none"`` for an empty list."""
    listed = ", ".join(repr(name) for name in names)
    return listed or "none"
