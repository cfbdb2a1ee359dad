"""Divergences, rules with a grace period, recovery to target, and what they must not do."""

from __future__ import annotations

from model_files import bundled, fixture

from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.engine.requests import Origin
from sm_bt.model.states import State
from sm_bt.sim import SimulatedSystem


def laser_failure(rig: SimulatedSystem) -> None:
    """laser_resender runs deactivate by itself; on_deactivate errors; it ends unconfigured."""
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE, outcome=Outcome.ERROR)


def test_pilot_rule_fires_after_the_grace_period() -> None:
    rig = SimulatedSystem(bundled("pilot_rules"), grace_period=2.0, recovery=False)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    laser_failure(rig)
    rig.run(1.0)
    assert str(rig.manager.actual("laser_resender")) == "unconfigured"
    assert not rig.events_of(EventKind.RULE)
    divergence = rig.manager.divergence("pilot")
    assert divergence is not None and divergence.cause is Cause.GRACE and not divergence.is_error
    rig.run_until(lambda: bool(rig.events_of(EventKind.RULE)), timeout=2.0)
    assert "degrade_from_normal" in rig.events_of(EventKind.RULE)[0].message
    rig.run_until(lambda: str(rig.manager.actual("pilot")) == "active.f_degraded_mode", timeout=5.0)
    assert str(rig.manager.actual("pointcloud_to_laser")) == "active.__DEFAULT__"
    assert str(rig.manager.actual("laser_resender")) == "unconfigured"
    assert str(rig.manager.actual("amcl")) == "active.DEGRADED"
    assert rig.backend.node("controller_server").parameters["FollowPath.transform_tolerance"] == 2.5
    assert rig.manager.divergences() == []


def test_rules_do_not_fire_against_a_request_in_flight() -> None:
    # The reference fires degrade_from_PERFORMANCE while the manipulator is still being
    # activated (its issue #94). Here a request in flight is never an error.
    # Slow nodes keep the manipulator inactive far beyond the grace period while it is switched.
    rig = SimulatedSystem(bundled("actuation"), grace_period=0.1, transition_delay=1.0, parameter_delay=1.0)
    assert rig.finish(rig.manager.change_mode("actuation", "__DEFAULT__")).succeeded
    request = rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    assert request.succeeded, request.reason
    assert not rig.events_of(EventKind.RULE)
    assert str(rig.manager.actual("actuation")) == "active.PERFORMANCE"


def test_rules_fire_on_a_fault_bottom_up_before_recovery() -> None:
    rig = SimulatedSystem(fixture("nested"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("robot", "WORK")).succeeded
    rig.backend.trigger("lidar", Transition.DEACTIVATE)
    rig.run_until(lambda: str(rig.manager.actual("robot")) == "active.PARK", timeout=5.0)
    assert [e.message.split(":")[0] for e in rig.events_of(EventKind.RULE)] == ["rule park_without_lidar"]
    # The rule above covers lidar: nobody tried to restore it to its old target.
    assert not [e for e in rig.events_of(EventKind.REQUEST) if e.request and e.request.origin is Origin.RECOVERY]


def test_recovery_restores_the_target_when_no_rule_matches() -> None:
    rig = SimulatedSystem(bundled("actuation"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("actuation", "__DEFAULT__")).succeeded
    rig.backend.trigger("drive_base", Transition.DEACTIVATE)
    rig.run(0.3)
    assert str(rig.manager.actual("drive_base")) == "inactive"
    rig.run_until(lambda: str(rig.manager.actual("drive_base")) == "active.__DEFAULT__", timeout=3.0)
    recoveries = [e.request for e in rig.events_of(EventKind.REQUEST)
                  if e.request and e.request.origin is Origin.RECOVERY]
    assert recoveries and recoveries[0].part == "drive_base"
    assert str(rig.manager.actual("actuation")) == "active.__DEFAULT__"


def test_recovery_is_bounded_then_the_node_is_failed() -> None:
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5, recovery_attempts=3)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded

    def keep_failing(event: Event) -> None:
        request = event.request
        if event.kind is EventKind.REQUEST and request and request.origin is Origin.RECOVERY and not request.done:
            rig.backend.fail_next("laser_resender", Transition.CONFIGURE, Outcome.FAILURE)

    rig.manager.subscribe(keep_failing)
    laser_failure(rig)
    rig.run_until(lambda: bool(rig.events_of(EventKind.FAILED)), timeout=20.0)
    recoveries = list({e.request.id: e.request for e in rig.events_of(EventKind.REQUEST)
                       if e.request and e.request.origin is Origin.RECOVERY}.values())
    assert len(recoveries) == 3 and not any(r.succeeded for r in recoveries)
    assert rig.manager.failed() == ["laser_resender"]
    assert "after 3 attempts" in rig.events_of(EventKind.FAILED)[0].message
    # Only the mode that wants laser_resender unconfigured is still reachable.
    assert rig.manager.reachable_modes("pilot") == ["f_degraded_mode"]
    rig.run(10.0)
    assert len(rig.events_of(EventKind.FAILED)) == 1  # reported once, no further attempts


def test_a_vanished_node_is_reported_not_restored_until_it_comes_back() -> None:
    rig = SimulatedSystem(bundled("actuation"), grace_period=0.5, recovery_attempts=2, vanish_after=0.5)
    assert rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE")).succeeded
    rig.backend.crash("manipulator")
    rig.run(5.0)
    assert rig.manager.actual("manipulator").state is State.UNKNOWN
    divergence = rig.manager.divergence("manipulator")
    assert divergence is not None and divergence.is_error and "no answer" in divergence.reason
    # Nothing to restore while it is gone: no attempt is spent on it.
    assert not [e for e in rig.events_of(EventKind.REQUEST) if e.request and e.request.origin is Origin.RECOVERY]
    rig.backend.restart("manipulator")
    rig.run_until(lambda: str(rig.manager.actual("actuation")) == "active.PERFORMANCE", timeout=10.0)
    assert rig.manager.failed() == [] and rig.manager.divergences() == []


def test_a_users_direct_change_is_not_fought() -> None:
    rig = SimulatedSystem(bundled("actuation"), grace_period=0.2)
    assert rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE")).succeeded
    assert rig.finish(rig.manager.change_state("manipulator", "deactivate")).succeeded
    rig.run(5.0)
    # degrade_from_PERFORMANCE would match, but the user asked for this.
    assert not rig.events_of(EventKind.RULE)
    assert str(rig.manager.actual("manipulator")) == "inactive"
    divergence = rig.manager.divergence("actuation")
    assert divergence is not None and divergence.cause is Cause.OVERRIDE


def test_divergence_events_start_and_end() -> None:
    rig = SimulatedSystem(bundled("actuation"), grace_period=0.5)
    assert rig.finish(rig.manager.change_mode("actuation", "__DEFAULT__")).succeeded
    rig.events.clear()
    rig.backend.trigger("drive_base", Transition.DEACTIVATE)
    rig.run_until(lambda: str(rig.manager.actual("drive_base")) == "active.__DEFAULT__", timeout=3.0)
    messages = [e.message for e in rig.events_of(EventKind.DIVERGENCE, "drive_base")]
    assert any("(grace)" in m for m in messages)
    assert any("(fault)" in m for m in messages)
    assert messages[-1].endswith("back on target active.__DEFAULT__")


def test_a_node_that_fails_again_after_each_recovery_runs_out_of_attempts() -> None:
    # Each recovery succeeds, then the node fails again at once (a broken sensor): the attempts
    # are counted over the recovery window, so recovery gives up instead of looping for ever.
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5, recovery_attempts=2, recovery_window=60.0)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded

    def fail_when_back(event: Event) -> None:
        if event.kind is EventKind.ACTUAL and event.part == "laser_resender" and event.actual \
                and event.actual.state is State.ACTIVE and rig.clock.now() > 0.5:
            rig.clock.call_later(0.1, lambda: laser_failure(rig))

    rig.manager.subscribe(fail_when_back)
    laser_failure(rig)
    rig.run_until(lambda: bool(rig.events_of(EventKind.FAILED)), timeout=20.0)
    recoveries = {e.request.id: e.request for e in rig.events_of(EventKind.REQUEST)
                  if e.request and e.request.origin is Origin.RECOVERY}
    assert len(recoveries) == 2 and all(r.succeeded for r in recoveries.values())
    rig.run(10.0)
    assert rig.manager.failed() == ["laser_resender"] and str(rig.manager.actual("laser_resender")) == "unconfigured"


