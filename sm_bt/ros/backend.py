"""RosBackend: the :class:`~sm_bt.engine.backend.Backend` protocol served by real ROS 2 nodes.

Every node part of the model is reached through its standard services: ``change_state`` and
``get_state`` (lifecycle), ``set_parameters_atomically`` and ``get_parameters``, and observed
through ``/{node}/transition_event`` and ``/parameter_events``. Works for any lifecycle node
(rclpy or rclcpp) and for plain nodes with parameters only.

What the reference manager does not do, and this backend does:

* **Live state on (re)appearance.** A node whose services show up is asked for its state and
  parameters before anything is reported; transition and parameter events that arrive meanwhile
  are applied after that report, in order.
* **Liveness.** After a crash or behind a cut network, DDS keeps showing a node for its lease
  (20 s with Fast DDS), so discovery alone cannot tell. The nodes of one process share a DDS
  participant and die together: one node per participant is probed (``get_state``, or
  ``get_parameters`` for plain nodes) ``probe_interval`` s after its last answer, and anything
  heard from any of them (an answer, a transition or parameter event) vouches for all. Silence
  for the *liveness window* means they are unreachable: ``liveness_timeout`` s on a good link
  (so a crash or a cut is reported within that long of the last word), wider where the answers
  are slow. The window adapts to the round trips actually observed (``2 x (srtt + 4 rttvar)``,
  TCP's estimator): a node behind a slow or lossy link, where reliable DDS delivery retransmits,
  is slow, not gone (:meth:`RosBackend.link` says how slow). A probe that is late (past twice
  its expected round trip, ``escalate_interval`` s at least) is backed by more, on paths of their
  own (the other nodes of the process, their other query services), one at first and twice as many
  every ``escalate_interval`` s of silence: reliable DDS delivers each reader's samples in order and
  repairs a lost one only after the writer's next heartbeat, so a lost datagram holds back its own
  path, not the others, and a link that just turned lossy still gets an answer through within the
  window while a cut gets none.
  The graph is looked at every
  ``poll_interval`` s while a node is missing, every ``idle_poll_interval`` s once all are present
  (``graph_interval`` for the services of present nodes: the costly part).
  Busy is not gone: a node in a transition (its last event says so) blocks every service of its
  process that shares its executor thread, for as long as its callback runs (seconds for Nav2's
  servers). While a node of a process is in one, the process's silence is no verdict; its
  changes are judged by ``call_timeout`` of silence instead (any answer or event of the process
  restarts it, so a change queued behind others waits while they progress), and probes answered
  late meanwhile do not widen the window. A process that never told of a transition (cut before
  our call reached it) is judged by the window, so a change in flight when the network is cut
  fails within it. A node that leaves the graph cleanly is reported at once.
* **Either path confirms.** A transition or parameter set of ours is done when its answer comes,
  or when the node's own events show it done (its goal state; every value applied), whichever is
  first: over a lossy link each path is held back by its own lost datagrams only.
* **Quick transitions are one step.** The transition state of a transition of ours (``configuring``)
  is reported only if the node is still in it ``VIA_GRACE`` s later: one that completes sooner
  goes straight to its goal, as it does when its answer comes before its events (the manager's view
  no longer depends on which of the two comes first, and a change of 20 nodes costs 20 reports fewer).
* **Timeouts everywhere.** Every call has one; a call that times out fails and is removed from
  the client, and every call in flight on a vanished node fails with the reason.
* **Safe transitions.** Requests carry the transition's id *and* label: rclpy looks the label up
  and answers ``success=false`` for one invalid in the node's state (it would crash its process on
  an invalid id); rclcpp checks the id.

Threads: rclpy calls back in its executor thread, timers run in the :class:`WallClock` thread.
Every report and ``done`` goes to the listener through one queue, so they reach the manager one at
a time, in order, and never from inside a call: what an answer or event makes is run by the
executor thread that heard it once its callback is done (a hop to another thread costs a wake-up,
up to a millisecond on a busy machine, on every change); what a call or timer makes, by the clock
(delay 0). The rclpy node must be spun by an
executor (see :mod:`sm_bt.ros.runtime`); the backend never spins it itself.
"""

from __future__ import annotations

import collections
import enum
import functools
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any

from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rcl_interfaces.msg import ParameterEvent, SetParametersResult
from rcl_interfaces.srv import GetParameters, ListParameters, SetParametersAtomically
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_parameter_events

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import Clock, TimerHandle, WallClock
from sm_bt.engine.lifecycle import STEP_OF, Transition
from sm_bt.model.states import State
from sm_bt.model.types import Model, NodePart, ParamValue
from sm_bt.ros import removable
from sm_bt.ros.cdr import goal_state_id, parameter_event_node, parameter_event_values
from sm_bt.ros.parameters import from_parameter_value, from_parameters, to_parameters

log = logging.getLogger("sm_bt.ros.backend")


class _Presence(enum.Enum):
    ABSENT = "absent"  # never seen, or vanished
    ACQUIRING = "acquiring"  # services seen; asking for its live state and parameters
    PRESENT = "present"  # reported to the listener


@dataclass(eq=False)
class _Call:
    """One request in flight on a node (finishing it twice is a no-op: see ``RosBackend._finish``)."""

    peer: _Peer
    label: str
    client: Any
    future: Any = None
    timer: TimerHandle | None = None
    on_result: Callable[[Any], None] | None = None  # gets the response
    on_failure: Callable[[str], None] | None = None  # gets the reason
    busy: bool = True  # the node may be blocked while serving it (see _Peer.working)
    finished: bool = False
    sent: float = 0.0
    probe: bool = False  # a liveness probe: its round trip is sampled


@dataclass(eq=False)
class _SetInFlight:
    """A parameter set of ours not answered yet, and the parameters whose event already came."""

    values: dict[str, ParamValue]
    outside_before: dict[str, int]
    echoed: set[str] = field(default_factory=set)
    call: _Call | None = None


@dataclass(eq=False)
class _TransitionInFlight:
    """A transition of ours not answered yet, and the states its node's events told meanwhile."""

    goal: State | None
    via: State | None = None
    seen: list[State] = field(default_factory=list)
    call: _Call | None = None


