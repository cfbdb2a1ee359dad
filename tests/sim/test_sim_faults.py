"""SimBackend fault injection: each fault, what the listener sees, and what pending calls get."""

from __future__ import annotations

from typing import Any

import pytest
from sim_helpers import Recorder, node_part
from sim_helpers import attached as attached_to

from sm_bt.engine.backend import CallResult, NodeReport
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.model.states import State
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim import NodeStatus, SimBackend, SimEventKind

S = State
T = Transition
AMCL_DEFAULTS: dict[str, ParamValue] = {"transform_tolerance": 0.2, "alpha1": 0.2}



def pilot_model() -> Model:
    parts = [node_part("amcl", AMCL_DEFAULTS), node_part("laser_resender", {"node_name": "laser_resender"})]
    return Model("test.yaml", {p.name: p for p in parts})


def attached(**options: Any) -> tuple[SimBackend, Recorder]:
    return attached_to(pilot_model(), **options)


def faults(backend: SimBackend, node: str) -> list[str]:
    return [e.details for e in backend.events if e.node == node and e.kind is SimEventKind.FAULT]


# -- fail_next -------------------------------------------------------------------------------------


def test_fail_next_fails_once() -> None:
    backend, recorder = attached()
    backend.fail_next("amcl", T.CONFIGURE)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert [r.ok for r in results] == [False, True]
    assert [p for k, p in recorder.about("amcl")] == [S.CONFIGURING, S.UNCONFIGURED, S.CONFIGURING, S.INACTIVE]
    assert faults(backend, "amcl") == ["armed: next on_configure returns FAILURE",
                                       "on_configure will return FAILURE"]


@pytest.mark.parametrize(("on_error", "final", "last_id"),
                         [(Outcome.SUCCESS, S.UNCONFIGURED, 60), (Outcome.FAILURE, S.FINALIZED, 61),
                          (Outcome.ERROR, S.FINALIZED, 62)])
def test_fail_next_with_error_and_on_error(on_error: Outcome, final: State, last_id: int) -> None:
    backend, recorder = attached(initial_state=S.ACTIVE)
    backend.fail_next("amcl", T.DEACTIVATE, Outcome.ERROR, on_error)
    results: list[CallResult] = []
    backend.change_state("amcl", T.DEACTIVATE, results.append)
    backend.clock.advance(1.0)
    assert [p for k, p in recorder.about("amcl")] == [S.DEACTIVATING, S.ERRORPROCESSING, final]
    assert [int(e.transition) for e in backend.node("amcl").transitions] == [4, 42, last_id]
    assert results == [CallResult(False, "deactivate of amcl failed: on_deactivate returned ERROR "
                                         f"(node went to errorprocessing, then {final.label})")]


def test_fail_next_is_per_node_and_per_transition() -> None:
    backend, _ = attached()
    backend.fail_next("amcl", T.ACTIVATE)
    results: list[CallResult] = []
    backend.change_state("laser_resender", T.CONFIGURE, results.append)
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    backend.change_state("laser_resender", T.ACTIVATE, results.append)
    backend.change_state("amcl", T.ACTIVATE, results.append)
    backend.clock.advance(1.0)
    assert [r.ok for r in results] == [True, True, True, False]


def test_fail_next_checks_its_arguments() -> None:
    backend = SimBackend(pilot_model())
    with pytest.raises(ValueError, match=r"FAILURE or Outcome\.ERROR"):
        backend.fail_next("amcl", T.CONFIGURE, Outcome.SUCCESS)
    with pytest.raises(ValueError, match="requestable"):
        backend.fail_next("amcl", T.ON_CONFIGURE_SUCCESS)
    with pytest.raises(KeyError):
        backend.fail_next("ghost", T.CONFIGURE)


# -- hang_next -------------------------------------------------------------------------------------


def test_hang_next_never_completes() -> None:
    backend, recorder = attached()
    backend.hang_next("amcl", T.CONFIGURE)
    hung: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, hung.append)
    backend.clock.advance(100.0)
    assert hung == []
    assert recorder.about("amcl") == [("state", S.CONFIGURING)]
    assert backend.node("amcl").state is S.CONFIGURING
    later: list[CallResult] = []
    backend.change_state("amcl", T.UNCONFIGURED_SHUTDOWN, later.append)
    backend.clock.advance(1.0)
    assert later == [CallResult(False, "shutdown of amcl refused: cannot shutdown while configuring "
                                       "(a transition is in progress)", refused=True)]
    assert "configure hangs in configuring: no response" in faults(backend, "amcl")


