"""The reference's mode manager interface, served by an rclpy node over a :class:`ModeManager`.

For every part of the model, with the reference's names and types (a drop-in for its
``mode_manager``; existing clients keep working):

* systems: ``/{system}/change_state``, ``get_state``, ``get_available_states`` (lifecycle_msgs);
* every part: ``/{part}/change_mode``, ``get_mode``, ``get_available_modes`` (system_modes_msgs);
* every part, sm_bt's own: ``/{part}/preview_change`` (sm_bt_msgs/PreviewChange): what a change
  of mode or state would do, without doing it (``sm-bt mode set --dry-run``);
  ``/{part}/request_change`` (sm_bt_msgs/RequestChange): a change with its requester and priority,
  answered with the reason when refused (``sm-bt mode set --priority``); ``/{part}/hold_mode``
  (sm_bt_msgs/HoldMode): a hold with a lease, renewed and released by its number (``sm-bt mode hold``);
* topics ``/{part}/mode_request_info`` and ``/{part}/transition_request_info`` (when a part's
  target changes), ``/{system}/transition_event`` and ``/{part}/mode_event`` (when its inferred
  state or mode changes);
* sm_bt's own topic ``/{part}/request_outcome`` (sm_bt_msgs/RequestOutcome, reliable, volatile,
  depth 10): how each request made through this interface ended (succeeded, failed with the
  reason, or refused), with its number, once, when it ends. A client that waits for its request
  (a fleet's manager, :mod:`sm_bt.ros.remote_parts`) learns of its failure at once, rather than
  at its own timeout.

Unlike the reference, events go out as soon as inference changes (no 1 s timer), carry their real
start state or mode and a timestamp (ROS time, nanoseconds: when the change happened), and every
topic is latched (transient local, depth 1). ``mode_event`` alone also offers a liveliness lease
(:data:`MODE_EVENT_LEASE`, automatic): DDS itself then tells its readers that ask for it (a
fleet's manager, :mod:`sm_bt.ros.remote_parts`) when this process stops or is cut off, with no
call answered by Python; readers that ask for no lease (the reference's, most clients') match as
before. Every message is published when its change happens, whoever reads, so that what the topics
say is true on the wire: a volatile subscriber gets only the changes after it subscribed, and a
late transient-local one gets the current value first (its writer's history holds nothing older).
The messages go out as CDR bytes written here (:mod:`sm_bt.ros.cdr`), a fraction of what building
them for rclpy costs. ``change_mode`` and ``change_state`` answer ``success`` for an *accepted*
request; confirmation comes as ``mode_event``/``transition_event`` (or through the behaviours).
The same engine serves the behaviours of a mission tree in the same process.

What goes on each topic:

* ``mode_event``: one message per change of the part's actual mode, as the reference's clients
  read it (a node's ``mode_event`` means "active in this mode"): published only when the part is
  ``active`` with a mode that differs from the last one published; ``start_mode`` is that last
  mode (empty only for a part's first event). States with no mode (inactive, activating without
  a mode, unknown) publish nothing here; ``transition_event`` and ``get_mode`` show them.
* ``transition_event`` (systems): every change of the inferred state, start = the state before.
* ``transition_request_info``: when a target changes state, or a transition is asked of the part:
  the transition (id and label), the state it starts from and the target's state. It goes out
  *before* ``mode_request_info`` (the reference's monitor takes a goal ``active`` there as
  ``__DEFAULT__``, and the mode request that follows corrects it).
* ``mode_request_info``: when the target is active: the part's mode before (empty when none) and
  the target mode.

Every service callback answers, whatever happens: an empty mode name (``__DEFAULT__`` names the
default mode), an unknown part, mode or transition, or an internal error give ``success=false``
and one log line. Log lines go through Python :mod:`logging` (``sm_bt.ros.manager_node``): silent
unless the application configures logging (``sm-bt manager`` does, on stderr).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableStates, GetState
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from sm_bt_msgs.msg import RequestOutcome
from sm_bt_msgs.srv import HoldMode, PreviewChange, RequestChange
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetAvailableModes, GetMode

from sm_bt.engine.events import Event, EventKind, Subscription
from sm_bt.engine.holds import Hold
from sm_bt.engine.inference import Actual
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, SystemPart
from sm_bt.ros import removable
from sm_bt.ros.cdr import mode_event, transition_event
from sm_bt.ros.names import qualified_name

log = logging.getLogger("sm_bt.ros.manager_node")

#: Latched: a subscriber that joins late still gets the last message.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Seconds of the liveliness lease every part's ``mode_event`` offers. Fast DDS (rmw_fastrtps sets the
#: announcement period to 2/3 of the lease) then asserts the process's liveliness every 1/3 s, from
#: its own threads, to every participant of the domain: a reader that asks for a lease of L s
#: (L >= this one to match; a fleet asks for its liveness window, 0.9 s) is told that the writer is no
#: longer alive L s after the last assertion it received: the process stopped, exited or was cut
#: off. Two assertions in a row may be lost within a 0.9 s lease. A reader that asks for no lease
#: (infinite: the default QoS) matches as before.
MODE_EVENT_LEASE = 0.5
#: ``mode_event``'s QoS: latched, with the lease.
MODE_EVENTS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         liveliness=LivelinessPolicy.AUTOMATIC,
                         liveliness_lease_duration=Duration(nanoseconds=int(MODE_EVENT_LEASE * 1e9)))
#: ``request_outcome``'s QoS: every outcome to the readers there (a burst of a preempted request and its
#: successor's refusal included); none to a reader that comes later, whose requests are newer.
OUTCOMES = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: What a system's ``change_state`` can lead to (``get_available_states``).
SYSTEM_STATES = (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE)


def _mode_label(actual: Actual) -> str:
    """``get_mode``'s answer: the mode, ``""`` when there is none, ``unknown`` while the state is."""
    if not actual.known:
        return "unknown"
    return actual.mode or ""