def test_recovery_attempts_come_back_after_the_window() -> None:
    rig = SimulatedSystem(bundled("pilot"), grace_period=0.5, recovery_attempts=1, recovery_window=5.0)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    for _ in range(3):  # one failure per window: restored every time
        laser_failure(rig)
        rig.run_until(lambda: str(rig.manager.actual("laser_resender")) == "unconfigured", timeout=2.0)
        rig.run_until(lambda: str(rig.manager.actual("laser_resender")) == "active.__DEFAULT__", timeout=5.0)
        rig.run(5.0)
    assert not rig.events_of(EventKind.FAILED)
    assert len({e.request.id for e in rig.events_of(EventKind.REQUEST)
                if e.request and e.request.origin is Origin.RECOVERY}) == 3


def test_a_rule_can_react_to_losing_a_part_its_condition_unknown() -> None:
    """`if_part: [laser_resender, unknown]`: the node crashed (or its process ended), its state is
    unknown, and the rule sends the pilot where it needs no laser; when a new process of the node
    appears, the rule's hold ends with its condition."""
    from pathlib import Path

    from sm_bt.model.loader import load_model_text

    source = Path(bundled("pilot").path).read_text().replace("    modes:\n      __DEFAULT__:\n        amcl: inactive", (
        "    rules:\n      laser_lost:\n        if_target: active.f_normal_mode\n"
        "        if_part: [laser_resender, unknown]\n        new_target: active.f_degraded_mode\n"
        "    modes:\n      __DEFAULT__:\n        amcl: inactive"), 1)
    rig = SimulatedSystem(load_model_text(source, "pilot_lost.yaml"), recovery=False)
    assert rig.finish(rig.manager.change_mode("pilot", "f_normal_mode")).succeeded
    rig.crash("laser_resender")
    rig.run(5.0)
    assert [e.message for e in rig.events_of(EventKind.RULE)] == [
        "rule laser_lost: laser_resender is unknown -> active.f_degraded_mode"]
    # (Degraded mode wants the laser unconfigured: it is unknown, so the pilot's actual is too.)
    assert str(rig.manager.target("pilot")) == "active.f_degraded_mode"
    [hold] = rig.manager.holds()
    assert hold.condition is not None and str(hold.condition[1]) == "unknown"
    rig.restart("laser_resender")
    rig.run(1.0)
    assert not hold.active and hold.reason == "its condition is over: laser_resender is no longer unknown"
