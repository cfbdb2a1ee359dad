"""Requesters, priorities and holds (``manager.hold``): a held part refuses lower-priority
requests with the holder's name, a lease that runs out frees it, the last request still wins at
the same priority; and the properties over random requesters, priorities, leases and clock steps."""

from __future__ import annotations

import itertools
from typing import Any

from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_files import bundled
from model_generator import GeneratedModel, generated_models

from sm_bt.engine.holds import DEFAULT_PRIORITY, PRIORITIES
from sm_bt.model.types import Model
from sm_bt.sim import SimulatedSystem


def pilot() -> SimulatedSystem:
    system = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="tree"))
    return system


def test_a_held_part_refuses_a_lower_priority_request_naming_the_holder() -> None:
    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="rule")
    system.finish(hold.request)
    system.run(3.2)
    refused = system.manager.change_mode("pilot", "f_normal_mode", requester="tree")
    assert refused.refused
    assert refused.reason == "pilot is held in active.f_degraded_mode by rule (priority 100) since 3.4 s"
    below = system.manager.change_mode("amcl", "__DEFAULT__", requester="tree")  # a node the hold needs
    assert below.reason == ("amcl (a part of pilot) is held in active.DEGRADED by rule (priority 100) since 3.4 s")
    agrees = system.manager.change_mode("amcl", "DEGRADED", requester="tree")  # what the hold needs anyway
    assert not agrees.refused
    assert str(system.manager.actual("pilot")) == "active.f_degraded_mode"
    assert [str(h) for h in system.manager.holds()] == [
        f"hold #{hold.id}: pilot in active.f_degraded_mode by rule (priority 100)"]


def test_the_same_or_a_higher_priority_wins_as_the_last_request_always_did() -> None:
    system = pilot()
    tree_hold = system.manager.hold("pilot", "f_slow_mode", requester="tree")
    operator = system.finish(system.manager.change_mode("pilot", "f_degraded_mode", requester="operator"))
    assert operator.succeeded and not tree_hold.active
    assert tree_hold.reason == f"superseded by request #{operator.id} (change_mode pilot f_degraded_mode) of operator"
    mine = system.manager.hold("pilot", "f_slow_mode", requester="tree")
    again = system.manager.change_mode("pilot", "f_normal_mode", requester="tree")  # equal priority
    assert not again.refused and not mine.active


def test_a_lease_that_is_not_renewed_frees_the_part_and_one_renewed_keeps_it() -> None:
    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="metacontroller", lease=2.0)
    for _ in range(5):  # renewed every second: it lasts
        system.run(1.0)
        hold.renew()
    assert hold.active and system.manager.change_mode("pilot", "f_normal_mode", requester="tree").refused
    system.run(2.0)  # not renewed: the requester died
    assert not hold.active and hold.reason == "its lease of 2 s ran out" and system.manager.holds() == []
    assert system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="tree")).succeeded


def test_a_hold_refused_by_a_higher_one_is_not_made_and_a_release_ends_one() -> None:
    system = pilot()
    rule = system.manager.hold("pilot", "f_degraded_mode", requester="rule")
    tree = system.manager.hold("pilot", "f_slow_mode", requester="tree")
    assert not tree.active and tree.reason.startswith("pilot is held in active.f_degraded_mode by rule")
    rule.release()
    assert not rule.active and rule.reason == "released" and system.manager.holds() == []
    assert system.manager.hold("pilot", "f_slow_mode", requester="tree", priority=DEFAULT_PRIORITY).active
    assert PRIORITIES["rule"] > PRIORITIES["operator"] > PRIORITIES["metacontroller"] > PRIORITIES["tree"]


# -- properties ------------------------------------------------------------------------------------

REQUESTERS = ("tree", "metacontroller", "operator", "rule")
#: A queued request's own timeout in the property (shorter than a run).
QUEUE_TIMEOUT = 4.0


