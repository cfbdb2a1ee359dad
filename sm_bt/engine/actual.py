"""What the engine knows of a part (:class:`Actual`) and of a node (:class:`NodeObservation`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

from sm_bt.model.states import State, StateMode
from sm_bt.model.types import ParamValue

#: ``state.label`` without the call (``State.label`` lowers the name each time).
STATE_LABELS = {state: state.label for state in State}
# Read once: looking up an enum's member on its class is slow (EnumType.__getattr__).
_UNKNOWN, _ACTIVE = State.UNKNOWN, State.ACTIVE


class Actual(NamedTuple):
    """The actual state and mode of a part, and how they were obtained (an immutable record).

    ``state_inferred``/``mode_inferred`` say whether a value was computed (the monitor's ``(*)``)
    rather than reported by a node. ``reason`` explains an ``unknown`` state or a missing mode.
    (A named tuple, not a frozen dataclass: the engine makes one per part per change, and that
    costs a third as much.)
    """

    part: str
    state: State
    mode: str | None = None
    state_inferred: bool = True
    mode_inferred: bool = True
    reason: str = ""

    @property
    def state_mode(self) -> StateMode:
        return StateMode(self.state, self.mode)

    @property
    def known(self) -> bool:
        return self.state is not State.UNKNOWN

    def is_(self, wanted: StateMode) -> bool:
        """Known and equal to ``wanted`` (as ``state_mode == wanted``, without making one)."""
        state = self.state
        return state is wanted.state and state is not _UNKNOWN and (state is not _ACTIVE or self.mode == wanted.mode)

    def meets(self, condition: StateMode) -> bool:
        """A rule's condition holds: :meth:`is_`, and ``unknown`` holds for a part whose state is
        not known (its node crashed or is gone), so that a rule can react to losing a part."""
        return self.is_(condition) or (condition.state is State.UNKNOWN and self.state is State.UNKNOWN)

    def __str__(self) -> str:
        if self.state is State.ACTIVE and self.mode:
            return f"active.{self.mode}"
        return STATE_LABELS[self.state]


@dataclass
class NodeObservation:
    """Everything reported about one node so far."""

    seen: bool = False
    state: State = State.UNKNOWN
    parameters: dict[str, ParamValue] = field(default_factory=dict)
    lifecycle: bool = True
    gone: str = ""  # why the node is not reachable now ("" while reachable or never seen)

    @property
    def reachable(self) -> bool:
        return self.seen and not self.gone


def out_of_reach(node: str, obs: NodeObservation, target: StateMode) -> str:
    """Why ``node`` cannot be taken to ``target`` as far as its observation says ("" if it can):
    what a refused request, and a preview, say."""
    if obs.gone:
        return f"{node} is not reachable ({obs.gone})"
    if obs.state is State.FINALIZED and target.state is not State.FINALIZED:
        return f"{node} is finalized (it must be restarted)"
    return ""
