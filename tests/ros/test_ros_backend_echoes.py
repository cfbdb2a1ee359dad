"""The ROS backend reports our own changes from the service responses and does not report their
echoes (``/parameter_events``, ``transition_event``) again, while changes by anyone else still are;
the transition state of a quick transition of ours is not reported at all, whichever of answer and
events comes first.

The bookkeeping is checked here without a ROS graph (a backend object with only its clock), so
that the orderings that are rare on a real graph can be played exactly: an echo before the
answer, a late echo of an earlier set, someone else's change between our set and its answer.
"""

from __future__ import annotations

import threading

import pytest

from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State
from sm_bt.ros.backend import RosBackend
from sm_bt.ros.dispatch import Dispatcher
from sm_bt.ros.node_events import VIA_GRACE, NodeEvents
from sm_bt.ros.peers import ECHO_WINDOW, Peer, Presence, SetInFlight, TransitionInFlight, expected_echo

pytestmark = pytest.mark.ros


class _Listener:
    def __init__(self) -> None:
        self.states: list[State] = []
        self.parameters: list[tuple[str, dict[str, object]]] = []

    def node_state(self, node: str, state: State) -> None:
        self.states.append(state)

    def node_parameters(self, node: str, changed: dict[str, object]) -> None:
        self.parameters.append((node, dict(changed)))


def _backend() -> tuple[RosBackend, Peer, _Listener, VirtualClock]:
    backend = RosBackend.__new__(RosBackend)  # the bookkeeping only: no rclpy node
    clock = VirtualClock()
    listener = _Listener()
    backend._clock = clock  # type: ignore[assignment]
    backend._listener = listener  # type: ignore[assignment]
    backend._lock = threading.Lock()
    backend._dispatcher = Dispatcher(clock)
    backend._by_fqn = {}
    backend._events = NodeEvents(backend._by_fqn, backend._lock, clock, None, backend._dispatch,  # type: ignore[arg-type]
                                 lambda: backend._listener)
    peer = Peer("amcl", "/amcl", ("alpha",), None, None, None, None, None, None, presence=Presence.PRESENT,
                 state=State.INACTIVE)
    return backend, peer, listener, clock


def _send(peer: Peer, values: dict[str, object]) -> SetInFlight:
    in_flight = SetInFlight(dict(values), {name: peer.outside.get(name, 0) for name in values})  # type: ignore[arg-type]
    peer.sets_in_flight.append(in_flight)
    return in_flight


def _answer(backend: RosBackend, peer: Peer, in_flight: SetInFlight) -> dict[str, object]:
    peer.sets_in_flight.remove(in_flight)
    return dict(backend._confirmed_set(peer, in_flight))


def test_late_echoes_of_two_confirmed_sets_are_not_reported() -> None:
    backend, peer, _, clock = _backend()
    first, second = _send(peer, {"alpha": 0.1}), _send(peer, {"alpha": 0.2})
    assert _answer(backend, peer, first) == {"alpha": 0.1}
    assert _answer(backend, peer, second) == {"alpha": 0.2}
    # The first set's echo arrives after the second was confirmed: it must not undo it.
    assert backend._events._not_ours(peer, {"alpha": 0.1}, clock.now()) == {}
    assert backend._events._not_ours(peer, {"alpha": 0.2}, clock.now()) == {}
    # Nothing is expected any more: the same value again is someone else's change.
    assert backend._events._not_ours(peer, {"alpha": 0.2}, clock.now()) == {"alpha": 0.2}


def test_an_echo_before_the_answer_is_not_expected_again() -> None:
    backend, peer, _, clock = _backend()
    in_flight = _send(peer, {"alpha": 0.3})
    assert backend._events._not_ours(peer, {"alpha": 0.3}, clock.now()) == {}  # reported with the answer
    assert _answer(backend, peer, in_flight) == {"alpha": 0.3}
    assert backend._events._not_ours(peer, {"alpha": 0.3}, clock.now()) == {"alpha": 0.3}


def test_a_change_by_someone_else_is_reported_and_wins_over_our_answer() -> None:
    backend, peer, _, clock = _backend()
    in_flight = _send(peer, {"alpha": 0.3})
    assert backend._events._not_ours(peer, {"alpha": 0.3}, clock.now()) == {}  # our echo
    assert backend._events._not_ours(peer, {"alpha": 0.9}, clock.now()) == {"alpha": 0.9}  # then another client
    assert _answer(backend, peer, in_flight) == {}  # our answer must not report 0.3 over 0.9


def test_an_echo_expected_too_long_is_forgotten() -> None:
    backend, peer, _, clock = _backend()
    _answer(backend, peer, _send(peer, {"alpha": 0.4}))
    clock.advance(ECHO_WINDOW + 0.1)
    assert backend._events._not_ours(peer, {"alpha": 0.4}, clock.now()) == {"alpha": 0.4}


def test_a_confirmed_transition_is_reported_once_and_its_events_are_not() -> None:
    backend, peer, listener, clock = _backend()
    seen = [State.ACTIVATING]  # the transition state's event came before the answer
    backend._transition_confirmed(peer, Transition.ACTIVATE, seen)
    clock.run_pending()
    assert listener.states == [State.ACTIVE] and peer.state is State.ACTIVE
    assert [state for state, _ in peer.state_echoes] == [State.ACTIVE]  # only the goal's event is to come
    assert expected_echo(peer.state_echoes, State.ACTIVE, clock.now())
    assert not expected_echo(peer.state_echoes, State.ACTIVATING, clock.now())  # anything later is news


