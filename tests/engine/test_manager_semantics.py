"""The manager's request semantics, case by case: preemption while calls are in flight, rules that
cascade through nested systems, recovery that gives up on a hung node, and refused requests.

The property tests (test_manager_properties.py, test_manager_pairs.py) check the same rules over
generated models and interleavings; these name the cases a reader looks for first.
"""

from __future__ import annotations

import re

import pytest
from model_files import MODELS, bundled, fixture

from sm_bt.engine.events import Cause, EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.engine.requests import Origin
from sm_bt.model.loader import load_model_text
from sm_bt.model.states import State, StateMode
from sm_bt.sim import SimulatedSystem

MANAGER_CAUSED = re.compile(r"cannot \w+ while")


# -- preemption ----------------------------------------------------------------------------------


def test_a_request_at_the_same_instant_supersedes_the_one_whose_calls_are_in_flight() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    first = rig.manager.change_state("pilot", "configure")
    second = rig.manager.change_mode("pilot", "f_normal_mode")
    rig.run_until(lambda: first.done and second.done)
    assert first.reason == f"preempted by request #{second.id} (change_mode pilot f_normal_mode)"
    assert second.succeeded, second.reason
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"


@pytest.mark.parametrize("offset", [0.0, 0.01, 0.03, 0.06, 0.12])
def test_the_last_request_wins_at_any_offset(offset: float) -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    first = rig.manager.change_mode("pilot", "f_degraded_mode")
    rig.run(offset)
    second = rig.manager.change_mode("pilot", "f_performance_mode")
    rig.run_until(lambda: first.done and second.done)
    assert second.succeeded, second.reason
    assert str(rig.manager.actual("pilot")) == "active.f_performance_mode"
    assert first.succeeded or first.reason.startswith(f"preempted by request #{second.id}")
    # The nodes end where the winner wants them, whatever the first had in flight.
    assert rig.backend.node("controller_server").parameters["FollowPath.max_vel_x"] == 0.5
    assert rig.backend.node("laser_resender").state is State.ACTIVE


def test_no_call_is_sent_that_conflicts_with_one_in_flight() -> None:
    # The second request wants amcl back down while its configure is still running: the driver
    # waits for the configure to end, then cleans up (the reference would send in parallel).
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, transition_delay=0.2)
    rig.manager.change_state("pilot", "configure")
    rig.run(0.05)
    second = rig.manager.change_to("pilot", "unconfigured")
    rig.finish(second)
    assert second.succeeded, second.reason
    refused = [e for e in rig.backend.events if e.kind == "response" and "refused" in e.details]
    assert refused == []
    amcl = [str(e.transition) for e in rig.backend.events if e.node == "amcl" and e.transition is not None]
    assert amcl == ["configure (1): unconfigured -> configuring", "on_configure_success (10): configuring -> inactive",
                    "cleanup (2): inactive -> cleaningup", "on_cleanup_success (20): cleaningup -> unconfigured"]


def test_while_a_request_moves_a_part_any_transition_is_taken_as_its_new_target() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    configure = rig.manager.change_state("pilot", "configure")
    activate = rig.manager.change_state("pilot", "activate")  # invalid from unconfigured: but it is moving
    rig.run_until(lambda: activate.done)
    assert configure.reason.startswith(f"preempted by request #{activate.id}")
    assert activate.succeeded, activate.reason
    assert rig.manager.actual("pilot").state is State.ACTIVE


def test_on_a_settled_part_an_invalid_transition_is_refused_and_changes_nothing() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.finish(rig.manager.change_mode("amcl", "DEGRADED"))
    sent = len(rig.backend.events)
    configure = rig.manager.change_state("amcl", "configure")
    assert configure.done and not configure.succeeded
    assert configure.reason == "amcl: transition configure is not valid in state active (valid: deactivate, shutdown)"
    assert len(rig.backend.events) == sent and rig.manager.requests() == []
    assert rig.manager.target("amcl") == StateMode(State.ACTIVE, "DEGRADED")


def test_a_failed_call_of_a_preempted_request_does_not_fail_its_successor() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.backend.fail_next("amcl", Transition.CONFIGURE)
    first = rig.manager.change_mode("pilot", "f_normal_mode")
    second = rig.manager.change_state("pilot", "configure")
    rig.run_until(lambda: second.done)
    # amcl's configure (sent for the first request) failed; the second request configures it again.
    assert second.succeeded, second.reason
    assert first.reason.startswith("preempted by")
    assert rig.manager.actual("amcl").state is State.INACTIVE