@st.composite
def held_runs(draw: st.DrawFn) -> tuple[Model, list[tuple[Any, ...]]]:
    """A model (generated, or the pilot with its laser rule) and a sequence of holds, requests,
    releases, renewals, node faults (rules may fire and hold) and clock steps by several
    requesters at several priorities."""
    if draw(st.booleans()):
        model = bundled("pilot_rules")
    else:
        generated: GeneratedModel = draw(generated_models())
        model = generated.load()
    parts = sorted(model.parts)
    steps: list[tuple[Any, ...]] = []
    if "pilot" in model.parts and model.parts["pilot"].rules:  # in normal mode, where its rule watches
        steps += [("request", "pilot", "f_normal_mode", "tree", None, None, False), ("run", 3.0)]
    for _ in range(draw(st.integers(1, 12))):
        kind = draw(st.sampled_from(["hold", "request", "run", "release", "renew", "fault"]))
        if kind in ("hold", "request"):
            part = draw(st.sampled_from(parts))
            mode = draw(st.sampled_from(sorted(model.parts[part].modes)))
            requester = draw(st.sampled_from(REQUESTERS))
            priority = draw(st.one_of(st.none(), st.sampled_from([10, 50, 90])))
            lease = draw(st.one_of(st.none(), st.floats(0.5, 5.0))) if kind == "hold" else None
            queue = kind == "request" and draw(st.booleans())
            steps.append((kind, part, mode, requester, priority, lease, queue))
        elif kind == "run":
            steps.append((kind, draw(st.floats(0.05, 3.0))))
        elif kind == "fault":  # a node fails by itself (deactivate -> ERROR): rules may fire and hold
            steps.append((kind, draw(st.sampled_from(sorted(node.name for node in model.nodes)))))
        else:
            steps.append((kind, draw(st.integers(0, 5))))
    return model, steps


def check_holds(model: Model, steps: list[tuple[Any, ...]]) -> None:
    from sm_bt.engine.lifecycle import Outcome, Transition
    from sm_bt.model.states import State

    system = SimulatedSystem(model, recovery=False)
    manager = system.manager
    made = []
    queued = []
    for step in steps:
        if step[0] in ("hold", "request"):
            _, part, mode, requester, priority, lease, queue = step
            before = manager.holds()
            if step[0] == "hold":
                hold = manager.hold(part, mode, requester=requester, priority=priority, lease=lease)
                made.append(hold)
                request = hold.request
            else:
                request = manager.change_mode(part, mode, requester=requester, priority=priority, queue=queue,
                                              timeout=QUEUE_TIMEOUT if queue else None)
                if queue:
                    assert "is held in" not in request.reason  # it waits instead
                    queued.append((request, manager.clock.now()))
            assert request is not None
            level = priority if priority is not None else PRIORITIES.get(requester, DEFAULT_PRIORITY)
            held_higher = [h for h in before if h.priority > level and h.active]
            if "is held in" in request.reason:
                assert held_higher, "refused for a hold, but none of a higher priority was there"
            if not before:
                assert "is held in" not in request.reason  # one requester: exactly as before
        elif step[0] == "run":
            system.run(step[1])
        elif step[0] == "fault":
            if system.backend.node(step[1]).state is State.ACTIVE:
                system.backend.trigger(step[1], Transition.DEACTIVATE, Outcome.ERROR)
        elif made:
            hold = made[step[1] % len(made)]
            hold.release() if step[0] == "release" else hold.renew()
        now = manager.clock.now()
        for hold in manager.holds():
            # An active hold's part and every part below it keep the targets it holds.
            for part, target in hold.targets.items():
                assert manager.target(part) == target, (hold, part, manager.target(part), target)
            # An expired lease has freed its part by now (its timer runs on the manager's clock).
            assert hold.expires is None or hold.expires > now - 1e-9, (hold, now)
    # No request waits forever: each queued one started, or failed at its own timeout.
    system.run(QUEUE_TIMEOUT + 1.0)
    for request, asked in queued:
        assert request.done, (request, request.feedback)
        if request.reason.startswith("still held"):
            assert request.finished is not None and request.finished - asked <= QUEUE_TIMEOUT + 1e-6


