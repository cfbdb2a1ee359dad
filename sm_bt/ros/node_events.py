"""What the nodes' own topics tell the ROS backend: ``transition_event`` and ``/parameter_events``.

Each event marks its node's process as heard; an event that shows a change of the manager's done
(the transition's goal state, every value of a set applied) finishes that call as its answer would
(whichever of the two paths comes first); echoes of the manager's own changes, already reported
from their answers, are dropped; what anyone else changed is reported. The transition state of a
transition of ours is held back ``VIA_GRACE`` s and reported only if the node is still in it (see
:mod:`sm_bt.ros.backend`). Messages are read from their serialised bytes where they can be
(:mod:`sm_bt.ros.cdr`).
"""

from __future__ import annotations

import functools
import threading
from collections.abc import Callable, Mapping

from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import ParameterEvent

from sm_bt.engine.backend import BackendListener
from sm_bt.engine.clock import TimerHandle, WallClock
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue
from sm_bt.ros.cdr import goal_state_id, parameter_event_node, parameter_event_values
from sm_bt.ros.node_calls import NodeCalls
from sm_bt.ros.parameters import from_parameters
from sm_bt.ros.peers import SLACK, Peer, Presence, expected_echo, same_value, state_of
from sm_bt.ros.requests import APPLIED, deserialised

#: A transition state of a transition of ours is reported once the node stayed in it this long.
VIA_GRACE = 0.05


class NodeEvents:
    """The events of the nodes in ``by_fqn`` (the backend's, by fully qualified name), under the
    backend's ``lock``; reports go to ``listener()`` through ``dispatch``, calls of ours they
    confirm are finished through ``calls``. Executor thread, except the held-back timer (clock)."""

    def __init__(self, by_fqn: Mapping[str, Peer], lock: threading.Lock, clock: WallClock, calls: NodeCalls,
                 dispatch: Callable[[Callable[[], None]], None],
                 listener: Callable[[], BackendListener | None]) -> None:
        self._by_fqn = by_fqn
        self._lock = lock
        self._clock = clock
        self._calls = calls
        self._dispatch = dispatch
        self._listener = listener
        # Transition states of ours not reported yet: node -> (state, its event count, due).
        self._held_back: dict[Peer, tuple[State, int, float]] = {}
        self._held_timer: TimerHandle | None = None

    def stop(self) -> None:
        """Nothing more to report (lock held)."""
        if self._held_timer is not None:
            self._held_timer.cancel()
            self._held_timer = None
        self._held_back.clear()

    def on_raw_transition_event(self, peer: Peer, raw: bytes) -> None:
        goal = goal_state_id(raw)  # see sm_bt.ros.cdr: what the message would cost to build
        if goal is None:
            message = deserialised(raw, TransitionEvent, peer.fqn)
            if message is None:
                return
            goal = message.goal_state.id
        self.on_transition_event(peer, state_of(goal))

    def on_transition_event(self, peer: Peer, state: State) -> None:
        with self._lock:
            peer.events += 1
            now = peer.last_heard = peer.state_heard = self._clock.now()
            if expected_echo(peer.state_echoes, state, now):
                return  # a transition of ours, already reported from its answer
            for in_flight in peer.transitions_in_flight:
                in_flight.seen.append(state)
            # Our transition reached its goal: the event tells as well as the answer would (over a
            # lossy link, whichever of the two paths comes first).
            reached = [t.call for t in peer.transitions_in_flight
                       if t.goal is state and t.call is not None and not t.call.finished]
            if peer.presence is Presence.ACQUIRING:
                peer.buffered_state = state
                return
            report = peer.presence is Presence.PRESENT and state is not peer.state
            if report:
                peer.state = state
                if any(t.via is state for t in peer.transitions_in_flight):
                    report = False  # ours, on its way: told only if it lasts (see the module's doc)
                    self._hold_back(peer, state, now)
            listener = self._listener()
        if report and listener is not None:
            self._dispatch(lambda: listener.node_state(peer.part, state))
        for call in reached:
            self._calls.finish(call, response=ChangeState.Response(success=True))

    def _hold_back(self, peer: Peer, state: State, now: float) -> None:
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
                   if when <= now + SLACK and peer.events == events and peer.state is state
                   and peer.presence is Presence.PRESENT]
            self._held_back = {peer: held for peer, held in self._held_back.items()
                               if held[2] > now + SLACK and peer.events == held[1]}
            if self._held_back:
                self._held_timer = self._clock.call_later(
                    min(held[2] for held in self._held_back.values()) - now, self._report_held_back)
            listener = self._listener()
        if listener is not None:
            for peer, state in due:
                self._dispatch(functools.partial(listener.node_state, peer.part, state))

    def on_raw_parameter_event(self, raw: bytes) -> None:
        # See sm_bt.ros.cdr: another node's event costs its name only, ours no message objects.
        node = parameter_event_node(raw)
        if node is not None and node not in self._by_fqn:
            return
        values = parameter_event_values(raw) if node is not None else None
        if node is None or values is None:  # not plain CDR: the usual way
            message = deserialised(raw, ParameterEvent, "/parameter_events")
            if message is None:
                return
            node = message.node
            values = from_parameters(list(message.new_parameters) + list(message.changed_parameters))
        peer = self._by_fqn.get(node)
        if peer is not None:
            self.on_parameter_event(peer, values)

    def on_parameter_event(self, peer: Peer, values: Mapping[str, ParamValue]) -> None:
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
            if changed and peer.presence is Presence.ACQUIRING:
                peer.buffered_parameters.update(changed)
            listener = self._listener() if changed and peer.presence is Presence.PRESENT else None
        for call in applied:
            self._calls.finish(call, response=APPLIED)
        if listener is not None:
            self._dispatch(lambda: listener.node_parameters(peer.part, changed))

    @staticmethod
    def _not_ours(peer: Peer, changed: dict[str, ParamValue], now: float) -> dict[str, ParamValue]:
        """The changes of a parameter event that are not echoes of our own sets (lock held)."""
        others = {}
        for name, value in changed.items():
            if expected_echo(peer.echoes.get(name), value, now):
                continue  # reported from the answer to our set
            mine = next((s for s in peer.sets_in_flight
                         if name not in s.echoed and same_value(s.values.get(name), value)), None)
            if mine is not None:
                mine.echoed.add(name)  # our set, answered soon: reported then
                continue
            peer.outside[name] = peer.outside.get(name, 0) + 1
            others[name] = value
        return others