def test_cancel_while_calls_are_in_flight_leaves_no_request_and_restores_the_target() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    request = rig.manager.change_mode("pilot", "f_degraded_mode")
    rig.run(0.02)
    request.cancel()
    assert request.reason == "cancelled" and rig.manager.requests() == []
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_normal_mode")
    back = rig.manager.change_mode("pilot", "f_normal_mode")
    rig.finish(back)
    assert back.succeeded, back.reason


# -- rules cascade through nested systems ----------------------------------------------------------


def test_a_parents_rule_reacts_to_its_sub_systems_rule() -> None:
    rig = SimulatedSystem(fixture("cascade"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("robot", "__DEFAULT__")).succeeded
    rig.backend.trigger("laser", Transition.DEACTIVATE, Outcome.ERROR)  # ends unconfigured
    rig.run_until(lambda: str(rig.manager.actual("robot")) == "active.CAUTIOUS", timeout=10.0)
    rules = [(e.part, e.message.split(":")[0]) for e in rig.events_of(EventKind.RULE)]
    assert rules == [("navigation", "rule degrade_without_laser"), ("robot", "rule cautious_when_navigation_degrades")]
    # Between the two, the parent's divergence was a fault (a rule below re-targeted its part),
    # not an override that nothing may act on.
    robot_causes = {e.divergence.cause for e in rig.events_of(EventKind.DIVERGENCE, "robot") if e.divergence}
    assert Cause.FAULT in robot_causes and Cause.OVERRIDE not in robot_causes
    assert str(rig.manager.actual("arm")) == "inactive" and str(rig.manager.actual("planner")) == "active.SLOW"
    assert rig.manager.divergences() == []
    # Nobody tried to restore the laser: the rules covered it.
    assert not [e for e in rig.events_of(EventKind.REQUEST) if e.request and e.request.origin is Origin.RECOVERY]


def test_without_a_rule_above_the_parent_stays_a_reported_fault() -> None:
    text = (MODELS / "cascade.yaml").read_text()
    rule = text[text.index("    rules:\n      cautious_when"):text.index("navigation:\n  ros__parameters")]
    rig = SimulatedSystem(load_model_text(text.replace(rule, "\n"), "cascade_without_robot_rule.yaml"),
                          grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("robot", "__DEFAULT__")).succeeded
    rig.backend.trigger("laser", Transition.DEACTIVATE, Outcome.ERROR)
    rig.run_until(lambda: str(rig.manager.actual("navigation")) == "active.DEGRADED", timeout=10.0)
    rig.run(2.0)
    # The sub-system's rule acted; the system above has no rule for it, so the divergence stays
    # a fault that the mission tree sees (OnDivergence), and nothing fights the rule below.
    divergence = rig.manager.divergence("robot")
    assert divergence is not None and divergence.cause is Cause.FAULT and divergence.is_error
    assert [d.part for d in rig.manager.divergences(errors_only=True)] == ["robot"]
    assert rig.manager.requests() == []
    assert str(rig.manager.actual("navigation")) == "active.DEGRADED"


# -- recovery gives up on a hung node ---------------------------------------------------------------


def test_recovery_gives_up_on_a_node_hung_in_a_transition_and_the_tree_sees_it() -> None:
    rig = SimulatedSystem(bundled("pilot"), grace_period=1.0, recovery_attempts=3, request_timeout=30.0)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    rig.backend.hang_next("laser_resender", Transition.ACTIVATE)
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE, Outcome.ERROR)  # fails, ends unconfigured
    took = rig.run_until(lambda: bool(rig.events_of(EventKind.FAILED)), timeout=200.0, step=0.1)
    failed = rig.events_of(EventKind.FAILED)[0].message
    assert failed.startswith("gave up restoring laser_resender to active.__DEFAULT__ after 3 attempts: ")
    assert "laser_resender hung in activating for" in failed
    assert took < 3 * (30.0 + 1.0) + 2.0
    recoveries = {e.request.id: e.request for e in rig.events_of(EventKind.REQUEST)
                  if e.request and e.request.origin is Origin.RECOVERY}
    assert len(recoveries) == 3 and all(r.done and not r.succeeded for r in recoveries.values())
    # Given up: no more attempts, and the divergence is an error the tree can see, with the reason.
    rig.run(120.0)
    assert len({e.request.id for e in rig.events_of(EventKind.REQUEST)
                if e.request and e.request.origin is Origin.RECOVERY}) == 3
    errors = {d.part: d for d in rig.manager.divergences(errors_only=True)}
    assert errors["laser_resender"].cause is Cause.FAULT and errors["laser_resender"].reason == failed
    assert rig.manager.failed() == ["laser_resender"]
    # The operator restarts the node: it is a new process with a whole budget, and is restored.
    rig.backend.restart("laser_resender")
    rig.run_until(lambda: str(rig.manager.actual("pilot")) == "active.f_normal_mode", timeout=10.0)
    assert rig.manager.failed() == []


