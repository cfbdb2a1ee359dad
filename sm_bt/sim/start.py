"""How simulated node processes start: the state each starts in, checked with messages that name
what is valid."""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence

from sm_bt.model.states import PRIMARY_STATES, State

#: A state to start in: a :class:`State` or its label (``"active"``).
StartState = State | str

#: The states a node process can start in, in lifecycle order (for messages).
_STARTABLE = tuple(s for s in State if s in PRIMARY_STATES)


def start_state(value: StartState, what: str) -> State:
    """``value`` as a state a node process can start in; ``ValueError`` naming the valid ones."""
    valid = ", ".join(state.label for state in _STARTABLE)
    if isinstance(value, State):
        state = value
    else:
        try:
            state = State.from_label(value)
        except ValueError:
            raise ValueError(f"{what} {value!r} is not a lifecycle state: use one of {valid}") from None
    if not state.is_primary:
        raise ValueError(f"{what} {state.label!r} is not a primary state: a node starts in one of {valid}")
    return state


def initial_states(names: Sequence[str], initial_state: StartState | Mapping[str, StartState],
                   plain: Collection[str]) -> dict[str, State]:
    """The state each of ``names`` starts in: one for all or per node (unlisted ones unconfigured);
    a node without lifecycle (in ``plain``) always runs active."""
    per_node = initial_state if isinstance(initial_state, Mapping) else {}
    common = State.UNCONFIGURED if isinstance(initial_state, Mapping) else start_state(initial_state, "initial_state")
    states: dict[str, State] = {}
    for name in names:
        if name in per_node:
            state = start_state(per_node[name], f"initial_state of node {name}")
            if name in plain and state is not State.ACTIVE:
                raise ValueError(f"initial_state of node {name}: it has no lifecycle services (parameters "
                                 f"only), so it runs active, not {state}")
        else:
            state = State.ACTIVE if name in plain else common
        states[name] = state
    return states


def check_names(names: Sequence[str], **mappings: Collection[str]) -> None:
    """``ValueError`` if an argument (by its keyword) names a node that is not in ``names``."""
    for label, mapping in mappings.items():
        unknown = sorted(set(mapping) - set(names))
        if unknown:
            raise ValueError(f"{label} names unknown nodes {unknown} (nodes: {', '.join(names)})")


def check_delay(label: str, seconds: float) -> None:
    if not (math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"{label} must be a finite number of seconds >= 0, not {seconds!r}")
