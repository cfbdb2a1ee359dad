"""The managed-node state machine tables and the lifecycle path planner."""

import pytest

from sm_bt.engine.lifecycle import (
    OUTCOMES,
    REQUESTABLE,
    REQUESTABLE_LABELS,
    Outcome,
    PlanError,
    Transition,
    edge_for,
    plan,
    transition_by_label,
)
from sm_bt.model.states import State

U, I, A, F = State.UNCONFIGURED, State.INACTIVE, State.ACTIVE, State.FINALIZED  # noqa: E741

# Every primary state to every other, written out by hand.
EXPECTED_PATHS = {
    (U, U): [], (U, I): ["configure"], (U, A): ["configure", "activate"], (U, F): ["shutdown"],
    (I, U): ["cleanup"], (I, I): [], (I, A): ["activate"], (I, F): ["shutdown"],
    (A, U): ["deactivate", "cleanup"], (A, I): ["deactivate"], (A, A): [], (A, F): ["shutdown"],
    (F, F): [],
}


@pytest.mark.parametrize(("start", "goal"), sorted(EXPECTED_PATHS, key=lambda k: (k[0].value, k[1].value)))
def test_plan_from_every_primary_state(start: State, goal: State) -> None:
    steps = plan(start, goal)
    assert [s.transition.label for s in steps] == EXPECTED_PATHS[(start, goal)]
    # Consecutive steps chain, and the path ends at the goal.
    state = start
    for step in steps:
        assert step.start is state
        state = step.goal
    assert state is goal


def test_shutdown_uses_the_id_of_the_start_state() -> None:
    assert plan(U, F)[0].transition is Transition.UNCONFIGURED_SHUTDOWN
    assert plan(I, F)[0].transition is Transition.INACTIVE_SHUTDOWN
    assert plan(A, F)[0].transition is Transition.ACTIVE_SHUTDOWN


@pytest.mark.parametrize("goal", [U, I, A])
def test_nothing_leaves_finalized(goal: State) -> None:
    with pytest.raises(PlanError, match="finalized"):
        plan(F, goal)


def test_transition_states_cannot_be_planned() -> None:
    with pytest.raises(PlanError, match="primary"):
        plan(State.ACTIVATING, A)
    with pytest.raises(PlanError, match="primary"):
        plan(U, State.UNKNOWN)


def test_ids_and_labels_match_lifecycle_msgs() -> None:
    assert (Transition.CONFIGURE, Transition.CONFIGURE.label) == (1, "configure")
    assert (Transition.UNCONFIGURED_SHUTDOWN, Transition.UNCONFIGURED_SHUTDOWN.label) == (5, "shutdown")
    assert (Transition.ON_DEACTIVATE_ERROR, Transition.ON_DEACTIVATE_ERROR.label) == (42, "transition_error")
    assert Transition.ON_ERROR_SUCCESS.label == "transition_success"
    assert Transition.ON_ACTIVATE_FAILURE.label == "transition_failure"


def test_outcome_table_follows_rcl_lifecycle() -> None:
    assert OUTCOMES[State.DEACTIVATING][Outcome.ERROR] == (Transition.ON_DEACTIVATE_ERROR, State.ERRORPROCESSING)
    assert OUTCOMES[State.ERRORPROCESSING][Outcome.SUCCESS] == (Transition.ON_ERROR_SUCCESS, U)
    assert OUTCOMES[State.ERRORPROCESSING][Outcome.FAILURE] == (Transition.ON_ERROR_FAILURE, F)
    assert OUTCOMES[State.ACTIVATING][Outcome.FAILURE] == (Transition.ON_ACTIVATE_FAILURE, I)
    assert OUTCOMES[State.SHUTTINGDOWN][Outcome.FAILURE][1] is F


def test_invalid_transition_names_the_valid_ones() -> None:
    with pytest.raises(PlanError, match=r"cleanup is not valid in state active \(valid: deactivate, shutdown\)"):
        edge_for(A, Transition.CLEANUP)


def test_label_resolution_depends_on_start_state() -> None:
    assert transition_by_label("shutdown", A) is Transition.ACTIVE_SHUTDOWN
    assert transition_by_label("shutdown", U) is Transition.UNCONFIGURED_SHUTDOWN
    assert transition_by_label("configure", A) is Transition.CONFIGURE
    with pytest.raises(PlanError, match="not a lifecycle transition label"):
        transition_by_label("reboot", A)


def test_requestable_labels_are_the_requestable_transitions() -> None:
    assert set(REQUESTABLE_LABELS) == {step.transition.label for step in REQUESTABLE}
