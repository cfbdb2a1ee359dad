"""SimNode: the rcl_lifecycle default state machine and typed, atomic parameters (no time involved)."""

from __future__ import annotations

import pytest

from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.lifecycle import OUTCOMES, REQUESTABLE, Outcome, Transition
from sm_bt.model.states import PRIMARY_STATES, State
from sm_bt.model.types import ParamValue
from sm_bt.sim import ParameterRejected, SimNode, TransitionRefused, parameter_type

S = State
T = Transition
OK, FAIL, ERR = Outcome.SUCCESS, Outcome.FAILURE, Outcome.ERROR

# (start state, transition, callback outcome) -> (states passed, transition ids reported); on_error succeeds.
TRUTH_TABLE: dict[tuple[State, Transition, Outcome], tuple[list[State], list[int]]] = {
    (S.UNCONFIGURED, T.CONFIGURE, OK): ([S.CONFIGURING, S.INACTIVE], [1, 10]),
    (S.UNCONFIGURED, T.CONFIGURE, FAIL): ([S.CONFIGURING, S.UNCONFIGURED], [1, 11]),
    (S.UNCONFIGURED, T.CONFIGURE, ERR): ([S.CONFIGURING, S.ERRORPROCESSING, S.UNCONFIGURED], [1, 12, 60]),
    (S.INACTIVE, T.CLEANUP, OK): ([S.CLEANINGUP, S.UNCONFIGURED], [2, 20]),
    (S.INACTIVE, T.CLEANUP, FAIL): ([S.CLEANINGUP, S.INACTIVE], [2, 21]),
    (S.INACTIVE, T.CLEANUP, ERR): ([S.CLEANINGUP, S.ERRORPROCESSING, S.UNCONFIGURED], [2, 22, 60]),
    (S.INACTIVE, T.ACTIVATE, OK): ([S.ACTIVATING, S.ACTIVE], [3, 30]),
    (S.INACTIVE, T.ACTIVATE, FAIL): ([S.ACTIVATING, S.INACTIVE], [3, 31]),
    (S.INACTIVE, T.ACTIVATE, ERR): ([S.ACTIVATING, S.ERRORPROCESSING, S.UNCONFIGURED], [3, 32, 60]),
    (S.ACTIVE, T.DEACTIVATE, OK): ([S.DEACTIVATING, S.INACTIVE], [4, 40]),
    (S.ACTIVE, T.DEACTIVATE, FAIL): ([S.DEACTIVATING, S.ACTIVE], [4, 41]),
    (S.ACTIVE, T.DEACTIVATE, ERR): ([S.DEACTIVATING, S.ERRORPROCESSING, S.UNCONFIGURED], [4, 42, 60]),
    (S.UNCONFIGURED, T.UNCONFIGURED_SHUTDOWN, OK): ([S.SHUTTINGDOWN, S.FINALIZED], [5, 50]),
    (S.UNCONFIGURED, T.UNCONFIGURED_SHUTDOWN, FAIL): ([S.SHUTTINGDOWN, S.FINALIZED], [5, 51]),
    (S.UNCONFIGURED, T.UNCONFIGURED_SHUTDOWN, ERR): (
        [S.SHUTTINGDOWN, S.ERRORPROCESSING, S.UNCONFIGURED], [5, 52, 60]),
    (S.INACTIVE, T.INACTIVE_SHUTDOWN, OK): ([S.SHUTTINGDOWN, S.FINALIZED], [6, 50]),
    (S.INACTIVE, T.INACTIVE_SHUTDOWN, FAIL): ([S.SHUTTINGDOWN, S.FINALIZED], [6, 51]),
    (S.INACTIVE, T.INACTIVE_SHUTDOWN, ERR): ([S.SHUTTINGDOWN, S.ERRORPROCESSING, S.UNCONFIGURED], [6, 52, 60]),
    (S.ACTIVE, T.ACTIVE_SHUTDOWN, OK): ([S.SHUTTINGDOWN, S.FINALIZED], [7, 50]),
    (S.ACTIVE, T.ACTIVE_SHUTDOWN, FAIL): ([S.SHUTTINGDOWN, S.FINALIZED], [7, 51]),
    (S.ACTIVE, T.ACTIVE_SHUTDOWN, ERR): ([S.SHUTTINGDOWN, S.ERRORPROCESSING, S.UNCONFIGURED], [7, 52, 60]),
}

