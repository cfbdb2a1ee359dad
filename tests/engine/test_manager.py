"""The mode manager over simulated nodes: confirmed changes, failures, preemption, ordering."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st
from model_files import bundled, fixture

import sm_bt
from sm_bt.engine.events import EventKind
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.sim import SimulatedSystem


@pytest.fixture
def rig() -> SimulatedSystem:
    return SimulatedSystem(bundled("actuation"), rules=False, recovery=False)


def test_change_mode_returns_at_once_and_is_confirmed(rig: SimulatedSystem) -> None:
    request = rig.manager.change_mode("actuation", "PERFORMANCE")
    assert not request.done  # nothing happens until the nodes answer
    rig.finish(request)
    assert request.succeeded, request.reason
    assert str(rig.manager.actual("actuation")) == "active.PERFORMANCE"
    assert str(rig.manager.actual("manipulator")) == "active.STRONG"
    assert str(rig.manager.actual("drive_base")) == "active.FAST"
    assert rig.backend.node("drive_base").parameters == {"max_speed": 0.9, "controller": "MPC"}


def test_lifecycle_path_is_planned_and_parameters_come_first(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    steps = [e for e in rig.backend.events if e.node == "drive_base" and e.kind in ("transition", "parameters")]
    # Parameters first (a node reads them when it configures), then configure and activate.
    assert steps[0].kind == "parameters"
    transitions = [e.transition.transition for e in steps if e.transition is not None]
    assert transitions == [Transition.CONFIGURE, Transition.ON_CONFIGURE_SUCCESS,
                           Transition.ACTIVATE, Transition.ON_ACTIVATE_SUCCESS]


def test_asking_for_the_current_mode_succeeds_at_once(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
    sent = len(rig.backend.events)
    again = rig.manager.change_mode("actuation", "MODERATE")
    assert again.done and again.succeeded
    assert len(rig.backend.events) == sent


def test_same_mode_name_in_another_state_is_not_redundant(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
    rig.finish(rig.manager.change_state("actuation", "deactivate"))
    assert str(rig.manager.actual("actuation")) == "inactive"
    again = rig.manager.change_mode("actuation", "MODERATE")
    assert not again.done
    rig.finish(again)
    assert again.succeeded and str(rig.manager.actual("actuation")) == "active.MODERATE"


def test_a_name_the_model_does_not_have_raises_with_the_closest_one_and_changes_nothing(rig: SimulatedSystem) -> None:
    """One rule for the Python API: a mistake the model alone shows raises RequestError (a
    ValueError, and an sm_bt.Error) at once, naming what the model has, closest first."""
    manager = rig.manager
    cases = [
        (lambda: manager.change_mode("actuation", "PERFORMANSE"),
         "change_mode actuation PERFORMANSE: unknown mode 'PERFORMANSE' of actuation (did you mean 'PERFORMANCE'?) "
         "(modes: MODERATE, PERFORMANCE, __DEFAULT__)"),
        (lambda: manager.change_mode("acutation", "PERFORMANCE"),
         "unknown part 'acutation' (did you mean 'actuation'?) (parts: actuation, manipulator, drive_base)"),
        (lambda: manager.change_mode("actuation", ""), "change_mode of actuation: the mode name is empty"),
        (lambda: manager.change_state("actuation", "configur"),
         "change_state actuation configur: 'configur' is not a lifecycle transition label (transitions: configure, "
         "activate, deactivate, cleanup, shutdown) (did you mean 'configure'?)"),
        (lambda: manager.change_state("actuation", 99), "change_state actuation 99: 99 is not a valid Transition"),
        (lambda: manager.change_state("actuation", Transition.ON_CONFIGURE_SUCCESS),
         "(10) cannot be requested (transitions: configure, activate, deactivate, cleanup, shutdown)"),
        (lambda: manager.change_to("actuation", "finalized"),
         "change_to actuation finalized: finalized is not a state to ask for"),
        (lambda: manager.change_to("actuation", "active.TURBO"), "unknown mode 'TURBO' of actuation"),
        (lambda: manager.change_to("actuation", "Active"), "change_to actuation Active: "),
        (lambda: manager.actual("ghost"), "unknown part 'ghost'"),
        (lambda: manager.target("ghost"), "unknown part 'ghost'"),
        (lambda: manager.divergence("ghost"), "unknown part 'ghost'"),
        (lambda: manager.available_modes("ghost"), "unknown part 'ghost'"),
        (lambda: manager.observation("actuation"),
         "actuation is a system, not a node (nodes: manipulator, drive_base)"),
    ]
    for call, says in cases:
        with pytest.raises(RequestError) as raised:
            call()
        assert str(raised.value).startswith(says) or says in str(raised.value), str(raised.value)
        assert isinstance(raised.value, ValueError) and isinstance(raised.value, sm_bt.Error)
    assert manager.requests() == [] and manager.target("actuation") is None
    assert not [e for e in rig.backend.events if e.kind == "request"], "no node was touched"


def test_what_depends_on_the_running_system_is_a_refused_request_with_the_reason(rig: SimulatedSystem) -> None:
    """The other half of the rule: valid names the system cannot take now are refused requests."""
    refused = rig.manager.change_state("actuation", "activate")  # unconfigured: activate is not valid yet
    assert refused.refused and refused.done and not refused.succeeded
    assert refused.reason == ("actuation: transition activate is not valid in state unconfigured "
                              "(valid: configure, shutdown)")
    rig.close()
    closed = rig.manager.change_mode("actuation", "PERFORMANCE")
    assert closed.refused and closed.reason == "the manager is closed"


def test_refused_transition_fails_with_the_reason(rig: SimulatedSystem) -> None:
    rig.backend.fail_next("manipulator", Transition.CONFIGURE, Outcome.FAILURE)
    request = rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    assert not request.succeeded
    assert "manipulator" in request.reason and "configure" in request.reason


def test_rejected_parameters_fail_with_the_reason(rig: SimulatedSystem) -> None:
    rig.backend.reject_parameters("drive_base", "max_speed out of range")
    request = rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    assert not request.succeeded
    assert "drive_base" in request.reason and "max_speed out of range" in request.reason


def test_vanished_node_fails_the_request(rig: SimulatedSystem) -> None:
    rig.backend.crash("manipulator")
    request = rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    assert not request.succeeded
    assert "manipulator" in request.reason
    assert rig.manager.actual("manipulator").state is State.UNKNOWN


def test_hung_transition_times_out(rig: SimulatedSystem) -> None:
    rig.backend.hang_next("drive_base", Transition.ACTIVATE)
    request = rig.manager.change_mode("actuation", "PERFORMANCE", timeout=3.0)
    took = rig.run_until(lambda: request.done)
    assert not request.succeeded
    assert "timed out after 3 s" in request.reason and "drive_base" in request.reason
    assert took == pytest.approx(3.0, abs=0.02)


def test_new_request_preempts_the_one_in_flight(rig: SimulatedSystem) -> None:
    first = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.run(0.03)
    second = rig.manager.change_mode("actuation", "MODERATE")
    assert first.done and not first.succeeded and "preempted" in first.reason
    rig.finish(second)
    assert second.succeeded
    assert str(rig.manager.actual("actuation")) == "active.MODERATE"


def test_cancel_withdraws_and_restores_the_previous_target(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
    request = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.run(0.005)
    request.cancel()
    assert request.done and request.reason == "cancelled"
    assert rig.manager.target("actuation") == StateMode(State.ACTIVE, "MODERATE")


def test_late_node_is_waited_for() -> None:
    rig = SimulatedSystem(bundled("actuation"), late={"drive_base": 2.0}, rules=False, recovery=False)
    request = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.run(1.0)
    assert not request.done and "drive_base" in request.feedback
    rig.finish(request)
    assert request.succeeded


def test_change_state_plans_paths_for_systems(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_state("actuation", "configure"))
    assert str(rig.manager.actual("manipulator")) == str(rig.manager.actual("drive_base")) == "inactive"
    request = rig.finish(rig.manager.change_state("actuation", Transition.ACTIVATE))
    assert request.succeeded
    assert str(rig.manager.actual("actuation")) == "active.__DEFAULT__"
    assert str(rig.manager.actual("manipulator")) == "inactive"  # as its default mode says
    bad = rig.manager.change_state("actuation", "cleanup")
    assert bad.done and "not valid in state active" in bad.reason
    rig.finish(rig.manager.change_state("actuation", "deactivate"))
    rig.finish(rig.manager.change_state("actuation", "cleanup"))
    assert str(rig.manager.actual("actuation")) == "unconfigured"
    rig.finish(rig.manager.change_state("actuation", "shutdown"))
    assert str(rig.manager.actual("drive_base")) == "finalized"


def test_activate_keeps_the_mode_last_asked_for(rig: SimulatedSystem) -> None:
    rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    rig.finish(rig.manager.change_state("actuation", "deactivate"))
    request = rig.finish(rig.manager.change_state("actuation", "activate"))
    assert request.succeeded and str(rig.manager.actual("actuation")) == "active.PERFORMANCE"
    again = rig.manager.change_state("actuation", "activate")
    assert again.done and again.succeeded  # already active: nothing to do, no reset to default


def test_switching_order_is_respected() -> None:
    rig = SimulatedSystem(fixture("nested"), rules=False, recovery=False)
    request = rig.finish(rig.manager.change_mode("robot", "WORK"))
    assert request.succeeded, request.reason
    assert str(rig.manager.actual("robot")) == "active.WORK" and str(rig.manager.actual("base")) == "active.PRECISE"

    def first(node: str) -> float:
        return min(e.time for e in rig.backend.events if e.node == node and e.kind == "transition")

    def last(node: str) -> float:
        return max(e.time for e in rig.backend.events if e.node == node and e.kind == "transition")

    # robot WORK: base before arm; base PRECISE: lidar before drive.
    assert last("lidar") <= first("drive")
    assert max(last("lidar"), last("drive")) <= first("arm")


def test_parallel_by_default() -> None:
    rig = SimulatedSystem(bundled("actuation"), rules=False, recovery=False)
    rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    starts = {e.node: e.time for e in reversed(rig.backend.events) if e.kind == "transition"}
    assert starts["manipulator"] == starts["drive_base"]


def test_nodes_that_answer_at_one_instant_are_settled_together(rig: SimulatedSystem) -> None:
    """The two nodes finish at one instant: the first event any observer hears already comes after
    both reports (one settle for the instant, not one per report), and nothing is lost."""
    heard: list[tuple[str, str, str]] = []

    def observe(event) -> None:  # type: ignore[no-untyped-def]
        heard.append((event.part, str(rig.manager.actual("manipulator")), str(rig.manager.actual("drive_base"))))

    request = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.manager.subscribe(observe, part=["manipulator", "drive_base"], kinds=[EventKind.ACTUAL])
    rig.finish(request)
    assert heard and heard[-1][1:] == ("active.STRONG", "active.FAST")
    firsts = {}
    for part, manipulator, drive_base in heard:
        firsts.setdefault(part, (manipulator, drive_base))
    assert firsts["manipulator"] == firsts["drive_base"]  # both had moved when either was told
    assert [part for part, *_ in heard].count("manipulator") == [part for part, *_ in heard].count("drive_base")


def test_going_down_ignores_dont_care_parts() -> None:
    rig = SimulatedSystem(fixture("nested"), rules=False, recovery=False)
    rig.finish(rig.manager.change_mode("robot", "WORK"))
    request = rig.finish(rig.manager.change_mode("robot", "PARK"))
    assert request.succeeded
    assert str(rig.manager.actual("base")) == "inactive"
    assert str(rig.manager.actual("arm")) == "active.STRONG"  # PARK leaves it as it is


def test_observers_see_requests_and_changes(rig: SimulatedSystem) -> None:
    seen = []
    subscription = rig.manager.subscribe(seen.append, part="actuation", kinds=[EventKind.ACTUAL])
    rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
    assert seen and all(e.part == "actuation" and e.kind is EventKind.ACTUAL for e in seen)
    assert str(seen[-1].actual) == "active.MODERATE"
    subscription.cancel()
    rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
    assert str(seen[-1].actual) == "active.MODERATE"
    finished = [e.message for e in rig.events_of(EventKind.REQUEST) if not e.message.endswith("started")]
    assert len(finished) == 2 and all(" succeeded in " in m for m in finished)


def test_observer_may_call_the_manager(rig: SimulatedSystem) -> None:
    def chain(event) -> None:  # type: ignore[no-untyped-def]
        if event.kind is EventKind.REQUEST and event.request and event.request.succeeded \
                and event.request.target.mode == "MODERATE":
            rig.manager.change_mode("actuation", "PERFORMANCE")

    rig.manager.subscribe(chain)
    rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
    rig.run_until(lambda: str(rig.manager.actual("actuation")) == "active.PERFORMANCE")


def test_feedback_names_the_step(rig: SimulatedSystem) -> None:
    request = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.run(0.001)
    assert "set parameters" in request.feedback or "configure" in request.feedback


def test_close_fails_what_is_in_flight_and_refuses_what_comes_after(rig: SimulatedSystem) -> None:
    """A tree still ticking after the manager was closed must not wait for ever on a request that can
    no longer end: it is refused at once, and so is a rule's or recovery's."""
    in_flight = rig.manager.change_mode("actuation", "PERFORMANCE")
    rig.run(0.001)
    rig.close()
    assert in_flight.done and not in_flight.succeeded and in_flight.reason == "the manager is closed"
    after = rig.manager.change_mode("actuation", "PERFORMANCE")
    assert after.refused and after.reason == "the manager is closed"
    assert rig.manager.change_state("actuation", "configure").refused
    assert rig.manager.change_to("actuation", "inactive").refused


def test_an_event_nobody_wants_is_not_made_and_a_filtered_observer_misses_nothing() -> None:
    """With no observer, a change makes no event at all; an observer of one part's actual gets
    exactly what an observer of everything sees of that part's actual."""
    import sm_bt.engine.events as events

    made: list[object] = []
    put, actual = events.Outbox.put, events.Outbox.actual

    def counted_put(self: events.Outbox, event: events.Event) -> None:
        made.append(event)
        put(self, event)

    def counted_actual(self: events.Outbox, event: events.Event) -> None:
        made.append(event)
        actual(self, event)

    rig = SimulatedSystem(bundled("actuation"), rules=False, recovery=False, record=False)
    events.Outbox.put, events.Outbox.actual = counted_put, counted_actual  # type: ignore[method-assign]
    try:
        rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
        assert made == []
        everything: list[events.Event] = []
        one: list[events.Event] = []
        rig.manager.subscribe(everything.append)
        subscription = rig.manager.subscribe(one.append, part="drive_base", kinds=[EventKind.ACTUAL])
        rig.finish(rig.manager.change_mode("actuation", "MODERATE"))
        assert one and one == [e for e in everything if e.part == "drive_base" and e.kind is EventKind.ACTUAL]
        subscription.cancel()
        everything.clear()
        one.clear()
        rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE"))
        assert everything and one == []
    finally:
        events.Outbox.put, events.Outbox.actual = put, actual  # type: ignore[method-assign]


