"""What an analysis finds: a :class:`Finding` (kind, severity, where, what, and the smallest
example that shows it), in the order the model file reads."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

from sm_bt.model.types import Location


class Level(str, enum.Enum):
    """How much a finding matters: an error breaks what the model promises, a warning may, a note
    says what the analysis saw."""

    ERROR = "error"
    WARNING = "warning"
    NOTE = "note"


class Kind(str, enum.Enum):
    """What a finding is about (its name in ``--json``)."""

    UNREACHABLE = "unreachable"  # no request can take the part to the mode
    OVERRIDE_ONLY = "override-only"  # only a direct request reaches it: the system above never asks for it
    AMBIGUOUS = "ambiguous"  # inference cannot tell two modes apart
    RULE_NEVER_FIRES = "rule-never-fires"
    RULE_PING_PONG = "rule-ping-pong"  # rules switch a system back and forth
    RULE_UNDOES_REQUEST = "rule-undoes-request"  # a rule's condition is a mode the model asks for
    RULE_SHADOWED = "rule-shadowed"  # an earlier rule with the same condition always fires first
    FAULT_UNHANDLED = "fault-unhandled"  # a fault leaves a system diverged, no rule reacts
    TREE_UNREACHABLE = "tree-unreachable"  # a tree asks for what a fault makes unreachable, uncovered
    TREE_UNASKED = "tree-unasked"  # modes no tree asks for


@dataclass(frozen=True)
class Finding:
    kind: Kind
    level: Level
    location: Location
    message: str
    #: The smallest example that shows it (a plan, a sequence of switches, a fault and its outcome).
    example: str = ""

    def __str__(self) -> str:
        text = f"{self.location}: {self.level.value}: {self.message} [{self.kind.value}]"
        return text + (f"\n    e.g. {self.example}" if self.example else "")

    def as_json(self) -> dict[str, Any]:
        return {"kind": self.kind.value, "level": self.level.value, "file": self.location.file,
                "line": self.location.line, "message": self.message, "example": self.example}


def in_file_order(findings: list[Finding]) -> list[Finding]:
    """Errors first, then by file and line (a stable order for a person and a diff)."""
    rank = {Level.ERROR: 0, Level.WARNING: 1, Level.NOTE: 2}
    return sorted(findings, key=lambda f: (rank[f.level], f.location.file, f.location.line, f.kind.value))