class ModeManagerServer:
    """Serve ``manager``'s parts on ``node``; ``close()`` removes the services and topics. The
    requests made through the interface come from ``requester`` (its priority decides against the
    parts' holds, :mod:`sm_bt.engine.holds`). With ``nodes=False`` only the systems are served
    (the reference serves every node too: at plant size, each node's 6 services and 3 topics are 15
    DDS endpoints that every participant learns of, and that take seconds to make and to remove)."""

    def __init__(self, node: Node, manager: ModeManager,
                 on_request: Callable[[str, Request], None] | None = None, requester: str = "operator", *,
                 nodes: bool = True, namespace: str = "/") -> None:
        self._node = node
        self.namespace = namespace  # the parts' services hang from it: /robot1/pilot/change_mode
        self._manager = manager
        self.requester = requester
        self._on_request = on_request  # told of every request made through the interface
        self._services: list[Any] = []
        self._publishers: list[Any] = []
        self._mode_events: dict[str, Any] = {}
        self._transition_events: dict[str, Any] = {}
        self._mode_requests: dict[str, Any] = {}
        self._transition_requests: dict[str, Any] = {}
        self._outcomes: dict[str, Any] = {}
        self._holds: dict[int, Hold] = {}  # made through hold_mode, by number (ended ones dropped on the next call)
        self._holds_lock = threading.Lock()
        self._clock: Any = node.get_clock()  # a ROSClock
        # The last published values, so each event carries its real start (and none repeats).
        self._modes: dict[str, str] = {}
        self._states: dict[str, State] = {}
        # A remote part's interface is its own manager's: served here, a name could be both.
        served = [name for name, part in manager.model.parts.items()
                  if isinstance(part, SystemPart) or (nodes and part.remote is None)]
        systems = {name: isinstance(manager.model.parts[name], SystemPart) for name in served}
        for name in served:
            self._advertise(name, systems[name])
        with manager.lock:  # the current values first, then every change: none missed, none stale
            for name in served:
                self._publish_actual(name, manager.actual(name))
            self._subscription: Subscription | None = manager.subscribe(
                self._on_event, None if len(served) == len(manager.model.parts) else served,
                kinds=(EventKind.ACTUAL, EventKind.TARGET))
        # The services last: a request is taken as soon as its service exists, and what it changes
        # must find the topics there and the subscription made (or its request info is never told).
        for name in served:
            self._serve(name, systems[name])

    def close(self) -> None:
        # In the reverse order of the making: no request is taken once nothing would tell of it.
        for service in self._services:
            self._node.destroy_service(service)
        self._services.clear()
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        self._outcomes.clear()  # a request that ends from now on is told nowhere
        for publisher in self._publishers:
            self._node.destroy_publisher(publisher)
        self._publishers.clear()

    # -- set-up --------------------------------------------------------------------------------------

    def _advertise(self, part: str, system: bool) -> None:
        base = qualified_name(part, self.namespace)

        def publisher(kind: Any, name: str, qos: QoSProfile = LATCHED) -> Any:
            created = removable.publisher(self._node, kind, f"{base}/{name}", qos)
            self._publishers.append(created)
            return created

        self._mode_events[part] = publisher(ModeEvent, "mode_event", MODE_EVENTS)
        self._mode_requests[part] = publisher(ModeEvent, "mode_request_info")
        self._transition_requests[part] = publisher(TransitionEvent, "transition_request_info")
        self._outcomes[part] = publisher(RequestOutcome, "request_outcome", OUTCOMES)
        if system:
            self._transition_events[part] = publisher(TransitionEvent, "transition_event")

    def _serve(self, part: str, system: bool) -> None:
        base = qualified_name(part, self.namespace)
        node = self._node

        def service(kind: Any, name: str, answer: Callable[[Any, Any], Any]) -> None:
            callback = _never_raising(f"{base}/{name}", answer, _failure_response(kind))
            self._services.append(node.create_service(kind, f"{base}/{name}", callback))

        service(ChangeMode, "change_mode", lambda req, res: self._change_mode(part, req, res))
        service(GetMode, "get_mode", lambda req, res: self._get_mode(part, res))
        service(GetAvailableModes, "get_available_modes", lambda req, res: self._get_available_modes(part, res))
        service(PreviewChange, "preview_change", lambda req, res: self._preview_change(part, req, res))
        service(RequestChange, "request_change", lambda req, res: self._request_change(part, req, res))
        service(HoldMode, "hold_mode", lambda req, res: self._hold_mode(part, req, res))
        if system:
            service(ChangeState, "change_state", lambda req, res: self._change_state(part, req, res))
            service(GetState, "get_state", lambda req, res: self._get_state(part, res))
            service(GetAvailableStates, "get_available_states", lambda req, res: self._get_available_states(res))

    # -- services (executor thread) --------------------------------------------------------------------

    def _change_mode(self, part: str, request: Any, response: Any) -> Any:
        mode = request.mode_name
        log.debug("-> callback change_mode of %s to %r", part, mode)
        if not mode:
            # The reference answers false; never read "" as the default mode (nothing is touched).
            log.warning("change_mode of %s refused: the mode name is empty (name a mode; %s names the "
                        "default mode)", part, DEFAULT_MODE)
            response.success = False
            return response
        try:
            handle = self._manager.change_mode(part, mode, requester=self.requester)
        except RequestError as error:  # a name the model does not have: nothing is touched
            log.warning("change_mode of %s to %r refused: %s", part, mode, error)
            response.success = False
            return response
        self._told(part, handle)
        # false exactly when nothing was changed: an accepted request that fails later is told by
        # the events and /diagnostics, and its targets stand
        response.success = not handle.refused
        if not response.success:  # the manager has logged why (WARNING)
            log.debug("<- change_mode of %s to %r answered false: %s", part, mode, handle.reason)
        return response

    def _change_state(self, part: str, request: Any, response: Any) -> Any:
        transition: str | int = request.transition.label or int(request.transition.id)
        log.debug("-> callback change_state of %s: %s", part, transition)
        try:
            handle = self._manager.change_state(part, transition, requester=self.requester)
        except RequestError as error:
            log.warning("change_state of %s (%s) refused: %s", part, transition, error)
            response.success = False
            return response
        self._told(part, handle)
        response.success = not handle.refused
        if not response.success:  # the manager has logged why (WARNING)
            log.debug("<- change_state of %s (%s) answered false: %s", part, transition, handle.reason)
        return response

    def _preview_change(self, part: str, request: Any, response: Any) -> Any:
        log.debug("-> callback preview_change of %s: %r %r", part, request.mode, request.transition)
        try:
            preview = (self._manager.preview_state(part, request.transition) if request.transition
                       else self._manager.preview(part, request.mode or DEFAULT_MODE))
        except RequestError as error:  # a name the model does not have
            response.possible, response.refused = False, str(error)
            return response
        response.possible, response.refused, response.calls = preview.possible, preview.refused, preview.calls
        response.lines = preview.lines()
        response.json = json.dumps(preview.as_json())
        return response

    def _request_change(self, part: str, request: Any, response: Any) -> Any:
        requester = request.requester or self.requester
        priority = None if request.priority < 0 else int(request.priority)
        log.debug("-> callback request_change of %s: %r %r [%s, %s]", part, request.mode, request.transition,
                  requester, priority)
        try:
            handle = (self._manager.change_state(part, request.transition, requester=requester, priority=priority,
                                                 queue=request.queue) if request.transition else
                      self._manager.change_mode(part, request.mode or DEFAULT_MODE, requester=requester,
                                                priority=priority, queue=request.queue))
        except RequestError as error:  # a name the model does not have: nothing is touched
            log.warning("request_change of %s refused: %s", part, error)
            response.accepted, response.reason = False, str(error)
            return response
        self._told(part, handle)
        response.accepted, response.request = not handle.refused, handle.id
        response.reason = handle.reason if handle.refused else (handle.feedback if handle.feedback.startswith(
            "queued: ") else "")
        return response

    def _hold_mode(self, part: str, request: Any, response: Any) -> Any:
        log.debug("-> callback hold_mode of %s: %r [%s, %s] lease %g, hold %d%s", part, request.mode,
                  request.requester, request.priority, request.lease, request.hold,
                  " release" if request.release else "")
        with self._holds_lock:
            return self._hold_locked(part, request, response)

    def _hold_locked(self, part: str, request: Any, response: Any) -> Any:
        if request.hold:  # a renewal or a release of a hold made here
            held = self._holds.get(int(request.hold))
            if held is None or held.part != part:
                response.accepted, response.reason = False, f"no hold #{request.hold} of {part} was made here"
                return response
            if request.release:
                held.release()
            elif held.active:
                held.renew()
            response.accepted, response.hold = held.active or bool(request.release), held.id
            response.reason = "" if held.active or request.release else f"hold #{held.id} ended: {held.reason}"
            if not held.active:
                self._holds.pop(held.id, None)
            return response
        try:
            made = self._manager.hold(part, request.mode or DEFAULT_MODE, requester=request.requester or self.requester,
                                      priority=None if request.priority < 0 else int(request.priority),
                                      lease=float(request.lease) if request.lease > 0 else None)
        except RequestError as error:
            response.accepted, response.reason = False, str(error)
            return response
        if made.request is not None:
            self._told(part, made.request)
        response.accepted, response.reason, response.hold = made.active, made.reason, made.id
        for number in [n for n, h in self._holds.items() if not h.active]:
            del self._holds[number]
        if made.active:
            self._holds[made.id] = made
        return response

    def _told(self, part: str, handle: Request) -> None:
        if self._on_request is not None:
            self._on_request(part, handle)
        handle.add_done_callback(lambda ended: self._publish_outcome(part, ended))

    def _publish_outcome(self, part: str, request: Request) -> None:
        publisher = self._outcomes.get(part)
        if publisher is None:  # closed
            return
        message = RequestOutcome(request=request.id, description=request.description, requester=request.requester,
                                 outcome=request.outcome, reason=request.reason)
        try:
            publisher.publish(message)
        except Exception:  # destroyed meanwhile by close(), from another thread
            log.debug("request #%d of %s ended after the interface was closed", request.id, part)

    def _get_mode(self, part: str, response: Any) -> Any:
        response.current_mode = _mode_label(self._manager.actual(part))
        log.debug("-> callback get_mode of %s: %s", part, response.current_mode)
        return response

    def _get_available_modes(self, part: str, response: Any) -> Any:
        response.available_modes = self._manager.available_modes(part)
        return response

    def _get_state(self, part: str, response: Any) -> Any:
        state = self._manager.actual(part).state
        response.current_state = _state_message(state)
        log.debug("-> callback get_state of %s: %s", part, state.label)
        return response

    @staticmethod
    def _get_available_states(response: Any) -> Any:
        response.available_states = [_state_message(state) for state in SYSTEM_STATES]
        return response

    # -- topics (the thread of the manager's event, inside its lock) -------------------------------------

    def _on_event(self, event: Event) -> None:
        if event.kind is EventKind.ACTUAL and event.actual is not None:
            self._publish_actual(event.part, event.actual)
        elif event.kind is EventKind.TARGET and event.target is not None:
            self._publish_request(event, event.target)

    def _publish_actual(self, part: str, actual: Actual) -> None:
        # mode_event: only a new mode the part is active in (a reference client reads every
        # mode_event as "active in goal_mode"); start is the last mode published.
        if actual.state is State.ACTIVE and actual.mode:
            last = self._modes.get(part)
            if actual.mode != last:
                self._modes[part] = actual.mode
                self._mode_events[part].publish(mode_event(self._stamp(), last or "", actual.mode))
        if part in self._transition_events:
            # A system's every change of state; the first known state starts from unknown.
            previous = self._states.get(part, State.UNKNOWN)
            self._states[part] = actual.state
            if actual.state is not previous:
                self._transition_events[part].publish(_transition_event(self._stamp(), previous, actual.state, None))

    def _publish_request(self, event: Event, target: StateMode) -> None:
        part = event.part
        before = event.previous if event.previous is not None else event.actual
        start = before.state if before is not None else State.UNKNOWN
        # First the state (a reference monitor reads a goal "active" there as __DEFAULT__), then
        # the mode, which corrects it.
        if event.transition is not None or target.state is not start:
            self._transition_requests[part].publish(_transition_event(self._stamp(), start, target.state,
                                                                      event.transition))
        if target.state is State.ACTIVE:
            start_mode = (before.mode if before is not None else None) or ""
            self._mode_requests[part].publish(mode_event(self._stamp(), start_mode, _target_mode(target)))

    def _stamp(self) -> int:
        # ROS time: the system clock's, unless simulated time is on (a C call, not a Time object).
        clock = self._clock
        return clock.now().nanoseconds if clock.ros_time_is_active else time.time_ns()