@dataclass(eq=False)
class _Peer:
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
    presence: _Presence = _Presence.ABSENT
    lifecycle: bool = True
    state: State = State.UNKNOWN
    calls: set[_Call] = field(default_factory=set)
    last_heard: float = 0.0
    probe: _Call | None = None
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
    sets_in_flight: list[_SetInFlight] = field(default_factory=list)
    transitions_in_flight: list[_TransitionInFlight] = field(default_factory=list)
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


class RosBackend:
    """The nodes of ``model``, reached through ``node`` (an rclpy node spun by an executor).

    ``call_timeout`` bounds the silence of a node's process while a state change or parameter set
    of ours is in flight (:class:`~sm_bt.ros.runtime.RosRuntime` makes it the manager's request
    timeout: a transition may run that long), ``acquire_timeout`` the
    queries made when a node (re)appears (the first call after discovery is slow), and a node
    silent for ``liveness_timeout`` s (more on a slow link) while probed every ``probe_interval`` s
    is reported vanished. A node with parameter services but no lifecycle services for ``plain_after`` s is
    a plain node. ``poll_interval`` is how often the graph is looked at.
    """

    def __init__(self, node: Node, model: Model, *, clock: WallClock | None = None, call_timeout: float = 10.0,
                 acquire_timeout: float = 2.0, probe_interval: float = 0.3, liveness_timeout: float = 0.9,
                 plain_after: float = 1.0, poll_interval: float = 0.1, idle_poll_interval: float = 1.0,
                 graph_interval: float = 1.0, escalate_interval: float = 0.05, watch_node: Node | None = None) -> None:
        self._node = node
        # The clients of discovery and liveness (get_state, get_parameters, ...) may live on a node
        # of their own, spun apart: the node of the calls that change nodes then wakes over fewer
        # entities for each answer and event (see sm_bt.ros.runtime).
        self._watch = watch_node if watch_node is not None else node
        self._model = model
        self._clock = clock if clock is not None else WallClock("sm_bt-ros-clock")
        self.call_timeout = call_timeout
        self.acquire_timeout = acquire_timeout
        self.probe_interval = probe_interval
        self.liveness_timeout = liveness_timeout
        self.escalate_interval = escalate_interval
        self.plain_after = plain_after
        self.poll_interval = poll_interval
        self.idle_poll_interval = idle_poll_interval
        self.graph_interval = graph_interval
        self._graph_checked = -graph_interval
        self._lock = threading.Lock()
        self._outbox = _Outbox(self._clock)
        self._peers: dict[str, _Peer] = {}
        self._by_fqn: dict[str, _Peer] = {}
        self._listener: BackendListener | None = None
        self._subscriptions: list[Any] = []
        self._poll_timer: TimerHandle | None = None
        # Transition states of ours not reported yet: node -> (state, its event count, due).
        self._held_back: dict[_Peer, tuple[State, int, float]] = {}
        self._held_timer: TimerHandle | None = None

    @property
    def clock(self) -> WallClock:
        return self._clock

    def link(self, node: str) -> Link:
        """How ``node`` answers now: its round trip and liveness window."""
        peer = self._peer(node)
        with self._lock:
            members = self._members(peer)
            window = self._window(members)
            # The round trip behind the window: a member probed only now and then (a backup probe)
            # still has the estimate of the link as it was.
            timed = [m for m in members if m.srtt is not None]
            slowest = max(timed, key=_estimate, default=None)
            return Link(slowest.srtt if slowest is not None else None, window, window > self.liveness_timeout + _SLACK)

    def _window(self, members: list[_Peer]) -> float:
        """The liveness window of a process, from the round trips of its probes (lock held)."""
        estimates = [ADAPT * _estimate(m) for m in members if m.srtt is not None]
        return min(max([self.liveness_timeout, *estimates]), MAX_WINDOW)

    # -- Backend protocol ---------------------------------------------------------------------------

    def attach(self, nodes: Sequence[str], listener: BackendListener) -> None:
        with self._lock:
            if self._listener is not None:
                raise RuntimeError("RosBackend is already attached")
            self._listener = listener
            for name in nodes:
                self._peers[name] = self._make_peer(name)
                self._by_fqn[self._peers[name].fqn] = self._peers[name]
            self._subscriptions.append(removable.subscription(self._node, ParameterEvent, "/parameter_events",
                                                              functools.partial(self._heard,
                                                                                self._on_raw_parameter_event),
                                                              qos_profile_parameter_events, raw=True))
        self._poll_timer = self._clock.call_later(0.0, self._poll)

    def detach(self) -> None:
        with self._lock:
            self._listener = None
            if self._poll_timer is not None:
                self._poll_timer.cancel()
            if self._held_timer is not None:
                self._held_timer.cancel()
                self._held_timer = None
            self._held_back.clear()
            calls = [call for peer in self._peers.values() for call in peer.calls]
        for call in calls:
            self._finish(call, failure="backend detached")
        with self._lock:
            for subscription in self._subscriptions:
                self._node.destroy_subscription(subscription)
            for peer in self._peers.values():
                for client in (peer.change_state, peer.set_parameters, *peer.retired):
                    self._node.destroy_client(client)
                for client in (peer.get_state, peer.get_parameters, peer.list_parameters, peer.get_transitions):
                    self._watch.destroy_client(client)
            self._subscriptions.clear()
            self._peers.clear()
            self._by_fqn.clear()

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        peer = self._peer(node)
        step = STEP_OF.get(transition)
        in_flight = _TransitionInFlight(step.goal, step.via) if step is not None else _TransitionInFlight(None)
        seen = in_flight.seen  # transition events received while the call is in flight
        with self._lock:
            refusal = self._refusal(peer)
            if refusal is None and not peer.lifecycle:
                refusal = f"node {node} has no lifecycle services (parameters only): it cannot {transition.label}"
            if refusal is None:
                events_before = peer.events
                peer.transitions_in_flight.append(in_flight)
        if refusal is not None:
            self._dispatch(lambda: done(CallResult(False, refusal)))
            return
        request = _change_state_request(transition)

        def fail(reason: str, refused: bool = False) -> None:
            self._dispatch(lambda: done(CallResult(False, reason, refused)))

        def explained(response: Any) -> None:
            # A transition that ran publishes transition events; one refused in the node's state
            # does not. The extra round trip gives events sent before the answer time to arrive.
            with self._lock:
                ran, state = peer.events != events_before, peer.state
            if ran:
                fail(f"{transition.label} of {node} failed: its on_{transition.label} callback did not succeed "
                     f"(node now {state.label})")
                return
            available = sorted({item.transition.label for item in response.available_transitions})
            fail(f"{transition.label} of {node} refused: not a transition of its state {state.label} "
                 f"(available: {', '.join(available) or 'none'})", refused=True)

        def answered(response: Any) -> None:
            with self._lock:
                _discard(peer.transitions_in_flight, in_flight)
            if response.success:
                self._transition_confirmed(peer, transition, seen)
                self._dispatch(lambda: done(CallResult(True)))
                return
            self._call(peer, peer.get_transitions, GetAvailableTransitions.Request(), "get_available_transitions",
                       self.acquire_timeout, explained,
                       lambda reason: fail(f"{transition.label} of {node} failed: the node answered success=false"),
                       busy=False)

        def unanswered(reason: str) -> None:
            with self._lock:
                _discard(peer.transitions_in_flight, in_flight)
            fail(reason)

        call = self._call(peer, peer.change_state, request, f"change_state {transition.label}", self.call_timeout,
                          answered, unanswered)
        with self._lock:
            in_flight.call = call

    def _transition_confirmed(self, peer: _Peer, transition: Transition, seen: list[State]) -> None:
        """A transition of ours succeeded: the node is in its goal now; report that at once and
        expect the events of it that have not come yet (the transition state, the goal)."""
        step = STEP_OF.get(transition)
        if step is None:
            return
        deadline = self._clock.now() + ECHO_WINDOW
        with self._lock:
            for state in (step.via, step.goal):
                if state in seen:
                    seen.remove(state)
                else:
                    peer.state_echoes.append((state, deadline))
            if peer.presence is not _Presence.PRESENT or peer.state is step.goal:
                return
            peer.state = step.goal
            listener = self._listener
        if listener is not None:
            self._dispatch(lambda: listener.node_state(peer.part, step.goal))

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        peer = self._peer(node)
        with self._lock:
            refusal = self._refusal(peer)
        try:
            request = _set_parameters_request(_typed_items(parameters))
        except TypeError as error:
            refusal = f"set_parameters on {node}: {error}"
        if refusal is not None:
            self._dispatch(lambda: done(CallResult(False, refusal)))
            return

        values = dict(parameters)
        with self._lock:
            in_flight = _SetInFlight(values, {name: peer.outside.get(name, 0) for name in values})
            peer.sets_in_flight.append(in_flight)

        def answered(response: Any) -> None:
            result = response.result
            with self._lock:
                _discard(peer.sets_in_flight, in_flight)
                if result.successful:
                    confirmed = self._confirmed_set(peer, in_flight)
                listener = self._listener
            if not result.successful:
                why = result.reason or "no reason given"
                self._dispatch(lambda: done(CallResult(False, f"set_parameters on {node} rejected: {why}")))
                return
            def confirm() -> None:  # the answer says what the node now holds
                if confirmed and listener is not None:
                    listener.node_parameters(peer.part, confirmed)
                done(CallResult(True))

            self._dispatch(confirm)

        def failed(reason: str) -> None:
            with self._lock:
                _discard(peer.sets_in_flight, in_flight)  # if it was applied after all, its event tells
            self._dispatch(lambda: done(CallResult(False, reason)))

        call = self._call(peer, peer.set_parameters, request, "set_parameters_atomically", self.call_timeout,
                          answered, failed)
        with self._lock:
            in_flight.call = call

    def _confirmed_set(self, peer: _Peer, in_flight: _SetInFlight) -> dict[str, ParamValue]:
        """A set of ours succeeded (lock held): the values to report now (not those someone else
        changed since it was sent), and the echoes still to come."""
        deadline = self._clock.now() + ECHO_WINDOW
        confirmed = {}
        for name, value in in_flight.values.items():
            if peer.outside.get(name, 0) != in_flight.outside_before[name]:
                continue  # changed by someone else meanwhile: that report stands
            confirmed[name] = value
            if name not in in_flight.echoed:
                peer.echoes.setdefault(name, collections.deque()).append((value, deadline))
        return confirmed

    # -- discovery, acquisition, liveness (clock thread) ------------------------------------------

    def _poll(self) -> None:
        now = self._clock.now()
        with self._lock:
            if self._listener is None:
                return
            peers = list(self._peers.values())
            probed = self._share_liveness(peers)
            graph = now - self._graph_checked >= self.graph_interval
            if graph:
                self._graph_checked = now
        for peer in peers:
            try:
                self._look_at(peer, now, peer in probed, graph)
            except Exception:  # one node's trouble must not stop the others being watched
                log.exception("watching %s failed", peer.fqn)
        with self._lock:
            if self._listener is not None:
                settled = all(peer.presence is _Presence.PRESENT for peer in peers)
                self._poll_timer = self._clock.call_later(
                    self.idle_poll_interval if settled else self.poll_interval, self._poll)

    @staticmethod
    def _share_liveness(peers: list[_Peer]) -> set[_Peer]:
        """Nodes of one participant live and die together (lock held): each hears what any of them
        heard, and one of them that is not busy is probed for all. Returns the ones to probe."""
        groups: dict[bytes | str, list[_Peer]] = {}
        for peer in peers:
            if peer.presence is _Presence.PRESENT:
                groups.setdefault(peer.participant or peer.fqn, []).append(peer)
        probed = set()
        for members in groups.values():
            heard = max(member.last_heard for member in members)
            asked = max(member.last_probe for member in members)
            for member in members:
                member.last_heard, member.last_asked = heard, asked
            probing = next((member for member in members if member.probe is not None), None)
            probed.add(probing or next((m for m in members if not m.busy), members[0]))
        return probed

    def _look_at(self, peer: _Peer, now: float, probed: bool, graph: bool) -> None:
        """``graph``: also ask whether a present node's services are still there."""
        present = peer.presence is _Presence.PRESENT
        lifecycle_ready = peer.get_state.service_is_ready() if graph or not present else True
        parameters_ready = peer.get_parameters.service_is_ready() if graph or not present else True
        # A lifecycle node is taken on once its transition events reach us too: a long transition
        # of ours is told from a cut by its events (see ``_Peer.working``), and an event sent
        # before its writer matched our reader is lost. A node whose events never come is taken
        # on after ``acquire_timeout`` s anyway.
        events_matched = lifecycle_ready and not present and peer.events_subscription.get_publisher_count() > 0
        if graph and present and peer.participant is None:  # its publishers may show up after it answered
            participant = self._participant_of(peer)
            with self._lock:
                peer.participant = participant
        with self._lock:
            presence = peer.presence
            if presence is _Presence.PRESENT:
                gone = not (lifecycle_ready if peer.lifecycle else parameters_ready)
                # Silent: asked since it (or a node of its process) was last heard, and no word
                # for the window (the probe chain usually tells first: this is the safety net).
                silent = (not self._working(peer) and now - peer.last_heard > self._window(self._members(peer))
                          and peer.last_asked > peer.last_heard)
                probe_due = probed and peer.probe is None and now - peer.last_probe >= self.probe_interval
            if presence is _Presence.ABSENT:
                if lifecycle_ready:
                    peer.lifecycle_since = now if peer.lifecycle_since is None else peer.lifecycle_since
                    events_matched = events_matched or now - peer.lifecycle_since >= self.acquire_timeout
                    peer.plain_since = None
                elif parameters_ready:
                    peer.plain_since = now if peer.plain_since is None else peer.plain_since
                else:
                    peer.plain_since = None
                if not lifecycle_ready:
                    peer.lifecycle_since = None
        if presence is _Presence.PRESENT:
            if gone:
                self._vanish((peer, f"node {peer.fqn} left the ROS graph"))
            elif silent:
                self._silence_verdict(peer)
            elif probe_due:
                self._probe(peer, now)
        elif presence is _Presence.ABSENT:
            if lifecycle_ready and events_matched:
                self._acquire(peer, lifecycle=True)
            elif peer.plain_since is not None and now - peer.plain_since >= self.plain_after:
                self._acquire(peer, lifecycle=False)

    def _acquire(self, peer: _Peer, *, lifecycle: bool) -> None:
        """Ask a node that showed up for its state (lifecycle nodes) and parameters, then report it."""
        with self._lock:
            peer.presence, peer.lifecycle_since = _Presence.ACQUIRING, None
            peer.buffered_state = None
            peer.buffered_parameters = {}
            events_before = peer.events
            # Back after a slow link's silence: its queries take as long as its answers do.
            timeout = max(self.acquire_timeout, self._window([peer]))

        def failed(reason: str) -> None:
            with self._lock:
                if peer.presence is _Presence.ACQUIRING:
                    peer.presence = _Presence.ABSENT
            log.debug("acquiring %s failed: %s", peer.fqn, reason)

        def got_parameters(state: State, names: list[str], response: Any) -> None:
            values = {name: value for name, message in zip(names, response.values, strict=False)
                      if (value := from_parameter_value(message)) is not None}
            with self._lock:
                if peer.presence is not _Presence.ACQUIRING or self._listener is None:
                    return
                listener = self._listener
                if peer.buffered_state is not None and peer.events != events_before:
                    state = peer.buffered_state  # it moved while we asked
                peer.presence, peer.lifecycle, peer.state, peer.gone = _Presence.PRESENT, lifecycle, state, ""
                peer.last_heard = peer.last_probe = self._clock.now()
                peer.participant = self._participant_of(peer)
                later = dict(peer.buffered_parameters)
            # DEBUG: the manager logs the node appearing (one line per event at INFO).
            log.debug("node %s appeared: %s%s", peer.fqn, state.label, "" if lifecycle else " (parameters only)")
            report = NodeReport(state, values, lifecycle)
            self._dispatch(lambda: listener.node_appeared(peer.part, report))
            self._clock.call_later(self.probe_interval, lambda: self._probe_if_due(peer))  # the liveness chain
            if later:
                self._dispatch(lambda: listener.node_parameters(peer.part, later))

        def ask_values(state: State, response: Any) -> None:
            # rclpy answers get_parameters with nothing at all when one name is undeclared: ask
            # only for the model's parameters the node has.
            declared = set(response.result.names)
            names = [name for name in peer.parameter_names if name in declared]
            request = GetParameters.Request(names=names)
            self._call(peer, peer.get_parameters, request, "get_parameters", timeout,
                       lambda answer: got_parameters(state, names, answer), failed, busy=False)

        def ask_parameters(state: State) -> None:
            request = ListParameters.Request(prefixes=[], depth=ListParameters.Request.DEPTH_RECURSIVE)
            self._call(peer, peer.list_parameters, request, "list_parameters", timeout,
                       lambda response: ask_values(state, response), failed, busy=False)

        if lifecycle:
            self._call(peer, peer.get_state, GetState.Request(), "get_state", timeout,
                       lambda response: ask_parameters(_state_of(response.current_state.id)), failed, busy=False)
        else:
            ask_parameters(State.ACTIVE)

    def _probe(self, peer: _Peer, now: float) -> None:
        with self._lock:
            peer.last_probe = now
            events_before = peer.events
            # Unanswered by the end of the window (from the last word of its process): the verdict.
            members = self._members(peer)
            heard = max(m.last_heard for m in members)
            timeout = max(heard + self._window(members) - now, self.probe_interval)
            late = max(self.escalate_interval, 2 * peer.srtt) if peer.srtt is not None else self.escalate_interval

        def answered(response: Any) -> None:
            self._clock.call_later(self.probe_interval, lambda: self._probe_if_due(peer))
            with self._lock:
                peer.probe = None
                if peer.presence is not _Presence.PRESENT or not peer.lifecycle:
                    return
                state = _state_of(response.current_state.id)
                # Only a probe that no transition event overtook, with no call of ours in flight,
                # may correct the state (a missed event); anything else may be stale.
                stale = peer.events != events_before or peer.busy or peer.settled >= now or state is peer.state
                if not stale:
                    peer.state = state
                listener = self._listener
            if not stale and listener is not None:
                log.warning("node %s is %s (its transition event was missed, or is late)", peer.fqn, state.label)
                self._dispatch(lambda: listener.node_state(peer.part, state))

        def unanswered(reason: str) -> None:
            with self._lock:
                peer.probe = None
            self._silence_verdict(peer)

        overdue = (late, lambda call: self._escalate(peer, call))
        if peer.lifecycle:
            call = self._call(peer, peer.get_state, GetState.Request(), "get_state (liveness)",
                              timeout, answered, unanswered, busy=False, probe=True, late=overdue)
        else:
            call = self._call(peer, peer.get_parameters, GetParameters.Request(names=[]), "get_parameters (liveness)",
                              timeout, answered, unanswered, busy=False, probe=True, late=overdue)
        with self._lock:
            if not call.finished:
                peer.probe = call

    def _escalate(self, peer: _Peer, probe: _Call, count: int = 1) -> None:
        """``probe`` is late: while it is, every ``escalate_interval`` s with no word from the process,
        ``count`` more probes (doubling each time) on paths of their own (see the module's doc),
        until every path has one. A link that just turned bad gets an answer through within the
        window; a cut costs a burst of small requests."""
        now = self._clock.now()
        with self._lock:
            if probe.finished or peer.presence is not _Presence.PRESENT or self._listener is None:
                return
            members = self._members(peer)
            if any(member.busy for member in members):
                return  # a change of ours in flight: its answers and events are the words to wait for
            heard = max(m.last_heard for m in members)
            deadline = heard + self._window(members)
            quiet = now - heard >= self.escalate_interval - _SLACK
            paths = self._free_paths(members)[:count] if quiet else []
        for member, client, request in paths:
            self._call(member, client, request, f"{client.srv_name} (liveness)",
                       max(deadline - now, self.escalate_interval), lambda response: None,
                       lambda reason: self._silence_verdict(peer), busy=False, probe=True)
        if deadline - now > self.escalate_interval:
            self._clock.call_later(self.escalate_interval,
                                   lambda: self._escalate(peer, probe, 2 * count if quiet else count))

    @staticmethod
    def _free_paths(members: list[_Peer]) -> list[tuple[_Peer, Any, Any]]:
        """The query services of a process with no call of ours on them (lock held): the nodes' state
        services first, then their other services."""
        paths: list[tuple[_Peer, Any, Any]] = []
        for member in members:
            if member.lifecycle:
                paths.append((member, member.get_state, GetState.Request()))
        for member in members:
            paths.append((member, member.get_parameters, GetParameters.Request(names=[])))
            if member.lifecycle:
                paths.append((member, member.get_transitions, GetAvailableTransitions.Request()))
            paths.append((member, member.list_parameters,
                          ListParameters.Request(prefixes=[_NO_SUCH_PREFIX], depth=1)))
        return [(member, client, request) for member, client, request in paths
                if not any(call.client is client and not call.finished for call in member.calls)]

    def _probe_if_due(self, peer: _Peer) -> None:
        """The next probe of a chain: one ``probe_interval`` after the last answer."""
        now = self._clock.now()
        with self._lock:
            members = self._members(peer)  # one chain per process: its answer vouches for all
            due = (self._listener is not None and peer.presence is _Presence.PRESENT
                   and all(m.probe is None for m in members)
                   and now - max(m.last_probe for m in members) >= self.probe_interval - _SLACK)
        if due:
            self._probe(peer, now)

    def _members(self, peer: _Peer) -> list[_Peer]:
        """The present nodes of ``peer``'s process, ``peer`` included (lock held)."""
        key = peer.participant or peer.fqn
        members = [p for p in self._peers.values()
                   if p.presence is _Presence.PRESENT and (p.participant or p.fqn) == key]
        return members or [peer]

    def _working(self, peer: _Peer) -> bool:
        """A node of ``peer``'s process is in a transition (lock held): with one executor thread for
        the process (rclpy's and rclcpp's default), nothing of it answers until the callback
        returns, however long it takes, so its silence is no sign of death for up to
        ``call_timeout`` s after that node's last event. A process that never told of a transition
        (a cut before our call reached it) is judged by the liveness window as before."""
        now = self._clock.now()
        return any(member.working(now, self.call_timeout) for member in self._members(peer))

    def _silence_verdict(self, peer: _Peer) -> None:
        """A probe went unanswered: its process is unreachable if nothing was heard from it for the
        window; otherwise (heard meanwhile, or busy with our transition) probe on."""
        now = self._clock.now()
        with self._lock:
            members = self._members(peer)
            heard = max(m.last_heard for m in members)
            window = self._window(members)
            working = self._working(peer)
            silent = [] if working or now - heard < window - _SLACK else \
                [m for m in members if m.presence is _Presence.PRESENT]
            again = not silent and self._listener is not None and peer.presence is _Presence.PRESENT
        # One verdict for the process, all its nodes at once: a call failed by the first one's going
        # must not judge the rest again from what is left (they were heard less recently).
        self._vanish(*[(member, f"no answer from {member.fqn} for {now - heard:.1f} s (node exited, or network "
                                "unreachable)") for member in silent])
        if again:
            self._clock.call_later(0.0 if not working else self.probe_interval, lambda: self._probe_if_due(peer))

    def _vanish(self, *verdicts: tuple[_Peer, str]) -> None:
        """Each ``(node, why)`` is gone: all marked first, then reported and their calls failed."""
        with self._lock:
            gone = [(peer, reason) for peer, reason in verdicts if peer.presence is _Presence.PRESENT]
            for peer, reason in gone:
                peer.presence, peer.state, peer.probe, peer.gone = _Presence.ABSENT, State.UNKNOWN, None, reason
            calls = [(call, peer, reason) for peer, reason in gone for call in list(peer.calls)]
            listener = self._listener
        for peer, reason in gone:
            log.debug("node %s vanished: %s", peer.fqn, reason)  # the manager logs it (WARNING)
            if listener is not None:
                self._dispatch(functools.partial(listener.node_vanished, peer.part, reason))
        for call, peer, reason in calls:
            self._finish(call, failure=f"node {peer.part} vanished: {reason}")

    # -- topics (executor thread) -------------------------------------------------------------------

    def _on_raw_transition_event(self, peer: _Peer, raw: bytes) -> None:
        goal = goal_state_id(raw)  # see sm_bt.ros.cdr: what the message would cost to build
        if goal is None:
            message = _deserialised(raw, TransitionEvent, peer.fqn)
            if message is None:
                return
            goal = message.goal_state.id
        self._on_transition_event(peer, _state_of(goal))

    def _on_transition_event(self, peer: _Peer, state: State) -> None:
        with self._lock:
            peer.events += 1
            now = peer.last_heard = peer.state_heard = self._clock.now()
            if _echo(peer.state_echoes, state, now):
                return  # a transition of ours, already reported from its answer
            for in_flight in peer.transitions_in_flight:
                in_flight.seen.append(state)
            # Our transition reached its goal: the event tells as well as the answer would (over a
            # lossy link, whichever of the two paths comes first).
            reached = [t.call for t in peer.transitions_in_flight
                       if t.goal is state and t.call is not None and not t.call.finished]
            if peer.presence is _Presence.ACQUIRING:
                peer.buffered_state = state
                return
            report = peer.presence is _Presence.PRESENT and state is not peer.state
            if report:
                peer.state = state
                if any(t.via is state for t in peer.transitions_in_flight):
                    report = False  # ours, on its way: told only if it lasts (see the module's doc)
                    self._hold_back(peer, state, now)
            listener = self._listener
        if report and listener is not None:
            self._dispatch(lambda: listener.node_state(peer.part, state))
        for call in reached:
            self._finish(call, response=ChangeState.Response(success=True))

    def _hold_back(self, peer: _Peer, state: State, now: float) -> None:
        """Report ``state`` of ``peer`` in ``VIA_GRACE`` s if nothing newer came (lock held)."""
        self._held_back[peer] = (state, peer.events, now + VIA_GRACE)
        if self._held_timer is None:
            self._held_timer = self._clock.call_later(VIA_GRACE, self._report_held_back)

    def _report_held_back(self) -> None:
        """Clock thread: the transition states held back that still hold now."""
        now = self._clock.now()
        with self._lock:
            self._held_timer = None
            due = [(peer, state) for peer, (state, events, when) in self._held_back.items()
                   if when <= now + _SLACK and peer.events == events and peer.state is state
                   and peer.presence is _Presence.PRESENT]
            self._held_back = {peer: held for peer, held in self._held_back.items()
                               if held[2] > now + _SLACK and peer.events == held[1]}
            if self._held_back:
                self._held_timer = self._clock.call_later(
                    min(held[2] for held in self._held_back.values()) - now, self._report_held_back)
            listener = self._listener
        if listener is not None:
            for peer, state in due:
                self._dispatch(functools.partial(listener.node_state, peer.part, state))

    def _on_raw_parameter_event(self, raw: bytes) -> None:
        # See sm_bt.ros.cdr: another node's event costs its name only, ours no message objects.
        node = parameter_event_node(raw)
        if node is not None and node not in self._by_fqn:
            return
        values = parameter_event_values(raw) if node is not None else None
        if node is None or values is None:  # not plain CDR: the usual way
            message = _deserialised(raw, ParameterEvent, "/parameter_events")
            if message is None:
                return
            node = message.node
            values = from_parameters(list(message.new_parameters) + list(message.changed_parameters))
        peer = self._by_fqn.get(node)
        if peer is not None:
            self._on_parameter_event(peer, values)

    def _on_parameter_event(self, peer: _Peer, values: Mapping[str, ParamValue]) -> None:
        """``values``: what an event of ``peer`` says it now holds (new and changed parameters)."""
        changed = {name: value for name, value in values.items() if name in peer.parameter_names}
        if not changed:
            return
        with self._lock:
            now = peer.last_heard = self._clock.now()
            changed = self._not_ours(peer, changed, now)
            # A set of ours whose every value came back applied: the node took it (sets are atomic).
            applied = [s.call for s in peer.sets_in_flight
                       if s.call is not None and not s.call.finished and s.echoed >= s.values.keys()]
            if changed and peer.presence is _Presence.ACQUIRING:
                peer.buffered_parameters.update(changed)
            listener = self._listener if changed and peer.presence is _Presence.PRESENT else None
        for call in applied:
            self._finish(call, response=_APPLIED)
        if listener is not None:
            self._dispatch(lambda: listener.node_parameters(peer.part, changed))

    @staticmethod
    def _not_ours(peer: _Peer, changed: dict[str, ParamValue], now: float) -> dict[str, ParamValue]:
        """The changes of a parameter event that are not echoes of our own sets (lock held)."""
        others = {}
        for name, value in changed.items():
            if _echo(peer.echoes.get(name), value, now):
                continue  # reported from the answer to our set
            mine = next((s for s in peer.sets_in_flight if name not in s.echoed and _same(s.values.get(name), value)),
                        None)
            if mine is not None:
                mine.echoed.add(name)  # our set, answered soon: reported then
                continue
            peer.outside[name] = peer.outside.get(name, 0) + 1
            others[name] = value
        return others

    # -- calls ---------------------------------------------------------------------------------------

    def _call(self, peer: _Peer, client: Any, request: Any, label: str, timeout: float,
              on_result: Callable[[Any], None], on_failure: Callable[[str], None], *, busy: bool = True,
              probe: bool = False, late: tuple[float, Callable[[_Call], None]] | None = None) -> _Call:
        """Send ``request``; ``late=(after, on_late)``: ``on_late(call)`` if unanswered ``after`` s
        (the timer of the timeout serves both: nothing more to arm for a call answered in time)."""
        call = _Call(peer, label, client, on_result=on_result, on_failure=on_failure, busy=busy,
                     sent=self._clock.now(), probe=probe)
        with self._lock:
            peer.calls.add(call)

        expire = functools.partial(self._expire, call, timeout)
        if late is not None and late[0] < timeout:
            after, on_late = late

            def overdue() -> None:
                call.timer = self._clock.call_later(timeout - after, expire)
                if not call.finished:
                    on_late(call)
            call.timer = self._clock.call_later(after, overdue)
        else:
            call.timer = self._clock.call_later(timeout, expire)
        future = client.call_async(request)
        call.future = future
        future.add_done_callback(lambda done: self._on_answer(call, done))
        return call

    def _expire(self, call: _Call, timeout: float) -> None:
        """``call``'s timeout: a change waits for as long as its process gives signs of life (see
        :meth:`_working`); a query fails ``timeout`` s after it was sent."""
        if call.finished:
            return
        if call.busy:
            with self._lock:
                heard = max([call.sent, *(member.last_heard for member in self._members(call.peer))])
            wait = heard + timeout - self._clock.now()
            if wait > _SLACK:
                call.timer = self._clock.call_later(wait, functools.partial(self._expire, call, timeout))
                return
            failure = f"{call.label} on {call.peer.part}: no answer, and no word from its process for {timeout:g} s"
        else:
            failure = f"{call.label} on {call.peer.part}: no answer within {timeout:g} s"
        self._finish(call, failure=failure)

    def _on_answer(self, call: _Call, future: Any) -> None:
        # A cancelled one calls back in the thread that cancelled it (maybe inside the manager):
        # nothing to report. Answers come from the executor.
        if not future.cancelled():
            self._heard(self._answered, call, future)

    def _answered(self, call: _Call, future: Any) -> None:
        error = future.exception()
        if error is not None:
            self._finish(call, failure=f"{call.label} on {call.peer.part} failed: {error}")
            return
        with self._lock:
            now = call.peer.last_heard = self._clock.now()
            # A quick query on a warm path: the link's (and the executor's) round trip, unless its
            # process had work of ours or a transition meanwhile (queued behind a callback, the
            # answer says nothing of the link).
            if call.probe and not any(member.busy or member.settled >= call.sent or member.state_heard >= call.sent
                                      for member in self._members(call.peer)):
                call.peer.sample(now - call.sent)
        self._finish(call, response=future.result())

    def _finish(self, call: _Call, *, response: Any = None, failure: str | None = None) -> None:
        with self._lock:
            if call.finished:
                return
            call.finished = True
            call.peer.calls.discard(call)
            if call.busy:  # its outcome is reported next (outside the lock): a probe answered meanwhile is stale
                call.peer.settled = self._clock.now()
            retired = call.client in call.peer.retired and not any(
                other.client is call.client for other in call.peer.calls)
            if retired:
                call.peer.retired.remove(call.client)
        # The call lets go of its timer, future and callbacks: each refers back to it, and a cycle
        # is left to the garbage collector (hundreds of objects per request of 20 nodes).
        timer, future, on_result, on_failure = call.timer, call.future, call.on_result, call.on_failure
        call.timer = call.future = call.on_result = call.on_failure = None
        if timer is not None:
            timer.cancel()
        if future is not None and not future.done():  # its answer, if it comes, is dropped
            call.client.remove_pending_request(future)
            if failure is not None:  # (cancelling runs its callbacks in the executor: not for a success)
                future.cancel()
                if call.busy and self._listener is not None:
                    self._renew_client(call)
        if retired:  # replaced earlier; this was the last call of ours on it
            self._node.destroy_client(call.client)
        if failure is not None:
            if on_failure is not None:
                on_failure(failure)
        elif on_result is not None:
            on_result(response)

    def _renew_client(self, call: _Call) -> None:
        """A change abandoned unanswered must never be carried out late: its request may still sit
        in the client's DDS writer, which re-sends it once the network heals. A fresh client takes
        its place; the old one (with its writer) goes once no call of ours is left on it."""
        peer, old = call.peer, call.client
        kind, attribute = ((ChangeState, "change_state") if old is peer.change_state
                           else (SetParametersAtomically, "set_parameters") if old is peer.set_parameters
                           else (None, ""))
        if kind is None:
            return  # renewed already
        with self._lock:
            fresh = self._node.create_client(kind, old.srv_name)
            setattr(peer, attribute, fresh)
            in_use = any(other.client is old and not other.finished for other in peer.calls)
            if in_use:
                peer.retired.append(old)
        if not in_use:
            self._node.destroy_client(old)
        log.debug("%s: a fresh client, the abandoned request is dropped with the old one", old.srv_name)

    # -- helpers -------------------------------------------------------------------------------------

    def _make_peer(self, part: str) -> _Peer:
        fqn = "/" + part.lstrip("/")
        spec = self._model.part(part)
        if not isinstance(spec, NodePart):
            raise ValueError(f"{part} is a system of the model, not a node")
        node, watch = self._node, self._watch
        peer = _Peer(
            part, fqn, tuple(spec.parameter_names),
            change_state=node.create_client(ChangeState, f"{fqn}/change_state"),
            get_state=watch.create_client(GetState, f"{fqn}/get_state"),
            set_parameters=node.create_client(SetParametersAtomically, f"{fqn}/set_parameters_atomically"),
            get_parameters=watch.create_client(GetParameters, f"{fqn}/get_parameters"),
            list_parameters=watch.create_client(ListParameters, f"{fqn}/list_parameters"),
            get_transitions=watch.create_client(GetAvailableTransitions, f"{fqn}/get_available_transitions"),
        )
        peer.events_subscription = removable.subscription(
            node, TransitionEvent, f"{fqn}/transition_event",
            functools.partial(self._heard, self._on_raw_transition_event, peer), QoSProfile(depth=10), raw=True)
        self._subscriptions.append(peer.events_subscription)
        return peer

    def _participant_of(self, peer: _Peer) -> bytes | None:
        """The GUID prefix of the DDS participant that publishes the node's events (its process)."""
        name = peer.fqn.rsplit("/", 1)
        namespace, node_name = (name[0] or "/"), name[1]
        try:
            for topic in (f"{peer.fqn}/transition_event", "/parameter_events"):
                publishers = self._node.get_publishers_info_by_topic(topic)
                if topic != "/parameter_events" and len(publishers) == 1:
                    # Its own topic: DDS knows the writer before the ROS graph knows which node
                    # it belongs to (the name is "_NODE_NAME_UNKNOWN_" meanwhile).
                    return bytes(publishers[0].endpoint_gid[:12])
                for info in publishers:
                    if info.node_name == node_name and info.node_namespace == namespace:
                        return bytes(info.endpoint_gid[:12])
        except Exception:  # the graph query is an optimisation: without it the node is probed alone
            log.debug("no participant known for %s", peer.fqn, exc_info=True)
        return None

    def _peer(self, node: str) -> _Peer:
        with self._lock:
            peer = self._peers.get(node)
        if peer is None:
            raise KeyError(f"node {node!r} is not attached (nodes: {', '.join(self._peers)})")
        return peer

    @staticmethod
    def _refusal(peer: _Peer) -> str | None:
        if peer.presence is _Presence.PRESENT:
            return None
        return f"node {peer.part} is not reachable ({peer.gone or 'not found on the ROS graph yet'})"

    def _dispatch(self, action: Callable[[], None]) -> None:
        """Hand a report or a ``done`` to the listener's side, in order (see the module's doc)."""
        self._outbox.put(action)

    def _heard(self, handler: Callable[..., None], *args: Any) -> None:
        """An rclpy callback: ``handler(*args)``, then what it reported, in this thread."""
        with self._outbox.held():
            handler(*args)