def test_the_outbox_knows_which_kinds_of_which_parts_are_wanted() -> None:
    from sm_bt.engine.events import Outbox, Subscription

    def subscription(parts: set[str] | None, kinds: set[EventKind] | None) -> Subscription:
        return Subscription(lambda event: None, None if parts is None else frozenset(parts),
                            None if kinds is None else frozenset(kinds), lambda s: None)

    outbox = Outbox()
    assert not outbox.wanted(EventKind.ACTUAL, "a")
    outbox.interest([subscription({"a"}, {EventKind.ACTUAL}), subscription(None, {EventKind.REQUEST})])
    assert outbox.wanted(EventKind.ACTUAL, "a") and not outbox.wanted(EventKind.ACTUAL, "b")
    assert outbox.wanted(EventKind.REQUEST, "b") and not outbox.wanted(EventKind.TARGET, "a")
    outbox.interest([subscription({"b"}, None)])
    assert all(outbox.wanted(kind, "b") for kind in EventKind) and not outbox.wanted(EventKind.REQUEST, "a")
    outbox.interest([subscription(None, None)])
    assert all(outbox.wanted(kind, part) for kind in EventKind for part in ("a", "b", "c"))
    outbox.interest([])
    assert not any(outbox.wanted(kind, "a") for kind in EventKind)