# What remains valid from each primary state (written by hand, not derived from REQUESTABLE).
VALID = {
    S.UNCONFIGURED: {T.CONFIGURE, T.UNCONFIGURED_SHUTDOWN},
    S.INACTIVE: {T.CLEANUP, T.ACTIVATE, T.INACTIVE_SHUTDOWN},
    S.ACTIVE: {T.DEACTIVATE, T.ACTIVE_SHUTDOWN},
    S.FINALIZED: set(),
}

PARAMS: dict[str, ParamValue] = {"alpha": 0.2, "beams": 60, "enabled": True, "frame": "map",
          "gains": (1.0, 2.0), "ids": (1, 2), "names": ("a",), "flags": (True,)}


def make(state: State = S.UNCONFIGURED, clock: VirtualClock | None = None) -> SimNode:
    return SimNode("amcl", PARAMS, clock or VirtualClock(), state=state)


def run(node: SimNode, transition: Transition, outcome: Outcome, on_error: Outcome = OK) -> SimNode:
    node.start(transition)
    node.complete(outcome)
    if node.state is S.ERRORPROCESSING:
        node.complete(on_error)
    return node


# -- lifecycle -------------------------------------------------------------------------------------


def test_truth_table_covers_every_requestable_transition_and_outcome() -> None:
    expected = {(step.start, step.transition, outcome) for step in REQUESTABLE for outcome in Outcome}
    assert set(TRUTH_TABLE) == expected


@pytest.mark.parametrize(("start", "transition", "outcome"), list(TRUTH_TABLE))
def test_transition_sequence(start: State, transition: Transition, outcome: Outcome) -> None:
    states, ids = TRUTH_TABLE[(start, transition, outcome)]
    node = run(make(start), transition, outcome)
    assert [e.goal for e in node.transitions] == states
    assert [int(e.transition) for e in node.transitions] == ids
    assert [e.start for e in node.transitions] == [start, *states[:-1]]
    assert node.state is states[-1]


@pytest.mark.parametrize(("on_error", "tid"), [(FAIL, 61), (ERR, 62)])
def test_failing_error_processing_finalizes(on_error: Outcome, tid: int) -> None:
    node = run(make(S.INACTIVE), T.ACTIVATE, ERR, on_error)
    assert [e.goal for e in node.transitions] == [S.ACTIVATING, S.ERRORPROCESSING, S.FINALIZED]
    assert [int(e.transition) for e in node.transitions] == [3, 32, tid]


def test_truth_table_agrees_with_the_outcomes_table() -> None:
    # Cross-check only: the expectations above are hand-written.
    for (start, transition, outcome), (states, ids) in TRUTH_TABLE.items():
        via = states[0]
        assert OUTCOMES[via][outcome] == (ids[1], states[1]), (start, transition, outcome)


@pytest.mark.parametrize("state", sorted(PRIMARY_STATES))
def test_valid_transitions(state: State) -> None:
    assert set(make(state).valid_transitions()) == VALID[state]


@pytest.mark.parametrize(
    ("state", "transition"),
    [(s, t) for s in sorted(PRIMARY_STATES) for t in Transition if t not in VALID[s]],
)
def test_invalid_transition_refused_with_valid_ones_listed(state: State, transition: Transition) -> None:
    node = make(state)
    with pytest.raises(TransitionRefused) as refused:
        node.start(transition)
    message = str(refused.value)
    assert f"not valid in state {state.label}" in message
    for valid in VALID[state]:
        assert valid.label in message
    if state is S.FINALIZED:
        assert "valid: none" in message
    assert node.state is state and node.transitions == []


@pytest.mark.parametrize(
    ("start", "transition", "via"),
    [(S.UNCONFIGURED, T.CONFIGURE, S.CONFIGURING), (S.INACTIVE, T.CLEANUP, S.CLEANINGUP),
     (S.INACTIVE, T.ACTIVATE, S.ACTIVATING), (S.ACTIVE, T.DEACTIVATE, S.DEACTIVATING),
     (S.ACTIVE, T.ACTIVE_SHUTDOWN, S.SHUTTINGDOWN)],
)
def test_request_during_transition_refused(start: State, transition: Transition, via: State) -> None:
    node = make(start)
    node.start(transition)
    assert node.in_transition and node.valid_transitions() == ()
    for again in Transition:
        with pytest.raises(TransitionRefused, match=f"while {via.label}"):
            node.start(again)
    assert node.state is via


def test_request_during_error_processing_refused() -> None:
    node = make(S.ACTIVE)
    node.start(T.DEACTIVATE)
    node.complete(ERR)
    with pytest.raises(TransitionRefused, match="errorprocessing"):
        node.start(T.CONFIGURE)


