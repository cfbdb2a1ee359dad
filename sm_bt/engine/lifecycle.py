"""The ROS 2 managed-node state machine as data, and a planner over it.

Ids and labels are those of ``lifecycle_msgs/msg/Transition`` and the default state machine of
``rcl_lifecycle``: a transition started from a primary state leads to a transition state, whose
callback outcome (success, failure, error) leads on.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass

from sm_bt.model.errors import Error
from sm_bt.model.states import PRIMARY_STATES, State


class Transition(enum.IntEnum):
    """Transition ids as in ``lifecycle_msgs/msg/Transition``."""

    CREATE = 0
    CONFIGURE = 1
    CLEANUP = 2
    ACTIVATE = 3
    DEACTIVATE = 4
    UNCONFIGURED_SHUTDOWN = 5
    INACTIVE_SHUTDOWN = 6
    ACTIVE_SHUTDOWN = 7
    DESTROY = 8
    ON_CONFIGURE_SUCCESS = 10
    ON_CONFIGURE_FAILURE = 11
    ON_CONFIGURE_ERROR = 12
    ON_CLEANUP_SUCCESS = 20
    ON_CLEANUP_FAILURE = 21
    ON_CLEANUP_ERROR = 22
    ON_ACTIVATE_SUCCESS = 30
    ON_ACTIVATE_FAILURE = 31
    ON_ACTIVATE_ERROR = 32
    ON_DEACTIVATE_SUCCESS = 40
    ON_DEACTIVATE_FAILURE = 41
    ON_DEACTIVATE_ERROR = 42
    ON_SHUTDOWN_SUCCESS = 50
    ON_SHUTDOWN_FAILURE = 51
    ON_SHUTDOWN_ERROR = 52
    ON_ERROR_SUCCESS = 60
    ON_ERROR_FAILURE = 61
    ON_ERROR_ERROR = 62

    @property
    def label(self) -> str:
        """The label ``rcl_lifecycle`` gives this transition (``"configure"``, ``"transition_success"``)."""
        return _LABELS[self]

    def __str__(self) -> str:
        return self.label


class Outcome(str, enum.Enum):
    """What a transition callback returned (``on_configure`` and friends)."""

    SUCCESS = "success"
    FAILURE = "failure"
    ERROR = "error"


_LABELS: dict[Transition, str] = {
    Transition.CREATE: "create",
    Transition.CONFIGURE: "configure",
    Transition.CLEANUP: "cleanup",
    Transition.ACTIVATE: "activate",
    Transition.DEACTIVATE: "deactivate",
    Transition.UNCONFIGURED_SHUTDOWN: "shutdown",
    Transition.INACTIVE_SHUTDOWN: "shutdown",
    Transition.ACTIVE_SHUTDOWN: "shutdown",
    Transition.DESTROY: "destroy",
}
for _t in Transition:
    if _t >= 10:
        _LABELS[_t] = "transition_" + _t.name.rsplit("_", 1)[1].lower()


@dataclass(frozen=True)
class TransitionEdge:
    """A transition requested from a primary state: it passes ``via`` and ends in ``goal`` on success."""

    transition: Transition
    start: State
    via: State
    goal: State


#: The transitions a client may request (``change_state``), by start state.
REQUESTABLE: tuple[TransitionEdge, ...] = (
    TransitionEdge(Transition.CONFIGURE, State.UNCONFIGURED, State.CONFIGURING, State.INACTIVE),
    TransitionEdge(Transition.CLEANUP, State.INACTIVE, State.CLEANINGUP, State.UNCONFIGURED),
    TransitionEdge(Transition.ACTIVATE, State.INACTIVE, State.ACTIVATING, State.ACTIVE),
    TransitionEdge(Transition.DEACTIVATE, State.ACTIVE, State.DEACTIVATING, State.INACTIVE),
    TransitionEdge(Transition.UNCONFIGURED_SHUTDOWN, State.UNCONFIGURED, State.SHUTTINGDOWN, State.FINALIZED),
    TransitionEdge(Transition.INACTIVE_SHUTDOWN, State.INACTIVE, State.SHUTTINGDOWN, State.FINALIZED),
    TransitionEdge(Transition.ACTIVE_SHUTDOWN, State.ACTIVE, State.SHUTTINGDOWN, State.FINALIZED),
)

#: The step of each requestable transition (each has one start state).
EDGE_OF: dict[Transition, TransitionEdge] = {step.transition: step for step in REQUESTABLE}

#: The requestable transitions by label, in lifecycle order (``shutdown`` resolves by start state).
REQUESTABLE_LABELS: tuple[str, ...] = ("configure", "activate", "deactivate", "cleanup", "shutdown")
#: The state a requestable transition (by label) ends in when it succeeds.
TRANSITION_GOALS: dict[str, str] = {step.transition.label: step.goal.label for step in REQUESTABLE}

#: Where a transition state goes for each callback outcome, with the transition id reported.
OUTCOMES: dict[State, dict[Outcome, tuple[Transition, State]]] = {
    State.CONFIGURING: {
        Outcome.SUCCESS: (Transition.ON_CONFIGURE_SUCCESS, State.INACTIVE),
        Outcome.FAILURE: (Transition.ON_CONFIGURE_FAILURE, State.UNCONFIGURED),
        Outcome.ERROR: (Transition.ON_CONFIGURE_ERROR, State.ERRORPROCESSING),
    },
    State.CLEANINGUP: {
        Outcome.SUCCESS: (Transition.ON_CLEANUP_SUCCESS, State.UNCONFIGURED),
        Outcome.FAILURE: (Transition.ON_CLEANUP_FAILURE, State.INACTIVE),
        Outcome.ERROR: (Transition.ON_CLEANUP_ERROR, State.ERRORPROCESSING),
    },
    State.ACTIVATING: {
        Outcome.SUCCESS: (Transition.ON_ACTIVATE_SUCCESS, State.ACTIVE),
        Outcome.FAILURE: (Transition.ON_ACTIVATE_FAILURE, State.INACTIVE),
        Outcome.ERROR: (Transition.ON_ACTIVATE_ERROR, State.ERRORPROCESSING),
    },
    State.DEACTIVATING: {
        Outcome.SUCCESS: (Transition.ON_DEACTIVATE_SUCCESS, State.INACTIVE),
        Outcome.FAILURE: (Transition.ON_DEACTIVATE_FAILURE, State.ACTIVE),
        Outcome.ERROR: (Transition.ON_DEACTIVATE_ERROR, State.ERRORPROCESSING),
    },
    State.SHUTTINGDOWN: {
        Outcome.SUCCESS: (Transition.ON_SHUTDOWN_SUCCESS, State.FINALIZED),
        Outcome.FAILURE: (Transition.ON_SHUTDOWN_FAILURE, State.FINALIZED),
        Outcome.ERROR: (Transition.ON_SHUTDOWN_ERROR, State.ERRORPROCESSING),
    },
    State.ERRORPROCESSING: {
        Outcome.SUCCESS: (Transition.ON_ERROR_SUCCESS, State.UNCONFIGURED),
        Outcome.FAILURE: (Transition.ON_ERROR_FAILURE, State.FINALIZED),
        Outcome.ERROR: (Transition.ON_ERROR_ERROR, State.FINALIZED),
    },
}


class PlanError(Error, ValueError):
    """No sequence of transitions leads from one state to the other."""


def edge_for(start: State, transition: Transition) -> TransitionEdge:
    """The step ``transition`` makes from ``start``; ``PlanError`` if it is not valid there."""
    for step in REQUESTABLE:
        if step.start is start and step.transition is transition:
            return step
    valid = ", ".join(s.transition.label for s in REQUESTABLE if s.start is start) or "none"
    raise PlanError(f"transition {transition.label} is not valid in state {start.label} (valid: {valid})")


def transition_by_label(label: str, start: State) -> Transition:
    """Resolve a label (``"shutdown"`` depends on the start state) to a transition id."""
    for step in REQUESTABLE:
        if step.start is start and step.transition.label == label:
            return step.transition
    for transition in Transition:
        if transition.label == label:
            return transition
    raise PlanError(f"{label!r} is not a lifecycle transition label")


def plan(start: State, goal: State) -> tuple[TransitionEdge, ...]:
    """The shortest sequence of requestable transitions from primary ``start`` to primary ``goal``.

    ``()`` when they are equal. ``PlanError`` when either is not a primary state, or when no path
    exists (nothing leaves ``finalized``).
    """
    planned = _PLANS.get((start, goal))
    if planned is None:
        try:
            planned = _search(start, goal)
        except PlanError as error:
            planned = error
        _PLANS[(start, goal)] = planned  # a few dozen pairs of states: each searched once
    if isinstance(planned, PlanError):
        raise PlanError(str(planned))
    return planned


_PLANS: dict[tuple[State, State], tuple[TransitionEdge, ...] | PlanError] = {}


def _search(start: State, goal: State) -> tuple[TransitionEdge, ...]:
    for state, role in ((start, "start"), (goal, "goal")):
        if state not in PRIMARY_STATES:
            raise PlanError(f"cannot plan from or to {state.label}: the {role} must be a primary state")
    previous: dict[State, TransitionEdge] = {}
    queue = deque([start])
    seen = {start}
    while queue:
        current = queue.popleft()
        if current is goal:
            path: list[TransitionEdge] = []
            while current is not start:
                step = previous[current]
                path.append(step)
                current = step.start
            return tuple(reversed(path))
        for step in REQUESTABLE:
            if step.start is current and step.goal not in seen:
                seen.add(step.goal)
                previous[step.goal] = step
                queue.append(step.goal)
    raise PlanError(f"no lifecycle path from {start.label} to {goal.label}"
                    + (" (a finalized node must be restarted)" if start is State.FINALIZED else ""))


def first_transition(start: State, goal: State) -> Transition | None:
    """The first requestable transition from ``start`` towards ``goal``; ``None`` when they are
    equal, either is not a primary state, or no path exists."""
    if start is goal or not (start.is_primary and goal.is_primary):
        return None
    try:
        steps = plan(start, goal)
    except PlanError:
        return None
    return steps[0].transition if steps else None