def test_hung_call_fails_when_the_node_vanishes() -> None:
    backend, _ = attached()
    backend.hang_next("amcl", T.CONFIGURE)
    hung: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, hung.append)
    backend.clock.advance(5.0)
    backend.crash("amcl")
    backend.clock.advance(1.0)
    assert hung == [CallResult(False, "node amcl vanished")]


def test_hung_call_fails_on_restart_and_the_fault_is_used_up() -> None:
    backend, _ = attached()
    backend.hang_next("amcl", T.CONFIGURE)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(5.0)
    backend.restart("amcl")
    assert results == [CallResult(False, "node amcl restarted")]
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert results[1:] == [CallResult(True)]


# -- reject_parameters -----------------------------------------------------------------------------


def test_reject_parameters_until_cleared() -> None:
    backend, recorder = attached()
    backend.reject_parameters("amcl", "parameter server busy")
    results: list[CallResult] = []
    backend.set_parameters("amcl", {"alpha1": 0.05}, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(False, "parameter server busy")]
    assert backend.node("amcl").parameters == AMCL_DEFAULTS and recorder.reports == []
    backend.reject_parameters("amcl", None)
    backend.set_parameters("amcl", {"alpha1": 0.05}, results.append)
    backend.clock.advance(1.0)
    assert results[1:] == [CallResult(True)]
    assert recorder.about("amcl") == [("parameters", {"alpha1": 0.05})]
    assert faults(backend, "amcl") == ["armed: parameter sets rejected (parameter server busy)",
                                       "cleared: parameter sets accepted again"]


# -- set_parameter (from outside) ------------------------------------------------------------------


def test_set_parameter_from_outside_is_reported_at_once() -> None:
    backend, recorder = attached()
    backend.set_parameter("amcl", "transform_tolerance", 1.5)
    assert recorder.reports == [("parameters", "amcl", {"transform_tolerance": 1.5})]
    assert backend.node("amcl").parameters["transform_tolerance"] == 1.5


@pytest.mark.parametrize(("name", "value", "message"),
                         [("transform_tolerance", 2, "is of type {double}, setting it to {integer}"),
                          ("alpha9", 0.1, "'alpha9' is not declared")])
def test_set_parameter_is_type_checked(name: str, value: ParamValue, message: str) -> None:
    backend, recorder = attached()
    with pytest.raises(ValueError, match=message.replace("{", r"\{").replace("}", r"\}")):
        backend.set_parameter("amcl", name, value)
    assert recorder.reports == [] and backend.node("amcl").parameters == AMCL_DEFAULTS


def test_set_parameter_needs_a_running_node() -> None:
    backend = SimBackend(pilot_model(), late={"amcl": 1.0})
    with pytest.raises(ValueError, match="it is not started"):
        backend.set_parameter("amcl", "alpha1", 0.1)


# -- trigger ---------------------------------------------------------------------------------------


def test_laser_resender_fails_by_itself() -> None:
    backend, recorder = attached(initial_state={"laser_resender": S.ACTIVE})
    backend.trigger("laser_resender", T.DEACTIVATE, outcome=Outcome.ERROR)
    assert recorder.about("laser_resender") == [("state", S.DEACTIVATING)]
    backend.clock.advance(0.05)
    assert recorder.about("laser_resender")[-1] == ("state", S.ERRORPROCESSING)
    backend.clock.advance(0.05)
    assert recorder.about("laser_resender") == [
        ("state", S.DEACTIVATING), ("state", S.ERRORPROCESSING), ("state", S.UNCONFIGURED)]
    events = [e.transition for e in backend.events if e.kind is SimEventKind.TRANSITION]
    assert [(int(e.transition), int(e.start), int(e.goal)) for e in events if e is not None] == [
        (4, 3, 14), (42, 14, 15), (60, 15, 1)]


def test_trigger_success_and_failure() -> None:
    backend, recorder = attached()
    backend.trigger("amcl", T.CONFIGURE)
    backend.clock.advance(1.0)
    backend.trigger("amcl", T.ACTIVATE, outcome=Outcome.FAILURE)
    backend.clock.advance(1.0)
    assert [p for _, p in recorder.about("amcl")] == [S.CONFIGURING, S.INACTIVE, S.ACTIVATING, S.INACTIVE]


def test_trigger_does_not_consume_fail_next() -> None:
    backend, _ = attached()
    backend.fail_next("amcl", T.CONFIGURE)
    backend.trigger("amcl", T.CONFIGURE)
    backend.clock.advance(1.0)
    backend.trigger("amcl", T.CLEANUP)
    backend.clock.advance(1.0)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert [r.ok for r in results] == [False]