def test_complete_without_running_callback_is_an_error() -> None:
    with pytest.raises(RuntimeError, match="no transition callback"):
        make().complete(OK)


def test_events_are_stamped_with_the_clock() -> None:
    clock = VirtualClock()
    node = make(clock=clock)
    clock.advance(1.5)
    node.start(T.CONFIGURE)
    clock.advance(0.25)
    node.complete(OK)
    assert [e.time for e in node.transitions] == [1.5, 1.75]
    assert str(node.transitions[0]) == "configure (1): unconfigured -> configuring"
    assert str(node.transitions[1]) == "on_configure_success (10): configuring -> inactive"


def test_must_start_in_a_primary_state() -> None:
    with pytest.raises(ValueError, match="primary"):
        make(S.CONFIGURING)


# -- parameters ------------------------------------------------------------------------------------


def test_parameters_declared_with_types_of_the_defaults() -> None:
    node = make()
    assert node.parameters == PARAMS
    assert node.parameter_types == {
        "alpha": "double", "beams": "integer", "enabled": "bool", "frame": "string",
        "gains": "double_array", "ids": "integer_array", "names": "string_array", "flags": "bool_array",
    }


@pytest.mark.parametrize(
    ("value", "kind"),
    [(True, "bool"), (1, "integer"), (1.0, "double"), ("x", "string"), ((1.0,), "double_array"),
     ((1,), "integer_array"), ((False,), "bool_array"), (("x",), "string_array"), ((), "array"),
     ((1, 2.0), None), ((True, 1), None), ([1.0], None), (None, None), ({"a": 1}, None), (((1,),), None)],
)
def test_parameter_type(value: object, kind: str | None) -> None:
    assert parameter_type(value) == kind


def test_accepted_set_applies_every_value() -> None:
    node = make()
    node.set_parameters({"alpha": 0.05, "beams": 30, "gains": (), "names": ("b", "c")})
    assert node.parameters == {**PARAMS, "alpha": 0.05, "beams": 30, "gains": (), "names": ("b", "c")}


def test_int_for_double_rejected_with_the_rclcpp_message() -> None:
    node = make()
    with pytest.raises(ParameterRejected) as rejected:
        node.set_parameters({"alpha": 1})
    assert str(rejected.value) == (
        "Wrong parameter type, parameter {alpha} is of type {double}, setting it to {integer} is not allowed."
    )


@pytest.mark.parametrize(
    ("name", "value", "declared", "given"),
    [("alpha", "0.1", "double", "string"), ("beams", True, "integer", "bool"),
     ("enabled", 1, "bool", "integer"), ("beams", 2.0, "integer", "double"),
     ("gains", (1, 2), "double_array", "integer_array"), ("frame", ("map",), "string", "string_array")],
)
def test_wrong_type_rejected_atomically(name: str, value: object, declared: str, given: str) -> None:
    node = make()
    with pytest.raises(ParameterRejected, match=rf"parameter \{{{name}\}} is of type \{{{declared}\}}, "
                                                rf"setting it to \{{{given}\}}"):
        node.set_parameters({"names": ("z",), name: value})  # type: ignore[dict-item]
    assert node.parameters == PARAMS


def test_undeclared_rejected_atomically() -> None:
    node = make()
    with pytest.raises(ParameterRejected, match="parameter 'alpha9' is not declared"):
        node.set_parameters({"alpha": 0.1, "alpha9": 0.1})
    assert node.parameters == PARAMS


def test_every_offending_parameter_is_named() -> None:
    node = make()
    reason = node.check_parameters({"nope": 1, "alpha": 1, "beams": [1]})  # type: ignore[dict-item]
    assert reason is not None
    assert "'nope' is not declared" in reason
    assert "{alpha}" in reason
    assert "'beams': [1] is not a ROS 2 parameter value" in reason
    assert node.check_parameters({"alpha": 0.3}) is None


def test_parameters_can_be_set_in_any_state() -> None:
    node = make(S.ACTIVE)
    node.start(T.DEACTIVATE)
    node.set_parameters({"alpha": 0.7})
    assert node.parameters["alpha"] == 0.7


def test_declared_value_without_ros_type_is_refused() -> None:
    with pytest.raises(ValueError, match="no ROS 2 type"):
        SimNode("x", {"p": (1, "a")}, VirtualClock())  # type: ignore[dict-item]
