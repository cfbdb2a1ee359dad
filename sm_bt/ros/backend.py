"""RosBackend: the :class:`~sm_bt.engine.backend.Backend` protocol served by real ROS 2 nodes.

Every node part of the model is reached through its standard services: ``change_state`` and
``get_state`` (lifecycle), ``set_parameters_atomically`` and ``get_parameters``, and observed
through ``/{node}/transition_event`` and ``/parameter_events``. Works for any lifecycle node
(rclpy or rclcpp) and for plain nodes with parameters only.

What the reference manager does not do, and this backend does:

* **Live state on (re)appearance.** A node whose services show up is asked for its state and
  parameters before anything is reported; transition and parameter events that arrive meanwhile
  are applied after that report, in order.
* **Liveness.** A node that stops answering is reported vanished within the liveness window
  (``liveness_timeout`` s, wider on a slow link), a node busy in a long transition is not, and a
  node that leaves the graph cleanly is reported at once: :mod:`sm_bt.ros.liveness`. The graph is
  looked at every ``poll_interval`` s while a node is missing, every ``idle_poll_interval`` s once
  all are present (``graph_interval`` for the services of present nodes: the costly part).
* **Either path confirms.** A transition or parameter set of ours is done when its answer comes,
  or when the node's own events show it done (its goal state; every value applied), whichever is
  first: over a lossy link each path is held back by its own lost datagrams only. The events are
  read in :mod:`sm_bt.ros.node_events`.
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
executor thread that heard it once its callback is done (a hop to another thread would cost a
wake-up on every change); what a call or timer makes, by the clock (delay 0). The rclpy node must
be spun by an executor (see :mod:`sm_bt.ros.runtime`); the backend never spins it itself.
"""

from __future__ import annotations

import collections
import functools
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
from rcl_interfaces.msg import ParameterEvent
from rcl_interfaces.srv import GetParameters, ListParameters, SetParametersAtomically
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_parameter_events

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import WallClock
from sm_bt.engine.lifecycle import EDGE_OF, Transition
from sm_bt.model.remote_parts import MixedModel, check_fleet
from sm_bt.model.states import State
from sm_bt.model.types import Model, NodePart, ParamValue
from sm_bt.ros import removable
from sm_bt.ros.discovery import Discovery
from sm_bt.ros.dispatch import Dispatcher
from sm_bt.ros.liveness import Liveness
from sm_bt.ros.names import qualified_name
from sm_bt.ros.node_calls import NodeCalls
from sm_bt.ros.node_events import NodeEvents
from sm_bt.ros.peers import (
    ECHO_WINDOW,
    Link,
    Peer,
    Presence,
    SetInFlight,
    TransitionInFlight,
    discard,
    state_of,
)
from sm_bt.ros.requests import (
    change_state_request,
    set_parameters_request,
    typed_items,
)