def test_a_timed_out_request_names_the_hung_node() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.backend.hang_next("amcl", Transition.CONFIGURE)
    request = rig.finish(rig.manager.change_mode("pilot", "f_normal_mode", timeout=2.0))
    assert re.fullmatch(r"timed out after 2 s \(.*amcl hung in configuring for 2 s.*\)", request.reason), request.reason


# -- refused requests -------------------------------------------------------------------------------


def test_an_empty_mode_name_is_refused_with_the_part_named() -> None:
    rig = SimulatedSystem(bundled("pilot"))
    with pytest.raises(ValueError, match="change_mode of pilot: the mode name is empty"):
        rig.manager.change_mode("pilot", "")
    assert rig.manager.target("pilot") is None and rig.manager.requests() == []
    assert rig.finish(rig.manager.change_mode("pilot", "__DEFAULT__")).succeeded


def test_no_failure_is_caused_by_the_managers_own_calls() -> None:
    # Every ordered pair of mode changes at the same instant, on the pilot.
    modes = bundled("pilot").parts["pilot"].modes
    for first_mode in modes:
        for second_mode in modes:
            rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
            first = rig.manager.change_mode("pilot", first_mode)
            second = rig.manager.change_mode("pilot", second_mode)
            rig.run_until(lambda: first.done and second.done)  # noqa: B023 (used at once)
            assert second.succeeded, (first_mode, second_mode, second.reason)
            assert not MANAGER_CAUSED.search(first.reason), (first_mode, second_mode, first.reason)


def test_a_request_that_needs_a_vanished_node_is_refused_and_changes_nothing() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, vanish_after=0.5)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    rig.backend.crash("laser_resender")
    rig.run(1.0)
    sent = len(rig.backend.events)
    request = rig.manager.change_mode("pilot", "f_performance_mode")
    assert request.done and not request.succeeded and request.refused
    assert request.reason.startswith("laser_resender is not reachable (no answer for")
    assert request not in rig.manager.requests()
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_normal_mode")
    assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
    assert len(rig.backend.events) == sent, "no node was touched"
    # A mode that leaves the vanished node alone is still fine.
    assert rig.finish(rig.manager.change_mode("controller_server", "FAST")).succeeded
    # After it comes back, nothing of the refused request is carried out.
    rig.backend.restart("laser_resender", State.INACTIVE)
    rig.run(5.0)
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_normal_mode")
    assert not [e for e in rig.backend.events if "f_performance_mode" in str(e)]


def test_an_accepted_request_that_fails_is_not_a_refusal() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.finish(rig.manager.change_state("pilot", "configure"))
    rig.backend.fail_next("amcl", Transition.ACTIVATE)
    request = rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    assert not request.succeeded and not request.refused
    assert "amcl" in request.reason
    assert rig.manager.target("pilot") == StateMode(State.ACTIVE, "f_normal_mode"), "an accepted target stands"


# -- answers before reports (as ROS 2 may deliver them) ---------------------------------------------


def test_confirmation_waits_for_the_reports_when_answers_come_first() -> None:
    # Every answer arrives before the node's own reports of the change: the manager must neither
    # plan from the stale reported state nor take an earlier set's late echo for the current mode.
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, report_delay=0.03)
    for mode in ("f_performance_mode", "f_energy_saving_mode", "f_degraded_mode", "f_normal_mode"):
        request = rig.finish(rig.manager.change_mode("pilot", mode))
        assert request.succeeded, (mode, request.reason)
        assert str(rig.manager.actual("pilot")) == f"active.{mode}"
        for node in ("amcl", "controller_server"):
            assert rig.manager.observation(node).parameters == rig.backend.node(node).parameters, (mode, node)
    refused = [e for e in rig.backend.events if e.kind == "response" and "refused" in e.details]
    assert refused == []