class _Outbox:
    """Actions for the listener's side, run in order by one thread at a time. Answers and events come
    in bursts (one per node of a change): one drain runs every action waiting.

    By default the clock drains (delay 0). Within :meth:`held` (an rclpy callback) actions only
    queue, and a thread that queued some drains when it leaves, unless another thread is draining
    already (that one takes them in turn). A thread that queued nothing leaves the others' to them:
    the watching executor's probe answers are not held back behind a burst of the backend's."""

    def __init__(self, clock: Clock) -> None:
        self._clock = clock
        self._actions: collections.deque[Callable[[], None]] = collections.deque()
        self._lock = threading.Lock()
        self._draining = False
        self._holding = _Holding()
        self._held = _Held(self)

    def put(self, action: Callable[[], None]) -> None:
        holding = self._holding
        with self._lock:
            self._actions.append(action)
            if holding.depth:
                holding.queued = True
                return
            if self._draining:
                return
            self._draining = True
        self._clock.call_later(0.0, self._drain)

    def held(self) -> _Held:
        """``with outbox.held():`` around an rclpy callback (see the class's doc)."""
        return self._held

    def _drain_unless_draining(self) -> None:
        with self._lock:
            mine = bool(self._actions) and not self._draining
            if mine:
                self._draining = True
        if mine:
            self._drain()

    def _drain(self) -> None:
        while True:
            with self._lock:
                if not self._actions:
                    self._draining = False
                    return
                action = self._actions.popleft()
            try:
                action()
            except Exception:  # one bad report must not hold back the others
                log.exception("backend report %r failed", action)


