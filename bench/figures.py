"""One measured figure of ``make bench``, with the goal it is held against.

Every benchmark module returns a list of :class:`Figure`; ``bench/__main__.py`` prints them as a
table (goal beside each figure), writes them as JSON under ``build/bench/`` and plots cost vs N.
Goals are ratios or bounds measured in the same run, never absolute times held by a unit test.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal


@dataclass(frozen=True)
class Figure:
    """``value`` (in ``unit``) of ``name``; met when ``value <op> goal`` (no goal: reported only)."""

    group: str  # "P1", "P3", "scale", ... as the issue names the goals
    name: str
    value: float
    unit: str
    goal: float | None = None
    op: Literal["<=", ">="] = "<="
    details: dict[str, Any] = field(default_factory=dict)  # N, samples, raw times, ...

    @property
    def met(self) -> bool | None:
        if self.goal is None:
            return None
        return self.value <= self.goal if self.op == "<=" else self.value >= self.goal

    def as_json(self) -> dict[str, Any]:
        return {**asdict(self), "met": self.met}