def test_back_to_back_mode_sets_with_late_reports_end_in_the_last_mode() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, report_delay=0.05, parameter_delay=0.0)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    fast = rig.manager.change_mode("controller_server", "FAST")
    rig.run(0.001)  # FAST is answered; its report is still on its way
    slow = rig.manager.change_mode("controller_server", "SLOW")
    rig.finish(slow)
    assert fast.reason.startswith("preempted by") and slow.succeeded, slow.reason
    confirmed_at = len(rig.events)
    rig.run(0.2)  # every late report is in: none of them may take the confirmed mode back
    later = [str(e.actual) for e in rig.events[confirmed_at:] if e.kind is EventKind.ACTUAL
             and e.part == "controller_server"]
    assert later == [] and str(rig.manager.actual("controller_server")) == "active.SLOW"
    assert rig.backend.node("controller_server").parameters["FollowPath.max_vel_x"] == 0.1


def test_a_set_whose_report_came_under_another_request_is_not_awaited_later() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, report_delay=0.05, parameter_delay=0.0)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    first = rig.manager.change_mode("pilot", "f_performance_mode")  # sets controller_server FAST
    rig.run(0.001)  # answered; the report is on its way
    rig.manager.change_mode("laser_resender", "__DEFAULT__")  # preempts it; drives another node
    assert first.reason.startswith("preempted by")
    rig.run(0.2)
    rig.backend.set_parameter("controller_server", "FollowPath.max_vel_x", 0.7)  # somebody else
    rig.run(0.2)
    again = rig.finish(rig.manager.change_mode("controller_server", "FAST"), timeout=5.0)
    assert again.succeeded, again.reason
    assert rig.backend.node("controller_server").parameters["FollowPath.max_vel_x"] == 0.5


def test_a_set_answered_but_not_yet_reported_is_waited_for_before_judging_the_mode() -> None:
    # SLOW is answered, its report is on its way, and a request for the default mode comes: the
    # node still reports the default values, but it holds SLOW's. (Found by the property tests.)
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, report_delay=0.03)
    rig.finish(rig.manager.change_mode("controller_server", "__DEFAULT__"))
    rig.manager.change_mode("controller_server", "SLOW")
    rig.run(0.015)  # parameter_delay 0.01: answered, not reported
    back = rig.finish(rig.manager.change_mode("controller_server", "__DEFAULT__"))
    assert back.succeeded, back.reason
    rig.run(0.2)
    assert str(rig.manager.actual("controller_server")) == "active.__DEFAULT__"
    assert rig.backend.node("controller_server").parameters["FollowPath.max_vel_x"] == 0.3


def test_a_request_that_needs_a_finalized_node_is_refused_and_changes_nothing() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, initial_state={"amcl": "finalized"})
    request = rig.manager.change_mode("pilot", "f_normal_mode")
    assert request.done and request.reason == "amcl is finalized (it must be restarted)"
    assert rig.manager.target("pilot") is None
    assert not [e for e in rig.backend.events if e.kind == "request"], "no node was touched"
    # A mode that does not need amcl is fine.
    assert rig.finish(rig.manager.change_mode("controller_server", "FAST")).succeeded


# -- restarted nodes -------------------------------------------------------------------------------


def test_a_node_restarted_after_being_finalized_rejoins_its_system_instead_of_being_shut_down_again() -> None:
    """The operator's view: a node shut down, its process restarted. Before, the manager shut the
    fresh node down again within a second (its target was still finalized) and every later request
    of its system was refused ("finalized (it must be restarted)") until the manager itself was
    restarted."""
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    assert rig.finish(rig.manager.change_state("controller_server", "shutdown")).succeeded
    assert str(rig.manager.actual("controller_server")) == "finalized"
    refused = rig.manager.change_mode("pilot", "f_degraded_mode")
    assert refused.refused and refused.reason == "controller_server is finalized (it must be restarted)"
    rig.restart("controller_server")
    rig.run(0.01)
    # A new life: what pilot's target needs of it, not the finalized one.
    assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
    rig.run(5.0)
    assert str(rig.manager.actual("controller_server")) == "active.__DEFAULT__"
    assert rig.backend.node("controller_server").state is State.ACTIVE  # never shut down again
    request = rig.finish(rig.manager.change_mode("pilot", "f_degraded_mode"))
    assert request.succeeded, request.reason
    assert str(rig.manager.actual("pilot")) == "active.f_degraded_mode"