class _Holding(threading.local):
    """A thread's rclpy callbacks in progress, and whether they queued an action."""

    depth = 0
    queued = False


class _Held:
    """The context of :meth:`_Outbox.held` (one object serves every thread: its state is the
    thread's :class:`_Holding`; entered once per message, so no generator is made each time)."""

    __slots__ = ("_outbox",)

    def __init__(self, outbox: _Outbox) -> None:
        self._outbox = outbox

    def __enter__(self) -> None:
        holding = self._outbox._holding
        if not holding.depth:
            holding.queued = False
        holding.depth += 1

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        outbox = self._outbox
        holding = outbox._holding
        holding.depth -= 1
        if not holding.depth and holding.queued:
            outbox._drain_unless_draining()


_SLACK = 1e-3  # timers fire a little early or late
#: What a parameter set whose event came first is taken to have answered.
_APPLIED = SetParametersAtomically.Response(result=SetParametersResult(successful=True))
#: list_parameters asked with this prefix answers with nothing: a liveness probe, not a query.
_NO_SUCH_PREFIX = "sm_bt.liveness.none"
@functools.cache
def _change_state_request(transition: Transition) -> Any:
    """The request of ``transition``, with its id and label: one per transition, for every call
    (a request is serialised when it is sent; nothing keeps or changes it)."""
    request = ChangeState.Request()
    request.transition = TransitionMsg(id=int(transition), label=transition.label)
    return request