def _target_mode(target: StateMode) -> str:
    return target.mode or DEFAULT_MODE


def _never_raising(name: str, answer: Callable[[Any, Any], Any],
                   failed: Callable[[Any], None]) -> Callable[[Any, Any], Any]:
    """``answer`` as a service callback that always answers: an exception escaping an rclpy
    callback would stop the executor, and with it the whole manager."""

    def callback(request: Any, response: Any) -> Any:
        try:
            return answer(request, response)
        except Exception:
            log.exception("%s failed on %s", name, request)
            failed(response)
            return response

    return callback


def _failure_response(kind: Any) -> Callable[[Any], None]:
    """What a failed call of a ``kind`` service answers (``success=false``, or ``unknown``)."""

    def fill(response: Any) -> None:
        if kind is ChangeMode or kind is ChangeState:
            response.success = False
        elif kind is PreviewChange:
            response.possible, response.refused = False, "the manager failed to preview it (its log says why)"
        elif kind is HoldMode or kind is RequestChange:
            response.accepted, response.reason = False, "the manager failed to take it (its log says why)"
        elif kind is GetMode:
            response.current_mode = "unknown"
        elif kind is GetState:
            response.current_state = _state_message(State.UNKNOWN)

    return fill


def _state_message(state: State) -> Any:
    return StateMsg(id=int(state), label=state.label)


def _transition_event(stamp: int, start: State, goal: State, transition: Transition | None) -> bytes:
    return transition_event(stamp, (int(transition), transition.label) if transition is not None else (0, ""),
                            (int(start), start.label), (int(goal), goal.label))