def test_a_node_restarted_too_quickly_to_be_seen_gone_starts_a_new_life_too() -> None:
    """Over ROS the graph is looked at once a second: a process stopped and started again within
    that is heard of as a state change of the old one (finalized -> unconfigured). Nothing leaves
    finalized, so that is a new process as well (found by make test on a fresh clone: recovery
    shut the new process down again)."""
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    assert rig.finish(rig.manager.change_state("controller_server", "shutdown")).succeeded
    rig.restart("controller_server", unnoticed=True)
    rig.run(0.01)
    assert rig.manager.target("controller_server") == StateMode(State.ACTIVE, "__DEFAULT__")
    rig.run(5.0)
    assert str(rig.manager.actual("controller_server")) == "active.__DEFAULT__"
    assert rig.finish(rig.manager.change_mode("pilot", "f_degraded_mode")).succeeded


def test_a_node_restarted_in_a_finalized_system_keeps_the_state_it_came_back_in() -> None:
    """When its system was shut down too, nothing asks anything of the new process but itself: its
    target is the state it came back in, and the system is reachable again once every node is back."""
    rig = SimulatedSystem(fixture("nested"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("robot", "WORK")).succeeded
    assert rig.finish(rig.manager.change_state("robot", "shutdown")).succeeded
    rig.restart("lidar")
    rig.run(5.0)
    assert rig.manager.target("lidar") == StateMode(State.UNCONFIGURED)
    assert rig.backend.node("lidar").state is State.UNCONFIGURED
    refused = rig.manager.change_mode("robot", "WORK")
    assert refused.refused and "is finalized (it must be restarted)" in refused.reason
    for node in ("drive", "arm"):
        rig.restart(node)
    request = rig.finish(rig.manager.change_mode("robot", "WORK"))
    assert request.succeeded, request.reason


def test_a_node_restarted_in_another_state_after_its_system_was_shut_down_can_be_asked_for_again() -> None:
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5)
    assert rig.finish(rig.manager.change_state("pilot", "shutdown")).succeeded
    rig.restart("amcl", "inactive")
    rig.run(2.0)
    assert rig.manager.target("amcl") == StateMode(State.INACTIVE)
    assert rig.finish(rig.manager.change_mode("amcl", "DEGRADED")).succeeded
    assert rig.events_of(EventKind.TARGET, "amcl")[-1].target == StateMode(State.ACTIVE, "DEGRADED")


def test_a_divergence_a_request_works_on_is_announced_when_it_starts_and_ends_not_per_report() -> None:
    """While a request drives pilot's four nodes, each report moves pilot's actual (and the
    divergence's reason): that shows in ACTUAL events; the divergence itself is announced when it
    starts (in flight) and when it ends, not once per node report (at 10,000 nodes that was an
    event per node for every system on the way)."""
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, transition_delay=0.05)
    request = rig.finish(rig.manager.change_state("pilot", "configure"))
    assert request.succeeded, request.reason
    divergences = rig.events_of(EventKind.DIVERGENCE, "pilot")
    assert [(e.divergence.cause if e.divergence else None) for e in divergences] == [Cause.IN_FLIGHT, None]
    assert len(rig.events_of(EventKind.ACTUAL, "pilot")) > 2  # configuring ..., then inactive
    # The record stays current for whoever asks while it lasts.
    rig.manager.change_mode("pilot", "f_normal_mode")
    rig.run(0.02)
    record = rig.manager.divergence("pilot")
    assert record is not None and record.actual == rig.manager.actual("pilot")


def test_a_request_ends_when_a_node_it_needs_vanishes_even_with_no_call_on_it() -> None:
    # amcl hangs in configure, so the request waits; meanwhile pointcloud_to_laser, already at
    # its goal with no call in flight, vanishes: the request cannot complete.
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, vanish_after=0.5)
    rig.backend.hang_next("amcl", Transition.CONFIGURE)
    request = rig.manager.change_mode("pilot", "f_normal_mode", timeout=30.0)
    rig.run(0.5)
    assert not request.done and rig.manager.observation("pointcloud_to_laser").state is State.INACTIVE
    rig.backend.crash("pointcloud_to_laser")
    took = rig.run_until(lambda: request.done, timeout=5.0)
    assert took <= 0.5 + 0.02, took
    assert not request.succeeded and not request.refused
    assert request.reason.startswith("pointcloud_to_laser is not reachable (no answer for"), request.reason