_TypedItems = tuple[tuple[str, ParamValue, object], ...]


def _typed_items(values: Mapping[str, ParamValue]) -> _TypedItems:
    """``values`` as a key that tells ``1``, ``1.0`` and ``True`` apart (they are equal in Python)."""
    return tuple((name, tuple(value) if isinstance(value, list) else value,
                  tuple(map(type, value)) if isinstance(value, (tuple, list)) else type(value))
                 for name, value in values.items())


@functools.lru_cache(maxsize=4096)
def _set_parameters_request(items: _TypedItems) -> Any:
    """The request that sets these values: one per node mode, as a mode's values are set again and
    again (building the messages of five values takes about 40 µs, in the thread that makes the
    calls); like the transitions' requests, it is serialised when sent and never changed."""
    return SetParametersAtomically.Request(parameters=to_parameters({name: value for name, value, _ in items}))


#: The liveness window is this many estimated round trips (``srtt + 4 rttvar``) where that is
#: more than ``liveness_timeout``; never more than MAX_WINDOW.
ADAPT = 2.0
MAX_WINDOW = 10.0

#: How long an echo of our own change is waited for; after that, an equal value is news again.
ECHO_WINDOW = 5.0
#: A transition state of a transition of ours is reported once the node stayed in it this long.
VIA_GRACE = 0.05