def test_trigger_must_be_valid() -> None:
    backend, _ = attached()
    with pytest.raises(ValueError, match="cannot activate by itself: transition activate is not valid"):
        backend.trigger("amcl", T.ACTIVATE)
    backend.trigger("amcl", T.CONFIGURE)
    with pytest.raises(ValueError, match="while configuring"):
        backend.trigger("amcl", T.UNCONFIGURED_SHUTDOWN)


# -- crash -----------------------------------------------------------------------------------------


def test_crash_stops_answers_then_vanishes_and_fails_pending_calls() -> None:
    backend, recorder = attached(vanish_after=2.0)
    backend.set_delay("amcl", 0.5)
    results: list[tuple[str, CallResult]] = []
    backend.change_state("amcl", T.CONFIGURE, lambda r: results.append(("in flight", r)))
    backend.clock.advance(0.25)
    backend.crash("amcl")
    assert backend.status("amcl") is NodeStatus.CRASHED
    backend.set_parameters("amcl", {"alpha1": 0.1}, lambda r: results.append(("new", r)))
    backend.clock.advance(1.999)
    assert results == []
    assert recorder.about("amcl") == [("state", S.CONFIGURING)]  # frozen mid-transition
    backend.clock.advance(0.001)
    assert recorder.about("amcl")[1:] == [("vanished", "no answer for 2.0 s (crashed?)")]
    assert results == [("in flight", CallResult(False, "node amcl vanished")),
                       ("new", CallResult(False, "node amcl vanished"))]
    assert backend.status("amcl") is NodeStatus.VANISHED
    later: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, later.append)
    backend.clock.run_pending()
    assert later == [CallResult(False, "node amcl is not running")]
    assert [e.kind for e in backend.events if e.node == "amcl"][-5:] == [
        SimEventKind.VANISHED, SimEventKind.RESPONSE, SimEventKind.RESPONSE, SimEventKind.REQUEST,
        SimEventKind.RESPONSE]


def test_default_vanish_reason_and_only_running_nodes_crash() -> None:
    backend, recorder = attached()
    backend.crash("amcl")
    with pytest.raises(ValueError, match="it is crashed"):
        backend.crash("amcl")
    backend.clock.advance(1.0)
    assert recorder.reports == [("vanished", "amcl", "no answer for 1.0 s (crashed?)")]
    with pytest.raises(ValueError, match="it is vanished"):
        backend.trigger("amcl", T.CONFIGURE)


def test_vanish_reports_the_node_gone_at_once_and_fails_its_calls() -> None:
    backend, recorder = attached()
    backend.set_delay("amcl", 0.5)
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(0.25)
    backend.vanish("amcl")
    assert backend.status("amcl") is NodeStatus.VANISHED
    assert recorder.about("amcl") == [("state", S.CONFIGURING), ("vanished", "its process ended")]
    assert results == [CallResult(False, "node amcl vanished")]
    backend.clock.advance(1.0)  # the callback it was in never ends
    assert recorder.about("amcl")[2:] == [] and len(results) == 1
    with pytest.raises(ValueError, match="cannot make node amcl vanish: it is vanished"):
        backend.vanish("amcl")
    backend.restart("amcl")
    assert backend.status("amcl") is NodeStatus.RUNNING


def test_a_crashed_node_vanishes_at_once_when_its_process_ends() -> None:
    backend, recorder = attached(vanish_after=5.0)
    backend.crash("amcl")
    backend.vanish("amcl")
    assert recorder.reports == [("vanished", "amcl", "its process ended")]
    backend.clock.advance(10.0)  # the crash's own vanish timer is gone
    assert len(recorder.reports) == 1


# -- restart ---------------------------------------------------------------------------------------


def test_restart_after_crash_is_a_fresh_process() -> None:
    backend, recorder = attached(initial_parameters={"amcl": {"alpha1": 0.3}})
    backend.set_parameter("amcl", "alpha1", 0.9)
    backend.trigger("amcl", T.CONFIGURE)
    backend.clock.advance(1.0)
    backend.crash("amcl")
    backend.clock.advance(1.0)
    recorder.reports.clear()
    backend.restart("amcl")
    initial = {"transform_tolerance": 0.2, "alpha1": 0.3}
    assert recorder.reports == [("appeared", "amcl", NodeReport(S.UNCONFIGURED, initial))]
    assert backend.status("amcl") is NodeStatus.RUNNING
    assert backend.node("amcl").transitions == []
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(True)]


