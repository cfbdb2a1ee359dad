"""SimBackend as a Backend: reports, timing on the virtual clock, lifecycle and parameter requests."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping
from typing import Any

import pytest
from sim_helpers import Recorder, node_part
from sim_helpers import attached as attached_to

from sm_bt.engine.backend import Backend, CallResult, NodeReport
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.lifecycle import OUTCOMES, REQUESTABLE, Outcome, Transition
from sm_bt.model.states import State
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim import SimBackend, SimEventKind

S = State
T = Transition



def pilot_model() -> Model:
    parts = [node_part("amcl", {"transform_tolerance": 0.2, "alpha1": 0.2, "beams": 60}),
             node_part("laser_resender", {"node_name": "laser_resender"})]
    return Model("test.yaml", {p.name: p for p in parts})


def attached(**options: Any) -> tuple[SimBackend, Recorder]:
    return attached_to(pilot_model(), **options)


def transition_ids(backend: SimBackend, node: str) -> list[int]:
    return [int(e.transition.transition) for e in backend.events
            if e.node == node and e.kind is SimEventKind.TRANSITION and e.transition is not None]


# -- construction and attach -----------------------------------------------------------------------


def test_is_a_backend_with_its_own_or_a_given_clock() -> None:
    backend: Backend = SimBackend(pilot_model())
    assert isinstance(backend.clock, VirtualClock)
    clock = VirtualClock(5.0)
    assert SimBackend(pilot_model(), clock).clock is clock


def test_attach_reports_running_nodes_synchronously() -> None:
    backend = SimBackend(pilot_model(), initial_state={"laser_resender": S.INACTIVE},
                         initial_parameters={"amcl": {"alpha1": 0.05}})
    recorder = Recorder()
    backend.attach(["amcl", "laser_resender"], recorder)
    assert recorder.reports == [
        ("appeared", "amcl", NodeReport(S.UNCONFIGURED, {"transform_tolerance": 0.2, "alpha1": 0.05, "beams": 60})),
        ("appeared", "laser_resender", NodeReport(S.INACTIVE, {"node_name": "laser_resender"})),
    ]


def test_attach_only_reports_the_named_nodes() -> None:
    backend = SimBackend(pilot_model())
    recorder = Recorder()
    backend.attach(["amcl", "not_in_model"], recorder)
    backend.trigger("laser_resender", T.CONFIGURE)
    backend.clock.advance(1.0)
    assert [(kind, node) for kind, node, _ in recorder.reports] == [("appeared", "amcl")]


def test_one_initial_state_for_all() -> None:
    backend = SimBackend(pilot_model(), initial_state=S.ACTIVE)
    assert [backend.node(n).state for n in backend.nodes] == [S.ACTIVE, S.ACTIVE]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [({"amcl": {"alpha9": 0.1}}, "initial_parameters for node amcl: parameter 'alpha9' is not declared"),
     ({"amcl": {"beams": 6.0}}, r"parameter \{beams\} is of type \{integer\}, setting it to \{double\}"),
     ({"nobody": {"x": 1}}, r"initial_parameters names unknown nodes \['nobody'\]")],
)
def test_initial_parameters_validated(overrides: Mapping[str, Mapping[str, ParamValue]], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SimBackend(pilot_model(), initial_parameters=overrides)


def test_bad_options_refused() -> None:
    with pytest.raises(ValueError, match="transition_delay"):
        SimBackend(pilot_model(), transition_delay=-1.0)
    with pytest.raises(ValueError, match="unknown nodes"):
        SimBackend(pilot_model(), initial_state={"ghost": S.ACTIVE})
    with pytest.raises(ValueError, match="primary"):
        SimBackend(pilot_model(), initial_state=S.CONFIGURING)
    with pytest.raises(KeyError, match="no simulated node 'ghost'"):
        SimBackend(pilot_model()).node("ghost")


# -- change_state ----------------------------------------------------------------------------------


def test_configure_follows_the_virtual_clock() -> None:
    backend, recorder = attached()
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    # Nothing happens inside the call, nor before the clock runs.
    assert results == [] and recorder.reports == [] and backend.node("amcl").state is S.UNCONFIGURED
    backend.clock.run_pending()
    assert recorder.states("amcl") == [S.CONFIGURING] and results == []
    backend.clock.advance(0.049)
    assert recorder.states("amcl") == [S.CONFIGURING] and results == []
    backend.clock.advance(0.001)
    assert recorder.states("amcl") == [S.CONFIGURING, S.INACTIVE]
    assert results == [CallResult(True)]
    assert transition_ids(backend, "amcl") == [1, 10]
    assert [e.time for e in backend.node("amcl").transitions] == [0.0, pytest.approx(0.05)]


def test_without_history_nothing_is_recorded_and_the_nodes_work_the_same() -> None:
    backend, recorder = attached(history=False)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.set_parameters("amcl", {"alpha1": 0.5}, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(True), CallResult(True)]
    assert recorder.states("amcl") == [S.CONFIGURING, S.INACTIVE]
    assert backend.events == [] and backend.node("amcl").transitions == []
    assert backend.node("amcl").state is S.INACTIVE
    with_history, _ = attached()
    with_history.change_state("amcl", T.CONFIGURE, results.append)
    with_history.clock.advance(1.0)
    assert transition_ids(with_history, "amcl") == [1, 10]
    assert [e.goal for e in with_history.node("amcl").transitions] == [S.CONFIGURING, S.INACTIVE]


# The backend wires OUTCOMES correctly: SimNode's hand-written truth table pins the table itself.
@pytest.mark.parametrize(("step", "outcome"), [(s, o) for s in REQUESTABLE for o in Outcome])
def test_every_transition_and_outcome_through_the_backend(step: Any, outcome: Outcome) -> None:
    backend, recorder = attached(initial_state={"amcl": step.start})
    if outcome is not Outcome.SUCCESS:
        backend.fail_next("amcl", step.transition, outcome)
    results: list[CallResult] = []
    backend.change_state("amcl", step.transition, results.append)
    backend.clock.advance(1.0)
    first_id, after = OUTCOMES[step.via][outcome]
    expected_states, expected_ids = [step.via, after], [int(step.transition), int(first_id)]
    if after is S.ERRORPROCESSING:
        error_id, final = OUTCOMES[S.ERRORPROCESSING][Outcome.SUCCESS]
        expected_states.append(final)
        expected_ids.append(int(error_id))
    assert recorder.states("amcl") == expected_states
    assert transition_ids(backend, "amcl") == expected_ids
    assert backend.node("amcl").state is expected_states[-1]
    assert len(results) == 1 and results[0].ok is (outcome is Outcome.SUCCESS)


def test_activate_error_reports_every_state_with_its_timing() -> None:
    backend, recorder = attached(initial_state=S.INACTIVE, transition_delay=0.2, error_delay=0.5)
    backend.fail_next("amcl", T.ACTIVATE, Outcome.ERROR)
    results: list[CallResult] = []
    backend.change_state("amcl", T.ACTIVATE, results.append)
    backend.clock.run_until(0.2)
    assert recorder.states("amcl") == [S.ACTIVATING, S.ERRORPROCESSING]
    backend.clock.run_until(0.69)
    assert results == []
    backend.clock.run_until(0.7)
    assert recorder.states("amcl") == [S.ACTIVATING, S.ERRORPROCESSING, S.UNCONFIGURED]
    assert transition_ids(backend, "amcl") == [3, 32, 60]
    assert results == [CallResult(False, "activate of amcl failed: on_activate returned ERROR "
                                         "(node went to errorprocessing, then unconfigured)")]


def test_failure_reason() -> None:
    backend, _ = attached()
    backend.fail_next("amcl", T.CONFIGURE)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(False, "configure of amcl failed: on_configure returned FAILURE")]


def test_invalid_transition_refused_through_the_clock() -> None:
    backend, recorder = attached(initial_state={"amcl": S.ACTIVE})
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    assert results == []
    backend.clock.run_pending()
    assert results == [CallResult(False, "configure of amcl refused: transition configure is not valid "
                                         "in state active (valid: deactivate, shutdown)", refused=True)]
    assert recorder.reports == [] and backend.node("amcl").state is S.ACTIVE


def test_request_during_a_transition_refused() -> None:
    backend, recorder = attached()
    first: list[CallResult] = []
    second: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, first.append)
    backend.change_state("amcl", T.UNCONFIGURED_SHUTDOWN, second.append)
    backend.clock.run_pending()
    assert second == [CallResult(False, "shutdown of amcl refused: cannot shutdown while configuring "
                                        "(a transition is in progress)", refused=True)]
    backend.clock.advance(1.0)
    assert first == [CallResult(True)]
    assert recorder.states("amcl") == [S.CONFIGURING, S.INACTIVE]


def test_delay_overrides_per_node_and_per_transition() -> None:
    backend, _ = attached(transition_delay=0.125)
    backend.set_delay("amcl", 1.0)
    backend.set_delay("amcl", 0.25, T.ACTIVATE)
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.change_state("laser_resender", T.CONFIGURE, lambda _: None)
    backend.clock.advance(0.125)
    assert backend.node("laser_resender").state is S.INACTIVE  # default delay
    assert backend.node("amcl").state is S.CONFIGURING
    backend.clock.advance(0.875)
    assert backend.node("amcl").state is S.INACTIVE
    backend.change_state("amcl", T.ACTIVATE, lambda _: None)
    backend.clock.advance(0.125)
    assert backend.node("amcl").state is S.ACTIVATING
    backend.clock.advance(0.125)
    assert backend.node("amcl").state is S.ACTIVE
    with pytest.raises(ValueError, match="requestable"):
        backend.set_delay("amcl", 1.0, T.ON_ERROR_SUCCESS)
    with pytest.raises(ValueError, match=">= 0"):
        backend.set_delay("amcl", -0.1)


def test_per_node_delay_also_applies_to_error_processing() -> None:
    backend, _ = attached()
    backend.set_delay("amcl", 0.5)
    backend.fail_next("amcl", T.CONFIGURE, Outcome.ERROR)
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.clock.advance(0.5)
    assert backend.node("amcl").state is S.ERRORPROCESSING
    backend.clock.advance(0.25)
    assert backend.node("amcl").state is S.ERRORPROCESSING
    backend.clock.advance(0.25)
    assert backend.node("amcl").state is S.UNCONFIGURED


# -- set_parameters --------------------------------------------------------------------------------


def test_set_parameters_applies_after_the_delay() -> None:
    backend, recorder = attached()
    results: list[CallResult] = []
    backend.set_parameters("amcl", {"alpha1": 0.05, "transform_tolerance": 2.5}, results.append)
    backend.clock.run_pending()
    assert results == [] and recorder.reports == []
    backend.clock.advance(0.01)
    assert recorder.reports == [("parameters", "amcl", {"alpha1": 0.05, "transform_tolerance": 2.5})]
    assert results == [CallResult(True)]
    assert backend.node("amcl").parameters == {"transform_tolerance": 2.5, "alpha1": 0.05, "beams": 60}
    [event] = [e for e in backend.events if e.kind is SimEventKind.PARAMETERS]
    assert event.parameters == {"alpha1": 0.05, "transform_tolerance": 2.5}


@pytest.mark.parametrize(
    ("values", "reason"),
    [({"alpha1": 0.05, "transform_tolerance": 2}, "set_parameters on amcl rejected: Wrong parameter type, "
      "parameter {transform_tolerance} is of type {double}, setting it to {integer} is not allowed."),
     ({"alpha1": 0.05, "alpha1_": 0.05}, "set_parameters on amcl rejected: parameter 'alpha1_' is not declared"),
     ({"alpha1": "0.05"}, "set_parameters on amcl rejected: Wrong parameter type, parameter {alpha1} is of "
      "type {double}, setting it to {string} is not allowed."),
     ({"beams": True}, "set_parameters on amcl rejected: Wrong parameter type, parameter {beams} is of "
      "type {integer}, setting it to {bool} is not allowed.")],
)
def test_rejected_set_changes_nothing(values: dict[str, ParamValue], reason: str) -> None:
    backend, recorder = attached()
    before = backend.node("amcl").parameters
    results: list[CallResult] = []
    backend.set_parameters("amcl", values, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(False, reason)]
    assert recorder.reports == []
    assert backend.node("amcl").parameters == before


def test_parameters_can_be_set_during_a_transition() -> None:
    backend, _ = attached()
    results: list[CallResult] = []
    backend.set_delay("amcl", 1.0)
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.set_parameters("amcl", {"beams": 30}, results.append)
    backend.clock.advance(0.5)
    assert results == [CallResult(True)] and backend.node("amcl").state is S.CONFIGURING


# -- not running, detach, done never synchronous ---------------------------------------------------


@pytest.mark.parametrize("node", ["laser_resender", "ghost"])
def test_calls_to_a_node_not_running_fail_through_the_clock(node: str) -> None:
    backend = SimBackend(pilot_model(), late={"laser_resender": 5.0})
    results: list[CallResult] = []
    backend.change_state(node, T.CONFIGURE, results.append)
    backend.set_parameters(node, {"node_name": "x"}, results.append)
    assert results == []
    backend.clock.run_pending()
    assert results == [CallResult(False, f"node {node} is not running")] * 2


def test_done_is_never_called_inside_a_request() -> None:
    backend, recorder = attached(initial_state={"amcl": S.ACTIVE}, late={"laser_resender": 9.0})
    calls: list[str] = []
    in_call = False

    def done(result: CallResult) -> None:
        assert not in_call
        calls.append(result.reason)

    requests: list[Callable[[], None]] = [
        lambda: backend.change_state("amcl", T.DEACTIVATE, done),  # in transition
        lambda: backend.change_state("amcl", T.ACTIVATE, done),  # refused
        lambda: backend.set_parameters("amcl", {"beams": 1}, done),
        lambda: backend.set_parameters("amcl", {"beams": 1.0}, done),  # rejected
        lambda: backend.change_state("laser_resender", T.CONFIGURE, done),  # not running
        lambda: backend.set_parameters("ghost", {}, done),
    ]
    for request in requests:
        reports = len(recorder.reports)
        in_call = True
        request()
        in_call = False
        assert len(recorder.reports) == reports
    backend.clock.advance(1.0)
    assert len(calls) == len(requests)


def test_detach_stops_reports_but_calls_complete() -> None:
    backend, recorder = attached()
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.detach()
    backend.clock.advance(1.0)
    assert recorder.reports == []
    assert results == [CallResult(True)]


def test_reattach_reports_live_state() -> None:
    backend, _ = attached()
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.clock.advance(1.0)
    other = Recorder()
    backend.attach(["amcl"], other)
    assert other.reports == [("appeared", "amcl", NodeReport(S.INACTIVE, backend.node("amcl").parameters))]


def test_events_read_as_a_narrative() -> None:
    backend, _ = attached()
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.clock.advance(1.0)
    lines = [str(e) for e in backend.events if e.node == "amcl"]
    assert [e.kind for e in backend.events] == [SimEventKind.REQUEST, SimEventKind.TRANSITION,
                                                SimEventKind.TRANSITION, SimEventKind.RESPONSE]
    assert lines[0].split() == ["0.000", "amcl", "request", "change_state", "configure", "(1)"]
    assert lines[2].endswith("on_configure_success (10): configuring -> inactive")
    assert lines[3].endswith("configure: ok")


# -- initial state by label (issue 10, item 5) -----------------------------------------------------


def test_initial_state_by_label_for_all_or_per_node() -> None:
    backend, _ = attached(initial_state="active")
    assert [backend.node(n).state for n in backend.nodes] == [S.ACTIVE, S.ACTIVE]
    # Started in the default mode's parameters, as with a State.
    assert backend.node("laser_resender").parameters == {"node_name": "laser_resender"}
    backend = SimBackend(pilot_model(), initial_state={"amcl": "inactive", "laser_resender": S.ACTIVE})
    assert [backend.node(n).state for n in backend.nodes] == [S.INACTIVE, S.ACTIVE]


@pytest.mark.parametrize("bad", ["configuring", "ACTIVE", "running", S.ERRORPROCESSING])
def test_initial_state_label_must_be_a_primary_state(bad: State | str) -> None:
    for initial_state in (bad, {"amcl": bad}):
        with pytest.raises(ValueError, match="unconfigured, inactive, active, finalized"):
            SimBackend(pilot_model(), initial_state=initial_state)


def test_restart_takes_a_label_too() -> None:
    backend, _ = attached()
    backend.restart("amcl", "active")
    assert backend.node("amcl").state is S.ACTIVE
    with pytest.raises(ValueError, match="primary"):
        backend.restart("amcl", "activating")


# -- plain (parameter-only) nodes ------------------------------------------------------------------


def test_plain_node_appears_active_without_lifecycle() -> None:
    backend = SimBackend(pilot_model(), plain=("laser_resender",))
    assert backend.is_plain("laser_resender") and not backend.is_plain("amcl")
    recorder = Recorder()
    backend.attach(backend.nodes, recorder)
    assert recorder.reports == [
        ("appeared", "amcl", NodeReport(S.UNCONFIGURED, backend.node("amcl").parameters)),
        ("appeared", "laser_resender", NodeReport(S.ACTIVE, {"node_name": "laser_resender"}, lifecycle=False)),
    ]


def test_plain_node_runs_active_whatever_one_initial_state_says() -> None:
    backend = SimBackend(pilot_model(), initial_state="inactive", plain=["laser_resender"])
    assert backend.node("laser_resender").state is S.ACTIVE and backend.node("amcl").state is S.INACTIVE
    with pytest.raises(ValueError, match="no lifecycle services"):
        SimBackend(pilot_model(), initial_state={"laser_resender": "inactive"}, plain=["laser_resender"])
    with pytest.raises(ValueError, match=r"plain names unknown nodes \['ghost'\]"):
        SimBackend(pilot_model(), plain=["ghost"])


def test_plain_node_sets_parameters_and_refuses_transitions_through_the_clock() -> None:
    backend, recorder = attached(plain=("laser_resender",))
    results: list[CallResult] = []
    backend.set_parameters("laser_resender", {"node_name": "other"}, results.append)
    backend.change_state("laser_resender", T.DEACTIVATE, results.append)
    assert results == []  # never from inside the call
    backend.clock.run_pending()
    assert results == [CallResult(False, "node laser_resender has no lifecycle services (parameters only): "
                                         "it cannot deactivate")]
    backend.clock.advance(1.0)
    assert results[1:] == [CallResult(True)]
    assert recorder.about("laser_resender") == [("parameters", {"node_name": "other"})]
    assert backend.node("laser_resender").state is S.ACTIVE and backend.node("laser_resender").transitions == []


def test_plain_node_refuses_lifecycle_faults_but_takes_the_others() -> None:
    backend, recorder = attached(plain=("laser_resender",))
    for arm in (lambda: backend.fail_next("laser_resender", T.ACTIVATE),
                lambda: backend.hang_next("laser_resender", T.ACTIVATE),
                lambda: backend.trigger("laser_resender", T.DEACTIVATE)):
        with pytest.raises(ValueError, match="laser_resender: it has no lifecycle services"):
            arm()
    backend.reject_parameters("laser_resender", "read-only")
    backend.set_parameter("laser_resender", "node_name", "x")
    backend.crash("laser_resender")
    backend.clock.advance(2.0)
    assert recorder.about("laser_resender")[-1][0] == "vanished"
    with pytest.raises(ValueError, match="runs active"):
        backend.restart("laser_resender", S.INACTIVE)
    backend.restart("laser_resender")
    assert recorder.about("laser_resender")[-1] == (
        "appeared", NodeReport(S.ACTIVE, {"node_name": "laser_resender"}, lifecycle=False))


# -- helpers for long runs: hung nodes, disarming faults -------------------------------------------


def test_hung_lists_nodes_stuck_in_a_hanging_transition_until_restart() -> None:
    backend, _ = attached()
    backend.hang_next("amcl", T.CONFIGURE)
    assert backend.hung() == ()
    backend.change_state("amcl", T.CONFIGURE, lambda _: None)
    backend.set_parameters("amcl", {"alpha1": 0.1}, lambda _: None)
    assert backend.in_flight("amcl") == ("configure", "set_parameters")  # sent, not yet answered
    backend.clock.advance(5.0)
    assert backend.hung() == ("amcl",) and backend.node("amcl").state is S.CONFIGURING
    assert backend.in_flight("amcl") == ("configure",)
    backend.restart("amcl")
    assert backend.hung() == () and backend.in_flight("amcl") == ()


def test_clear_faults_disarms_what_was_not_used() -> None:
    backend, _ = attached()
    backend.fail_next("amcl", T.CONFIGURE)
    backend.hang_next("laser_resender", T.CONFIGURE)
    backend.reject_parameters("amcl", "no")
    backend.clear_faults()
    results: list[CallResult] = []
    for node in backend.nodes:
        backend.change_state(node, T.CONFIGURE, results.append)
    backend.set_parameters("amcl", {"alpha1": 0.1}, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(True)] * 3
    assert [e.details for e in backend.events if e.kind is SimEventKind.FAULT][-2:] == [
        "cleared: armed faults disarmed", "cleared: armed faults disarmed"]


def test_a_call_made_when_restart_fails_the_old_ones_reaches_the_new_process() -> None:
    # Found by the manager's property tests: a client that calls again from the failed call's
    # done() must reach the new process, not be left unanswered on the old one.
    backend, recorder = attached()
    results: list[CallResult] = []

    def again(result: CallResult) -> None:
        results.append(result)
        backend.set_parameters("amcl", {"alpha1": 0.1}, results.append)

    backend.set_parameters("amcl", {"alpha1": 0.3}, again)
    backend.crash("amcl")
    backend.restart("amcl")
    assert recorder.about("amcl")[-1][0] == "appeared"  # the new process is there before the failure
    backend.clock.advance(1.0)
    assert results == [CallResult(False, "node amcl restarted"), CallResult(True)]
    assert backend.node("amcl").parameters["alpha1"] == 0.1


def test_what_happens_at_one_instant_is_reported_in_one_batch() -> None:
    """Two nodes that finish at one instant are reported together (the manager settles once);
    one that finishes later is a batch of its own, and nothing is batched once detached."""
    backend, recorder = attached(transition_delay=1.0)
    backend.trigger("amcl", T.CONFIGURE)
    backend.trigger("laser_resender", T.CONFIGURE)
    backend.clock.advance(1.0)
    assert [recorder.reports[i] for i in range(*recorder.batches[0])] == [
        ("state", "amcl", S.INACTIVE), ("state", "laser_resender", S.INACTIVE)]
    backend.set_delay("amcl", 2.0)
    backend.trigger("amcl", T.ACTIVATE)
    backend.trigger("laser_resender", T.ACTIVATE)
    backend.clock.advance(3.0)
    assert [[recorder.reports[i][1:] for i in range(*b)] for b in recorder.batches[1:]] == [
        [("laser_resender", S.ACTIVE)], [("amcl", S.ACTIVE)]]
    backend.detach()
    assert backend.clock.batch is contextlib.nullcontext