@examples(200, stress=10_000)
@given(held_runs())
def test_holds_keep_their_parts_against_lower_priorities_and_leases_free_them(
        run: tuple[Model, list[tuple[Any, ...]]]) -> None:
    check_holds(*run)


def test_hold_mode_in_a_tree_renews_its_lease_every_tick_and_a_dead_tree_lets_go() -> None:
    import py_trees

    from sm_bt.behaviours import hold_mode

    system = pilot()
    work = py_trees.behaviours.Running("Pass the door")
    tree = system.tree(hold_mode("Careful", "pilot", "f_slow_mode", work, lease=1.0))
    for _ in range(20):  # 2 s of ticks: the lease of 1 s is renewed on each
        tree.tick()
        system.run(0.1)
    (held,) = system.manager.holds()
    assert held.requester == "tree" and str(held.target) == "active.f_slow_mode"
    low = system.manager.change_mode("pilot", "f_normal_mode", requester="script", priority=10)
    assert low.refused and "by tree (priority 40)" in low.reason
    system.run(1.5)  # the tree stopped ticking (its process died): the lease runs out
    assert system.manager.holds() == [] and held.reason == "its lease of 1 s ran out"
    assert system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="script",
                                                    priority=10)).succeeded


def test_hold_mode_releases_its_hold_when_the_work_ends() -> None:
    import py_trees

    from sm_bt.behaviours import hold_mode

    system = pilot()
    root = hold_mode("Careful", "pilot", "f_slow_mode", py_trees.behaviours.Success("Passed"), priority=70)
    trace = system.tick_until_done(system.tree(root), timeout=10.0)
    assert trace[-1].status.value == "SUCCESS"
    assert system.manager.holds() == []  # released, and the previous mode asked back


def test_a_metacontroller_and_a_tree_sharing_pilot_do_not_ping_pong_once_it_holds() -> None:
    """The tree asks for normal mode again and again; the metacontroller wants degraded mode.
    Asking as everyone always did, they switch the pilot back and forth; holding, it switches once."""
    import py_trees

    from sm_bt.behaviours import ChangeMode
    from sm_bt.engine.events import EventKind
    from sm_bt.trees.bt_cpp_nodes import Delay

    def switches(hold: bool) -> int:
        system = pilot()
        modes = [str(system.manager.actual("pilot"))]  # active.f_normal_mode, then every change
        system.manager.subscribe(lambda event: modes.append(str(event.actual)), part="pilot",
                                 kinds=[EventKind.ACTUAL])
        # Every half second, the tree's routine asks for normal mode.
        routine = py_trees.composites.Sequence("Routine", memory=True, children=[
            Delay("Pause", py_trees.behaviours.Success("Wait"), delay_msec=500),
            ChangeMode("Normal", "pilot", "f_normal_mode")])
        asks = py_trees.decorators.Repeat("Again", routine, num_success=-1)
        tree = system.tree(py_trees.decorators.FailureIsRunning("Keep asking", asks))
        held = None
        for _ in range(20):  # seconds
            if hold:
                if held is None:
                    held = system.manager.hold("pilot", "f_degraded_mode", requester="metacontroller", lease=2.0)
                held.renew()
            else:
                system.manager.change_mode("pilot", "f_degraded_mode", requester="metacontroller")
            for _ in range(10):
                tree.tick()
                system.run(0.1)
        shown = [mode for mode in modes if mode.startswith("active.f_")]
        return sum(1 for before, after in itertools.pairwise(shown) if before != after)

    assert switches(hold=False) >= 10  # ping-pong
    assert switches(hold=True) == 1  # normal -> degraded, and it stays


def test_who_holds_a_part_is_in_its_status_and_its_diagnostic() -> None:
    from sm_bt.ros.diagnostics import part_diagnostic

    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="metacontroller", lease=2.0)
    system.finish(hold.request)
    expires = f"{hold.expires:.1f}"
    assert system.manager.status("pilot").held_by == f"metacontroller (priority 60, until {expires} s)"
    assert system.manager.status("amcl").held_by == f"metacontroller (priority 60, until {expires} s)"  # below it
    with system.manager.lock:
        values = dict(part_diagnostic(system.manager, "amcl", None).values)
    assert values["held_by"] == f"metacontroller (priority 60, until {expires} s)"
    hold.release()
    assert system.manager.status("pilot").held_by == ""