log = logging.getLogger("sm_bt.ros.backend")


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
                 graph_interval: float = 1.0, escalate_interval: float = 0.05, watch_node: Node | None = None,
                 namespace: str = "/") -> None:
        if check_fleet(model):  # remote parts are other managers' systems, nothing on the graph has their name
            raise MixedModel(f"{model.path}: its nodes are remote parts: sm_bt.ros.remote_parts.RemoteBackend "
                             "drives them (RosRuntime picks it for a fleet's model)")
        #: Where the model's nodes are: ``/robot1`` makes part ``amcl`` the node ``/robot1/amcl``.
        self.namespace = namespace
        self._node = node
        # The clients of discovery and liveness (get_state, get_parameters, ...) may live on a node
        # of their own, spun apart: the node of the calls that change nodes then wakes over fewer
        # entities for each answer and event (see sm_bt.ros.runtime).
        self._watch = watch_node if watch_node is not None else node
        self._model = model
        self._clock = clock if clock is not None else WallClock("sm_bt-ros-clock")
        self.call_timeout = call_timeout
        self.acquire_timeout = acquire_timeout
        self._lock = threading.Lock()
        self._dispatcher = Dispatcher(self._clock)
        self._peers: dict[str, Peer] = {}
        self._listener: BackendListener | None = None
        self._calls = NodeCalls(node, self._lock, self._clock,
                                process_heard=lambda peer: self._liveness.last_heard(peer),
                                on_answered=lambda call, now: self._liveness.sample(call, now),
                                heard=self._heard, listening=lambda: self._listener is not None)
        self._liveness = Liveness(self._peers, self._lock, self._clock, self._calls.call, self._vanish,
                                  self._probe_found, lambda: self._listener is not None, call_timeout=call_timeout,
                                  probe_interval=probe_interval, liveness_timeout=liveness_timeout,
                                  escalate_interval=escalate_interval)
        self._discovery = Discovery(self._node, self._peers, self._lock, self._clock, self._calls, self._liveness,
                                    appeared=self._appeared, vanish=self._vanish,
                                    listening=lambda: self._listener is not None, acquire_timeout=acquire_timeout,
                                    plain_after=plain_after, poll_interval=poll_interval,
                                    idle_poll_interval=idle_poll_interval, graph_interval=graph_interval)
        self._by_fqn: dict[str, Peer] = {}
        self._subscriptions: list[Any] = []
        self._events = NodeEvents(self._by_fqn, self._lock, self._clock, self._calls, self._dispatch,
                                  lambda: self._listener)

    @property
    def clock(self) -> WallClock:
        return self._clock

    def link(self, node: str) -> Link:
        """How ``node`` answers now: its round trip and liveness window."""
        return self._liveness.link(self._peer(node))

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
                                                                                self._events.on_raw_parameter_event),
                                                              qos_profile_parameter_events, raw=True))
        self._discovery.start()

    def detach(self) -> None:
        with self._lock:
            self._listener = None
            self._discovery.stop()
            self._events.stop()
            calls = [call for peer in self._peers.values() for call in peer.calls]
        for call in calls:
            self._calls.finish(call, failure="backend detached")
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
        step = EDGE_OF.get(transition)
        in_flight = TransitionInFlight(step.goal, step.via) if step is not None else TransitionInFlight(None)
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
        request = change_state_request(transition)

        def fail(reason: str, refused: bool = False) -> None:
            self._dispatch(lambda: done(CallResult(False, reason, refused)))

        def explained(response: Any, asked_after: int) -> None:
            # A transition that ran publishes its transition state (heard while ours was in flight,
            # the extra round trip included); one refused in the node's state does not, and another
            # transition's events (a late one's) do not count.
            items = response.available_transitions
            current = state_of(items[0].start_state.id) if items else None  # what the node is in
            with self._lock:
                discard(peer.transitions_in_flight, in_flight)
                ran = step.via in seen if step is not None else peer.events != events_before
                # The node's state as it answered, unless an event told something newer since.
                told = current if peer.events == asked_after and peer.presence is Presence.PRESENT else None
                if told is not None:
                    peer.state = told
                state, listener = peer.state, self._listener
            if told is not None and listener is not None:
                # A refusal says the last report was out of date, and the manager waits for the next
                # one: this is it (the event that would have told it may never come).
                self._dispatch(functools.partial(listener.node_state, peer.part, told))
            if ran:
                fail(f"{transition.label} of {node} failed: its on_{transition.label} callback did not succeed "
                     f"(node now {state.label})")
                return
            available = sorted({item.transition.label for item in items})
            fail(f"{transition.label} of {node} refused: not a transition of its state {state.label} "
                 f"(available: {', '.join(available) or 'none'})", refused=True)

        def unexplained(reason: str) -> None:
            with self._lock:
                discard(peer.transitions_in_flight, in_flight)
            fail(f"{transition.label} of {node} failed: the node answered success=false")

        def answered(response: Any) -> None:
            if response.success:
                with self._lock:
                    discard(peer.transitions_in_flight, in_flight)
                self._transition_confirmed(peer, transition, seen)
                self._dispatch(lambda: done(CallResult(True)))
                return
            with self._lock:
                asked_after = peer.events
            self._calls.call(peer, peer.get_transitions, GetAvailableTransitions.Request(), "get_available_transitions",
                             self.acquire_timeout, functools.partial(explained, asked_after=asked_after), unexplained,
                             busy=False)

        def unanswered(reason: str) -> None:
            with self._lock:
                discard(peer.transitions_in_flight, in_flight)
            fail(reason)

        call = self._calls.call(peer, peer.change_state, request, f"change_state {transition.label}", self.call_timeout,
                                answered, unanswered)
        with self._lock:
            in_flight.call = call

    def _transition_confirmed(self, peer: Peer, transition: Transition, seen: list[State]) -> None:
        """A transition of ours succeeded: the node is in its goal now; report that at once and
        expect the events of it that have not come yet (the transition state, the goal)."""
        step = EDGE_OF.get(transition)
        if step is None:
            return
        deadline = self._clock.now() + ECHO_WINDOW
        with self._lock:
            for state in (step.via, step.goal):
                if state in seen:
                    seen.remove(state)
                else:
                    peer.state_echoes.append((state, deadline))
            if peer.presence is not Presence.PRESENT or peer.state is step.goal:
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
            request = set_parameters_request(typed_items(parameters))
        except TypeError as error:
            refusal = f"set_parameters on {node}: {error}"
        if refusal is not None:
            self._dispatch(lambda: done(CallResult(False, refusal)))
            return

        values = dict(parameters)
        with self._lock:
            in_flight = SetInFlight(values, {name: peer.outside.get(name, 0) for name in values})
            peer.sets_in_flight.append(in_flight)

        def answered(response: Any) -> None:
            result = response.result
            with self._lock:
                discard(peer.sets_in_flight, in_flight)
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
                discard(peer.sets_in_flight, in_flight)  # if it was applied after all, its event tells
            self._dispatch(lambda: done(CallResult(False, reason)))

        call = self._calls.call(peer, peer.set_parameters, request, "set_parameters_atomically", self.call_timeout,
                                answered, failed)
        with self._lock:
            in_flight.call = call

    def _confirmed_set(self, peer: Peer, in_flight: SetInFlight) -> dict[str, ParamValue]:
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

    def _appeared(self, peer: Peer, report: NodeReport, later: dict[str, ParamValue]) -> None:
        """Discovery knows ``peer``'s live state and parameters: report it, then what came since."""
        with self._lock:
            listener = self._listener
        if listener is None:
            return
        self._dispatch(lambda: listener.node_appeared(peer.part, report))
        if later:
            self._dispatch(lambda: listener.node_parameters(peer.part, later))

    def _probe_found(self, peer: Peer, state: State) -> None:
        """A probe found ``peer`` in ``state``, which no event told."""
        with self._lock:
            listener = self._listener
        if listener is not None:
            log.warning("node %s is %s (its transition event was missed, or is late)", peer.fqn, state.label)
            self._dispatch(lambda: listener.node_state(peer.part, state))

    def _vanish(self, *verdicts: tuple[Peer, str]) -> None:
        """Each ``(node, why)`` is gone: all marked first, then reported and their calls failed."""
        with self._lock:
            gone = [(peer, reason) for peer, reason in verdicts if peer.presence is Presence.PRESENT]
            for peer, reason in gone:
                peer.presence, peer.state, peer.probe, peer.gone = Presence.ABSENT, State.UNKNOWN, None, reason
            calls = [(call, peer, reason) for peer, reason in gone for call in list(peer.calls)]
            listener = self._listener
        for peer, reason in gone:
            log.debug("node %s vanished: %s", peer.fqn, reason)  # the manager logs it (WARNING)
            if listener is not None:
                self._dispatch(functools.partial(listener.node_vanished, peer.part, reason))
        for call, peer, reason in calls:
            self._calls.finish(call, failure=f"node {peer.part} vanished: {reason}")

    # -- helpers -------------------------------------------------------------------------------------

    def _make_peer(self, part: str) -> Peer:
        fqn = qualified_name(part, self.namespace)
        spec = self._model.part(part)
        if not isinstance(spec, NodePart):
            raise ValueError(f"{part} is a system of the model, not a node")
        node, watch = self._node, self._watch
        peer = Peer(
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
            functools.partial(self._heard, self._events.on_raw_transition_event, peer), QoSProfile(depth=10), raw=True)
        self._subscriptions.append(peer.events_subscription)
        return peer

    def _peer(self, node: str) -> Peer:
        with self._lock:
            peer = self._peers.get(node)
        if peer is None:
            raise KeyError(f"node {node!r} is not attached (nodes: {', '.join(self._peers)})")
        return peer

    @staticmethod
    def _refusal(peer: Peer) -> str | None:
        if peer.presence is Presence.PRESENT:
            return None
        return f"node {peer.part} is not reachable ({peer.gone or 'not found on the ROS graph yet'})"

    def _dispatch(self, action: Callable[[], None]) -> None:
        """Hand a report or a ``done`` to the listener's side, in order (see the module's doc)."""
        self._dispatcher.put(action)

    def _heard(self, handler: Callable[..., None], *args: Any) -> None:
        """An rclpy callback: ``handler(*args)``, then what it reported, in this thread."""
        with self._dispatcher.held():
            handler(*args)