Wish = tuple[frozenset[str] | None, frozenset[EventKind] | None]  # a subscription's parts and kinds


@given(st.lists(st.tuples(st.none() | st.frozensets(st.sampled_from("abcd"), max_size=3),
                          st.none() | st.frozensets(st.sampled_from(list(EventKind)), max_size=3)), max_size=4))
def test_the_parts_wanting_a_kind_are_those_wanted_one_by_one(wishes: list[Wish]) -> None:
    """The set a loop over many parts asks once agrees with the question asked part by part."""
    from sm_bt.engine.events import Outbox, Subscription

    outbox = Outbox()
    outbox.interest([Subscription(lambda event: None, parts, kinds, lambda s: None) for parts, kinds in wishes])
    for kind in EventKind:
        wanting = outbox.wanting(kind)
        for part in "abcde":
            assert (wanting is None or part in wanting) == outbox.wanted(kind, part), (kind, part)


def test_a_request_pauses_the_collector_while_it_starts_and_leaves_it_as_it_was(rig: SimulatedSystem) -> None:
    import gc

    seen: list[bool] = []
    rig.manager.subscribe(lambda event: seen.append(gc.isenabled()), kinds=[EventKind.TARGET])
    was = gc.isenabled()
    try:
        for enabled in (True, False):
            (gc.enable if enabled else gc.disable)()
            seen.clear()
            rig.finish(rig.manager.change_mode("actuation", "PERFORMANCE" if enabled else "__DEFAULT__"))
            rig.finish(rig.manager.change_state("actuation", "deactivate"))
            assert seen and not any(seen)  # told inside the request's entry
            assert gc.isenabled() is enabled
    finally:
        (gc.enable if was else gc.disable)()