# -- a rule's target is a hold while its condition lasts -------------------------------------------


def laser_lost() -> tuple[SimulatedSystem, Any]:
    """pilot_rules in normal mode; the laser fails as the real node does (deactivate ->
    errorprocessing -> unconfigured) and the rule degrade_from_normal sends the pilot to degraded
    mode; the rule's hold."""
    from sm_bt.engine.lifecycle import Outcome, Transition

    system = SimulatedSystem(bundled("pilot_rules"), recovery=False)
    system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="tree"))
    system.backend.trigger("laser_resender", Transition.DEACTIVATE, Outcome.ERROR)
    system.run(5.0)
    assert str(system.manager.actual("pilot")) == "active.f_degraded_mode"
    [hold] = system.manager.holds()
    return system, hold


def test_a_rule_holds_its_target_against_the_trees_routine_changes_while_its_condition_lasts() -> None:
    system, hold = laser_lost()
    assert (hold.part, str(hold.target), hold.requester, hold.priority, hold.lease) == (
        "pilot", "active.f_degraded_mode", "rule degrade_from_normal", PRIORITIES["rule"], None)
    assert system.manager.status("pilot").held_by == "rule degrade_from_normal (priority 100)"
    system.run(3.0)
    for mode in ("f_energy_saving_mode", "f_normal_mode"):  # the tree's routine: refused, nothing moves
        refused = system.manager.change_mode("pilot", mode, requester="tree")
        assert refused.refused and refused.reason.startswith(
            "pilot is held in active.f_degraded_mode by rule degrade_from_normal (priority 100) since "), refused.reason
        assert refused.reason.endswith(" s, while laser_resender is unconfigured"), refused.reason
    operator = system.manager.change_mode("pilot", "f_normal_mode", requester="operator")
    assert operator.refused  # 80 < 100
    assert str(system.manager.actual("pilot")) == "active.f_degraded_mode" and hold.active
    # Whoever knows the laser is repaired says so at the rule's priority: the last request wins.
    back = system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="tree", priority=100))
    assert back.succeeded and not hold.active and hold.reason.startswith(f"superseded by request #{back.id}")
    assert system.manager.holds() == []


def test_a_rules_hold_ends_when_its_condition_is_over() -> None:
    from sm_bt.engine.lifecycle import Transition

    system, hold = laser_lost()
    system.backend.trigger("laser_resender", Transition.CONFIGURE)  # brought up from outside
    system.run(1.0)
    assert not hold.active and hold.reason == "its condition is over: laser_resender is no longer unconfigured"
    assert system.finish(system.manager.change_mode("pilot", "f_normal_mode", requester="tree")).succeeded


def test_a_rule_does_not_fire_against_a_hold_of_a_higher_priority_and_overrides_lower_ones() -> None:
    from sm_bt.engine.lifecycle import Outcome, Transition

    for priority, fires in ((PRIORITIES["rule"] + 1, False), (PRIORITIES["operator"], True)):
        system = SimulatedSystem(bundled("pilot_rules"), recovery=False)
        held = system.manager.hold("pilot", "f_normal_mode", requester="operator", priority=priority)
        system.finish(held.request)
        system.backend.trigger("laser_resender", Transition.DEACTIVATE, Outcome.ERROR)
        system.run(5.0)
        assert (str(system.manager.actual("pilot")) == "active.f_degraded_mode") is fires
        assert held.active is not fires
        assert [h.requester for h in system.manager.holds()] == (["rule degrade_from_normal"] if fires
                                                                 else ["operator"])


# -- queue=True: waiting for a hold to end ---------------------------------------------------------