def _estimate(peer: _Peer) -> float:
    """The longest round trip to expect from ``peer`` (``srtt + 4 rttvar``; it has a sample)."""
    assert peer.srtt is not None
    return peer.srtt + 4 * peer.rttvar


def _same(a: object, b: object) -> bool:
    return type(a) is type(b) and a == b


def _echo(expected: collections.deque[tuple[Any, float]] | None, value: object, now: float) -> bool:
    """Is ``value`` the next expected echo (consumed if so)? Expired expectations are dropped
    first. Only the next one may match: a node publishes its events in order, and a value that is
    not the next echo is someone else's (reporting it can only tell the truth)."""
    if not expected:
        return False
    while expected and expected[0][1] < now:
        expected.popleft()
    if expected and _same(expected[0][0], value):
        expected.popleft()
        return True
    return False


def _deserialised(raw: bytes, kind: Any, source: str) -> Any:
    """``raw`` as a ``kind`` message, the usual way; None (and a warning) if it is not one."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(raw, kind)
    except Exception:  # nothing to learn from it
        log.warning("unreadable %s from %s (%d bytes) ignored", kind.__name__, source, len(raw))
        return None


def _discard(items: list[Any], item: object) -> None:
    for index, candidate in enumerate(items):
        if candidate is item:
            del items[index]
            return


def _state_of(state_id: int) -> State:
    try:
        return State(state_id)
    except ValueError:
        return State.UNKNOWN
