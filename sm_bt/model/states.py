"""Lifecycle state vocabulary shared by every layer.

The ids and labels are exactly those of ``lifecycle_msgs/msg/State`` so that they can go on the
wire unchanged. :class:`StateMode` is the value a part has or should have: a lifecycle state and,
only when that state is ``active``, a mode name (``"active.FAST"``, ``"inactive"``).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class State(enum.IntEnum):
    """ROS 2 managed-node states, ids and labels as in ``lifecycle_msgs/msg/State``."""

    UNKNOWN = 0
    UNCONFIGURED = 1
    INACTIVE = 2
    ACTIVE = 3
    FINALIZED = 4
    CONFIGURING = 10
    CLEANINGUP = 11
    SHUTTINGDOWN = 12
    ACTIVATING = 13
    DEACTIVATING = 14
    ERRORPROCESSING = 15

    @property
    def label(self) -> str:
        """The lower-case label used in model files and on the wire (``"active"``)."""
        return self.name.lower()

    @property
    def is_primary(self) -> bool:
        """True for the four primary states a node can rest in."""
        return self in PRIMARY_STATES

    @classmethod
    def from_label(cls, label: str) -> State:
        """Parse an exact, lower-case lifecycle label; raise ``ValueError`` otherwise."""
        state = _BY_LABEL.get(label)
        if state is None:
            raise ValueError(f"{label!r} is not a lifecycle state label (one of: {', '.join(LABELS)})")
        return state

    def __str__(self) -> str:
        return self.label


PRIMARY_STATES = frozenset({State.UNCONFIGURED, State.INACTIVE, State.ACTIVE, State.FINALIZED})
_BY_LABEL = {s.label: s for s in State}
LABELS: tuple[str, ...] = tuple(s.label for s in State)


@dataclass(frozen=True)
class StateMode:
    """A lifecycle state plus, when the state is ``active``, the mode.

    The mode is dropped for every state but ``active`` so that equality compares what matters:
    ``StateMode(INACTIVE, "FOO") == StateMode(INACTIVE)``. An active value with ``mode=None``
    means "active, mode not known" (for example parameters that match no mode).
    """

    state: State
    mode: str | None = None

    def __post_init__(self) -> None:
        if self.state is not State.ACTIVE and self.mode is not None:
            object.__setattr__(self, "mode", None)

    @classmethod
    def parse(cls, text: str) -> StateMode:
        """Parse ``"active"``, ``"active.FAST"`` or ``"inactive"``; raise ``ValueError`` if invalid.

        The state label is split off at the first ``.``; mode names may not contain a dot.
        """
        label, _, mode = text.partition(".")
        state = State.from_label(label)
        if "." in mode:
            raise ValueError(f"{text!r}: a mode name may not contain '.'")
        return cls(state, mode or None)

    def __str__(self) -> str:
        if self.state is State.ACTIVE and self.mode:
            return f"{self.state.label}.{self.mode}"
        return self.state.label