def test_a_restart_unnoticed_is_told_as_a_state_change_of_the_old_process() -> None:
    backend, recorder = attached(initial_state=S.ACTIVE)
    results: list[CallResult] = []
    backend.set_delay("amcl", 1.0)
    backend.change_state("amcl", T.DEACTIVATE, results.append)
    backend.clock.advance(0.5)
    recorder.reports.clear()
    backend.restart("amcl", unnoticed=True)
    assert recorder.reports == [("state", "amcl", S.UNCONFIGURED)]  # no vanish, no appearance
    assert results == [CallResult(False, "node amcl restarted")]
    assert backend.node("amcl").state is S.UNCONFIGURED and backend.status("amcl") is NodeStatus.RUNNING


def test_restart_before_vanishing_cancels_the_vanish() -> None:
    backend, recorder = attached()
    backend.crash("amcl")
    backend.clock.advance(0.5)
    backend.restart("amcl", S.INACTIVE)
    backend.clock.advance(5.0)
    assert recorder.about("amcl") == [("appeared", NodeReport(S.INACTIVE, AMCL_DEFAULTS))]


def test_restart_of_a_running_node_fails_its_calls_and_cancels_its_callbacks() -> None:
    backend, recorder = attached()
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.clock.run_pending()
    backend.restart("amcl", S.ACTIVE)
    backend.clock.advance(1.0)
    assert results == [CallResult(False, "node amcl restarted")]
    assert recorder.about("amcl") == [("state", S.CONFIGURING), ("appeared", NodeReport(S.ACTIVE, AMCL_DEFAULTS))]
    assert backend.node("amcl").state is S.ACTIVE


# -- late start ------------------------------------------------------------------------------------


def test_late_node_appears_at_its_time() -> None:
    backend = SimBackend(pilot_model(), late={"laser_resender": 2.0})
    recorder = Recorder()
    backend.attach(backend.nodes, recorder)
    assert [n for _, n, _ in recorder.reports] == ["amcl"]
    assert backend.status("laser_resender") is NodeStatus.NOT_STARTED
    backend.clock.advance(1.999)
    assert [n for _, n, _ in recorder.reports] == ["amcl"]
    backend.clock.advance(0.001)
    assert recorder.reports[-1] == ("appeared", "laser_resender",
                                    NodeReport(S.UNCONFIGURED, {"node_name": "laser_resender"}))
    results: list[CallResult] = []
    backend.change_state("laser_resender", T.CONFIGURE, results.append)
    backend.clock.advance(1.0)
    assert results == [CallResult(True)]


def test_start_late_method_and_its_limits() -> None:
    backend = SimBackend(pilot_model(), initial_state={"amcl": S.INACTIVE})
    backend.start_late("amcl", 3.0)
    recorder = Recorder()
    backend.attach(["amcl"], recorder)
    assert recorder.reports == []
    backend.clock.advance(3.0)
    assert recorder.reports == [("appeared", "amcl", NodeReport(S.INACTIVE, AMCL_DEFAULTS))]
    with pytest.raises(ValueError, match="already reported running"):
        backend.start_late("amcl", 5.0)
    assert faults(backend, "amcl") == ["not running until t=3"]
    assert [e.details for e in backend.events if e.kind is SimEventKind.STARTED] == ["started late in inactive"]


def test_late_node_started_early_by_restart() -> None:
    backend = SimBackend(pilot_model(), late={"amcl": 10.0})
    recorder = Recorder()
    backend.attach(["amcl"], recorder)
    backend.restart("amcl")
    backend.clock.advance(20.0)
    assert [k for k, _, _ in recorder.reports] == ["appeared"]  # once, not again at t=10


def test_restart_needs_a_primary_state_and_changes_nothing_otherwise() -> None:
    backend, _ = attached()
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    with pytest.raises(ValueError, match="primary"):
        backend.restart("amcl", S.CONFIGURING)
    backend.clock.advance(1.0)
    assert results == [CallResult(True)]


def test_identical_calls_are_answered_separately() -> None:
    backend, _ = attached()
    results: list[CallResult] = []
    backend.change_state("amcl", T.CONFIGURE, results.append)
    backend.change_state("amcl", T.CONFIGURE, results.append)  # same call again: refused first
    backend.clock.run_pending()
    backend.crash("amcl")
    backend.clock.advance(1.0)
    assert [r.reason for r in results] == [
        "configure of amcl refused: cannot configure while configuring (a transition is in progress)",
        "node amcl vanished"]
