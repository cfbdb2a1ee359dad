"""Discovery: a node of the model that shows up on the ROS graph is asked for its live state and
parameters before it is reported, and one that leaves the graph is reported gone (unless this
process has just stood still itself: :data:`GRAPH_CATCH_UP`).

The graph is looked at every ``poll_interval`` s while a node is missing, every
``idle_poll_interval`` s once all are present (``graph_interval`` for the services of present
nodes: the costly part). A node with lifecycle services is taken on once its transition events
reach us too (an event sent before its writer matched our reader is lost), or after
``acquire_timeout`` s anyway; one with parameter services only, after ``plain_after`` s, as a plain
node. Transition and parameter events that arrive while it is asked are applied after the report,
in order. Each look also lets :class:`~sm_bt.ros.liveness.Liveness` probe the present nodes.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping
from typing import Any

from lifecycle_msgs.srv import GetState
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.node import Node

from sm_bt.engine.backend import NodeReport
from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue
from sm_bt.ros.liveness import Liveness, host_of
from sm_bt.ros.node_calls import NodeCalls
from sm_bt.ros.parameters import from_parameter_value
from sm_bt.ros.peers import Peer, Presence, state_of

log = logging.getLogger("sm_bt.ros.backend")

#: Seconds after this process last stood still (:attr:`~sm_bt.engine.clock.WallClock.resumed`) in
#: which a node missing from the graph is looked at again rather than taken for gone: the graph
#: catches up then (seen after a 1.8 s stop under load: every node of a process missing for 0.1 s).
GRAPH_CATCH_UP = 1.0


class Discovery:
    """Watches the graph for the nodes of ``peers`` (the backend's table, under its ``lock``):
    ``appeared(peer, report, later)`` once a node's live state and parameters are known (``later``:
    parameter events heard meanwhile), ``vanish((peer, why))`` when it leaves the graph;
    ``listening()``: the backend is attached."""

    def __init__(self, node: Node, peers: Mapping[str, Peer], lock: threading.Lock, clock: Clock, calls: NodeCalls,
                 liveness: Liveness, *, appeared: Callable[[Peer, NodeReport, dict[str, ParamValue]], None],
                 vanish: Callable[..., None], listening: Callable[[], bool], acquire_timeout: float,
                 plain_after: float, poll_interval: float, idle_poll_interval: float, graph_interval: float) -> None:
        self._node = node
        self._peers = peers
        self._lock = lock
        self._clock = clock
        self._calls = calls
        self._liveness = liveness
        self._appeared = appeared
        self._vanish = vanish
        self._listening = listening
        self.acquire_timeout = acquire_timeout
        self.plain_after = plain_after
        self.poll_interval = poll_interval
        self.idle_poll_interval = idle_poll_interval
        self.graph_interval = graph_interval
        self._graph_checked = -graph_interval
        self._timer: TimerHandle | None = None

    def start(self) -> None:
        self._timer = self._clock.call_later(0.0, self._poll)

    def stop(self) -> None:
        """Lock held (the backend detaching)."""
        if self._timer is not None:
            self._timer.cancel()

    def _poll(self) -> None:
        now = self._clock.now()
        with self._lock:
            if not self._listening():
                return
            peers = list(self._peers.values())
            probed = self._liveness.share(peers)
            graph = now - self._graph_checked >= self.graph_interval
            if graph:
                self._graph_checked = now
        # One graph query for all present nodes: `service_is_ready` walks the whole graph cache (about
        # 0.45 ms a call with 200 nodes on the graph), and two a node a look cost 18 % of a core idle.
        on_graph = self.graph_nodes() if graph else None
        if graph and self._liveness.own_host is None:
            own_host = host_of(self.own_participant())
            with self._lock:
                self._liveness.own_host = own_host
        for peer in peers:
            try:
                self._look_at(peer, now, peer in probed, on_graph)
            except Exception:  # one node's trouble must not stop the others being watched
                log.exception("watching %s failed", peer.fqn)
        with self._lock:
            if self._listening():
                settled = all(peer.presence is Presence.PRESENT for peer in peers)
                self._timer = self._clock.call_later(
                    self.idle_poll_interval if settled else self.poll_interval, self._poll)

    def graph_nodes(self) -> set[str]:
        """The fully qualified names of the nodes on the ROS graph now."""
        return {namespace.rstrip("/") + "/" + name for name, namespace in self._node.get_node_names_and_namespaces()}

    def _look_at(self, peer: Peer, now: float, probed: bool, on_graph: set[str] | None) -> None:
        """``on_graph`` (the nodes on the graph): also check that a present node is still there; a
        node that leaves the graph cleanly leaves that list with its services."""
        present = peer.presence is Presence.PRESENT
        graph = on_graph is not None
        relisted = False
        if present:
            lifecycle_ready = parameters_ready = on_graph is None or peer.fqn in on_graph
            # Taken for a node without lifecycle services, which showed up later (under load, more
            # than plain_after after its parameter services): take it on again, as a lifecycle node.
            relisted = graph and lifecycle_ready and not peer.lifecycle and peer.get_state.service_is_ready()
        else:
            lifecycle_ready = peer.get_state.service_is_ready()
            parameters_ready = peer.get_parameters.service_is_ready()
        # A lifecycle node is taken on once its transition events reach us too: a long transition
        # of ours is told from a cut by its events (see ``Peer.working``), and an event sent
        # before its writer matched our reader is lost. A node whose events never come is taken
        # on after ``acquire_timeout`` s anyway.
        events_matched = lifecycle_ready and not present and peer.events_subscription.get_publisher_count() > 0
        if graph and present and peer.participant is None:  # its publishers may show up after it answered
            participant = self.participant_of(peer)
            with self._lock:
                peer.participant = participant
                self._liveness.joined(peer)
        with self._lock:
            presence = peer.presence
            if presence is Presence.PRESENT:
                gone = not (lifecycle_ready if peer.lifecycle else parameters_ready)
                silent = self._liveness.silent(peer, now)
                probe_due = probed and self._liveness.probe_due(peer, now)
            if presence is Presence.ABSENT:
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
        if presence is Presence.PRESENT:
            if gone and now - getattr(self._clock, "resumed", float("-inf")) < GRAPH_CATCH_UP:
                log.debug("%s missing from the graph right after this process stood still: looked at again", peer.fqn)
            elif gone:
                self._vanish((peer, f"node {peer.fqn} left the ROS graph"))
            elif relisted:
                self._acquire(peer, lifecycle=True)
            elif silent:
                self._liveness.silence_verdict(peer)
            elif probe_due:
                self._liveness.probe(peer, now)
        elif presence is Presence.ABSENT:
            if lifecycle_ready and events_matched:
                self._acquire(peer, lifecycle=True)
            elif peer.plain_since is not None and now - peer.plain_since >= self.plain_after:
                self._acquire(peer, lifecycle=False)

    def _acquire(self, peer: Peer, *, lifecycle: bool) -> None:
        """Ask a node that showed up for its state (lifecycle nodes) and parameters, then report it."""
        with self._lock:
            peer.presence, peer.lifecycle_since = Presence.ACQUIRING, None
            peer.buffered_state = None
            peer.buffered_parameters = {}
            events_before = peer.events
            # Back after a slow link's silence: its queries take as long as its answers do.
            timeout = max(self.acquire_timeout, self._liveness.window([peer]))

        def failed(reason: str) -> None:
            with self._lock:
                if peer.presence is Presence.ACQUIRING:
                    peer.presence = Presence.ABSENT
            log.debug("acquiring %s failed: %s", peer.fqn, reason)

        def got_parameters(state: State, names: list[str], response: Any) -> None:
            values = {name: value for name, message in zip(names, response.values, strict=False)
                      if (value := from_parameter_value(message)) is not None}
            with self._lock:
                if peer.presence is not Presence.ACQUIRING or not self._listening():
                    return
                if peer.buffered_state is not None and peer.events != events_before:
                    state = peer.buffered_state  # it moved while we asked
                peer.presence, peer.lifecycle, peer.state, peer.gone = Presence.PRESENT, lifecycle, state, ""
                peer.last_heard = peer.last_probe = self._clock.now()
                peer.participant = self.participant_of(peer)
                self._liveness.joined(peer)
                later = dict(peer.buffered_parameters)
            # DEBUG: the manager logs the node appearing (one line per event at INFO).
            log.debug("node %s appeared: %s%s", peer.fqn, state.label, "" if lifecycle else " (parameters only)")
            self._appeared(peer, NodeReport(state, values, lifecycle), later)
            self._liveness.start(peer)

        def ask_values(state: State, response: Any) -> None:
            # rclpy answers get_parameters with nothing at all when one name is undeclared: ask
            # only for the model's parameters the node has.
            declared = set(response.result.names)
            names = [name for name in peer.parameter_names if name in declared]
            request = GetParameters.Request(names=names)
            self._calls.call(peer, peer.get_parameters, request, "get_parameters", timeout,
                             lambda answer: got_parameters(state, names, answer), failed, busy=False)

        def ask_parameters(state: State) -> None:
            request = ListParameters.Request(prefixes=[], depth=ListParameters.Request.DEPTH_RECURSIVE)
            self._calls.call(peer, peer.list_parameters, request, "list_parameters", timeout,
                             lambda response: ask_values(state, response), failed, busy=False)

        if lifecycle:
            self._calls.call(peer, peer.get_state, GetState.Request(), "get_state", timeout,
                             lambda response: ask_parameters(state_of(response.current_state.id)), failed, busy=False)
        else:
            ask_parameters(State.ACTIVE)

    def own_participant(self) -> bytes | None:
        """The GUID prefix of the manager's own participant (its node's ``/rosout`` writer)."""
        name, namespace = self._node.get_name(), self._node.get_namespace()
        try:
            for info in self._node.get_publishers_info_by_topic("/rosout"):
                if info.node_name == name and info.node_namespace == namespace:
                    return bytes(info.endpoint_gid[:12])
        except Exception:  # as participant_of: without it, no silence is taken for a common one
            log.debug("own participant not found", exc_info=True)
        return None

    def participant_of(self, peer: Peer) -> bytes | None:
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