def test_the_dispatcher_runs_a_burst_in_order_in_one_clock_callback_and_survives_a_bad_action() -> None:
    clock = VirtualClock()
    dispatcher = Dispatcher(clock)
    ran: list[int] = []

    def bad() -> None:
        raise RuntimeError("a listener bug")

    for action in (lambda: ran.append(1), bad, lambda: ran.append(2)):
        dispatcher.put(action)
    assert len(clock._queue) == 1 and ran == []  # one wake for the burst, nothing run inline
    clock.run_pending()
    assert ran == [1, 2]
    dispatcher.put(lambda: ran.append(3))  # a later action schedules a new callback
    assert ran == [1, 2]
    clock.run_pending()
    assert ran == [1, 2, 3]


def test_a_modes_parameter_request_is_built_once_and_keeps_each_values_type() -> None:
    from rcl_interfaces.msg import ParameterType

    from sm_bt.ros.requests import set_parameters_request, typed_items

    def request(values: dict[str, object]) -> object:
        return set_parameters_request(typed_items(values))  # type: ignore[arg-type]

    first = request({"speed": 1, "modes": (1, 2)})
    assert request({"speed": 1, "modes": (1, 2)}) is first, "built once per mode"
    assert request({"speed": 1, "modes": [1, 2]}) is first, "a list is the tuple it holds"
    # Equal in Python, not to a node: each gets a request of its own type.
    as_bool, as_float = request({"speed": True, "modes": (True, False)}), request({"speed": 1.0, "modes": (1, 2)})
    assert [p.value.type for p in first.parameters] == [ParameterType.PARAMETER_INTEGER,  # type: ignore[attr-defined]
                                                        ParameterType.PARAMETER_INTEGER_ARRAY]
    assert [p.value.type for p in as_bool.parameters] == [ParameterType.PARAMETER_BOOL,  # type: ignore[attr-defined]
                                                          ParameterType.PARAMETER_BOOL_ARRAY]
    assert as_float.parameters[0].value.type == ParameterType.PARAMETER_DOUBLE  # type: ignore[attr-defined]


def _activating(peer: Peer) -> None:
    """An activate of ours in flight on ``peer`` (inactive)."""
    peer.transitions_in_flight.append(TransitionInFlight(State.ACTIVE, State.ACTIVATING))


def test_the_transition_state_of_a_quick_transition_of_ours_is_not_reported() -> None:
    backend, peer, listener, clock = _backend()
    _activating(peer)
    backend._events.on_transition_event(peer, State.ACTIVATING)
    clock.advance(VIA_GRACE / 2)
    assert listener.states == [] and peer.state is State.ACTIVATING, "the backend knows; the manager waits"
    backend._events.on_transition_event(peer, State.ACTIVE)
    clock.advance(2 * VIA_GRACE)
    assert listener.states == [State.ACTIVE]
    assert backend._events._held_back == {} and backend._events._held_timer is None


def test_the_transition_state_of_a_slow_transition_of_ours_is_reported_once_it_lasts() -> None:
    backend, peer, listener, clock = _backend()
    _activating(peer)
    backend._events.on_transition_event(peer, State.ACTIVATING)
    clock.advance(VIA_GRACE)
    assert listener.states == [State.ACTIVATING]
    backend._events.on_transition_event(peer, State.ACTIVE)
    clock.run_pending()
    assert listener.states == [State.ACTIVATING, State.ACTIVE]


def test_a_transition_state_of_someone_elses_transition_is_reported_at_once() -> None:
    backend, peer, listener, clock = _backend()
    backend._events.on_transition_event(peer, State.ACTIVATING)
    clock.run_pending()
    assert listener.states == [State.ACTIVATING]


def test_parameter_events_are_read_from_their_bytes_and_other_nodes_ones_dropped_by_name() -> None:
    from rcl_interfaces.msg import ParameterEvent
    from rclpy.serialization import serialize_message

    from sm_bt.ros.parameters import to_parameters

    backend, peer, listener, clock = _backend()
    backend._by_fqn[peer.fqn] = peer

    def event(node: str, values: dict[str, object], representation: bytes = b"") -> bytes:
        raw = bytes(serialize_message(ParameterEvent(node=node, changed_parameters=to_parameters(values))))  # type: ignore[arg-type]
        return representation + raw[len(representation):]

    backend._events.on_raw_parameter_event(event("/planner", {"alpha": 0.5}))
    backend._events.on_raw_parameter_event(event("/amcl", {"alpha": 0.5, "unmodelled": 1}))
    clock.run_pending()
    assert listener.parameters == [("amcl", {"alpha": 0.5})], "someone else's change of ours, reported"
    # Bytes that are not plain CDR go the usual way: rclpy reads them, or they are dropped with a warning.
    backend._events.on_raw_parameter_event(event("/amcl", {"alpha": 0.75}, b"\x00\x07"))
    backend._events.on_raw_parameter_event(b"\x00\x07\x00\x00 not an event")
    clock.run_pending()
    assert listener.parameters[1:] == [("amcl", {"alpha": 0.75})]