def test_a_queued_request_waits_for_the_hold_and_starts_when_it_ends() -> None:
    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="operator", lease=3.0)
    system.finish(hold.request)
    queued = system.manager.change_mode("pilot", "f_slow_mode", requester="tree", queue=True, timeout=10.0)
    assert not queued.done and not queued.refused
    assert queued.feedback.startswith("queued: pilot is held in active.f_degraded_mode by operator (priority 80)")
    system.run(2.0)
    assert not queued.done and str(system.manager.actual("pilot")) == "active.f_degraded_mode"
    system.run(2.0)  # the lease ran out: it starts, as if asked for now
    assert not hold.active and system.finish(queued).succeeded
    assert str(system.manager.actual("pilot")) == "active.f_slow_mode"


def test_a_queued_request_fails_at_its_timeout_naming_the_holder_and_can_be_cancelled() -> None:
    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="operator")
    system.finish(hold.request)
    queued = system.manager.change_mode("pilot", "f_slow_mode", requester="tree", queue=True, timeout=5.0)
    system.run(6.0)
    assert queued.done and not queued.succeeded and not queued.refused
    assert queued.reason.startswith("still held after 5 s: pilot is held in active.f_degraded_mode by operator")
    cancelled = system.manager.change_mode("pilot", "f_slow_mode", requester="tree", queue=True)
    cancelled.cancel()
    assert cancelled.done and cancelled.reason == "cancelled"
    hold.release()
    system.run(1.0)
    assert str(system.manager.actual("pilot")) == "active.f_degraded_mode"  # neither went ahead
    # Not held: a queued request starts at once, as any other.
    assert system.finish(system.manager.change_mode("pilot", "f_slow_mode", queue=True)).succeeded


def test_queued_requests_go_in_the_order_they_came_and_the_last_one_wins() -> None:
    system = pilot()
    hold = system.manager.hold("pilot", "f_degraded_mode", requester="operator")
    system.finish(hold.request)
    first = system.manager.change_mode("pilot", "f_slow_mode", requester="tree", queue=True, timeout=30.0)
    second = system.manager.change_mode("pilot", "f_performance_mode", requester="tree", queue=True, timeout=30.0)
    hold.release()
    system.run(5.0)
    assert first.done and not first.succeeded and first.reason.startswith(f"preempted by request #{second.id}")
    assert second.succeeded and str(system.manager.actual("pilot")) == "active.f_performance_mode"


def test_holds_that_agree_share_their_parts_until_the_last_one_lets_go() -> None:
    """An operator holds navigation in f_energy_saving_mode, a metacontroller holds planning (a part
    of it) in SLOW, which that mode needs too: both stand. The tree is refused while either holds,
    naming each; a need that conflicts loses to the higher priority, told which part and holder."""
    from model_files import fixture

    system = SimulatedSystem(fixture("nav2_like"), rules=False, recovery=False)
    operator = system.manager.hold("navigation", "f_energy_saving_mode", requester="operator")
    system.finish(operator.request)
    metacontroller = system.manager.hold("planning", "SLOW", requester="metacontroller")
    assert operator.active and metacontroller.active
    conflicting = system.manager.hold("planning", "FAST", requester="metacontroller")
    assert not conflicting.active and conflicting.reason.startswith(
        "planning (a part of navigation) is held in active.SLOW by operator (priority 80)")
    refused = system.manager.change_mode("planning", "NORMAL", requester="tree")
    assert "by operator (priority 80)" in refused.reason and "by metacontroller (priority 60)" in refused.reason
    operator.release()  # the metacontroller still needs planning SLOW
    refused = system.manager.change_mode("planning", "NORMAL", requester="tree")
    assert refused.refused and "by operator" not in refused.reason and "by metacontroller" in refused.reason
    assert system.manager.status("controller_server").held_by == "metacontroller (priority 60)"
    metacontroller.release()  # the last one lets go: nothing is held, nothing changed by the release
    assert system.manager.holds() == [] and str(system.manager.actual("planning")) == "active.SLOW"
    assert system.finish(system.manager.change_mode("planning", "NORMAL", requester="tree")).succeeded
