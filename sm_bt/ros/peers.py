"""What :class:`~sm_bt.ros.backend.RosBackend` knows of each node it manages: its presence, its
calls in flight, the changes of ours whose events are still to come, and the round trips of its
probes (the estimate behind the liveness window, :mod:`sm_bt.ros.liveness`)."""

from __future__ import annotations

import collections
import enum
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sm_bt.engine.clock import TimerHandle
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue

SLACK = 1e-3  # timers fire a little early or late
#: How long an echo of our own change is waited for; after that, an equal value is news again.
ECHO_WINDOW = 5.0


class Presence(enum.Enum):
    ABSENT = "absent"  # never seen, or vanished
    ACQUIRING = "acquiring"  # services seen; asking for its live state and parameters
    PRESENT = "present"  # reported to the listener


@dataclass(eq=False)
class NodeCall:
    """One request in flight on a node (finishing it twice is a no-op: see
    :meth:`~sm_bt.ros.node_calls.NodeCalls.finish`)."""

    peer: Peer
    label: str
    client: Any
    future: Any = None
    timer: TimerHandle | None = None
    on_result: Callable[[Any], None] | None = None  # gets the response
    on_failure: Callable[[str], None] | None = None  # gets the reason
    busy: bool = True  # the node may be blocked while serving it (see Peer.working)
    finished: bool = False
    sent: float = 0.0
    probe: bool = False  # a liveness probe: its round trip is sampled


@dataclass(eq=False)
class SetInFlight:
    """A parameter set of ours not answered yet, and the parameters whose event already came."""

    values: dict[str, ParamValue]
    outside_before: dict[str, int]
    echoed: set[str] = field(default_factory=set)
    call: NodeCall | None = None


@dataclass(eq=False)
class TransitionInFlight:
    """A transition of ours not answered yet, and the states its node's events told meanwhile."""

    goal: State | None
    via: State | None = None
    seen: list[State] = field(default_factory=list)
    call: NodeCall | None = None


@dataclass(eq=False)
class Peer:
    """What the backend knows about one node of the model."""

    part: str
    fqn: str
    parameter_names: tuple[str, ...]
    change_state: Any
    get_state: Any
    set_parameters: Any
    get_parameters: Any
    list_parameters: Any
    get_transitions: Any
    presence: Presence = Presence.ABSENT
    lifecycle: bool = True
    state: State = State.UNKNOWN
    calls: set[NodeCall] = field(default_factory=set)
    last_heard: float = 0.0
    probe: NodeCall | None = None
    last_probe: float = 0.0
    plain_since: float | None = None  # when parameter services were first seen without lifecycle ones
    lifecycle_since: float | None = None  # when lifecycle services were first seen (while absent)
    events_subscription: Any = None  # of its transition_event topic
    # Events seen while acquiring, applied after the node is reported (oldest first).
    buffered_state: State | None = None
    buffered_parameters: dict[str, ParamValue] = field(default_factory=dict)
    events: int = 0  # transition events received; tells a probe answer from a stale one
    settled: float = 0.0  # when a call of ours that may change the node last ended (ditto)
    state_heard: float = 0.0  # when the last transition event came
    gone: str = ""  # why it vanished (while absent after having been present)
    participant: bytes | None = None  # the DDS participant (process) hosting it, once known
    last_asked: float = 0.0  # the last probe of any node of its participant
    # Our own changes, reported from the service responses: the events that echo them later are
    # not reported again (an earlier set's late echo must not undo a newer confirmed value).
    echoes: dict[str, collections.deque[tuple[ParamValue, float]]] = field(default_factory=dict)
    state_echoes: collections.deque[tuple[State, float]] = field(default_factory=collections.deque)
    sets_in_flight: list[SetInFlight] = field(default_factory=list)
    transitions_in_flight: list[TransitionInFlight] = field(default_factory=list)
    outside: dict[str, int] = field(default_factory=dict)  # changes by others reported, per parameter
    # Round trips of its probes (the first calls after discovery are slow, and say nothing of the
    # link): the estimate behind the liveness window.
    srtt: float | None = None
    rttvar: float = 0.0
    retired: list[Any] = field(default_factory=list)  # clients replaced while a call was still on them

    @property
    def busy(self) -> bool:
        return any(call.busy and not call.finished for call in self.calls)

    def working(self, now: float, limit: float) -> bool:
        """In a transition, as its last event (less than ``limit`` s ago) says: its callback runs, and
        a lifecycle node's services wait meanwhile (Nav2's servers configure for seconds)."""
        return not self.state.is_primary and self.state is not State.UNKNOWN and now - self.state_heard < limit

    def sample(self, rtt: float) -> None:
        """A round trip of a quick call (RFC 6298's smoothing)."""
        if self.srtt is None:
            self.srtt, self.rttvar = rtt, rtt / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - rtt)
            self.srtt = 0.875 * self.srtt + 0.125 * rtt


@dataclass(frozen=True)
class Link:
    """How a node answers, as :meth:`RosBackend.link` reports it."""

    rtt: float | None  # smoothed round trip of its quick calls (None: none yet)
    window: float  # silence for this long means unreachable
    slow: bool  # the window is wider than on a good link


def estimate(peer: Peer) -> float:
    """The longest round trip to expect from ``peer`` (``srtt + 4 rttvar``; it has a sample)."""
    assert peer.srtt is not None
    return peer.srtt + 4 * peer.rttvar


def same_value(a: object, b: object) -> bool:
    return type(a) is type(b) and a == b


def expected_echo(expected: collections.deque[tuple[Any, float]] | None, value: object, now: float) -> bool:
    """Is ``value`` the next expected echo (consumed if so)? Expired expectations are dropped
    first. Only the next one may match: a node publishes its events in order, and a value that is
    not the next echo is someone else's (reporting it can only tell the truth)."""
    if not expected:
        return False
    while expected and expected[0][1] < now:
        expected.popleft()
    if expected and same_value(expected[0][0], value):
        expected.popleft()
        return True
    return False


def discard(items: list[Any], item: object) -> None:
    for index, candidate in enumerate(items):
        if candidate is item:
            del items[index]
            return


def state_of(state_id: int) -> State:
    try:
        return State(state_id)
    except ValueError:
        return State.UNKNOWN
