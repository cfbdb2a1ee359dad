"""The reference's mode manager interface, served by an rclpy node over a :class:`ModeManager`.

For every part of the model, with the reference's names and types (a drop-in for its
``mode_manager``; existing clients keep working):

* systems: ``/{system}/change_state``, ``get_state``, ``get_available_states`` (lifecycle_msgs);
* every part: ``/{part}/change_mode``, ``get_mode``, ``get_available_modes`` (system_modes_msgs);
* topics ``/{part}/mode_request_info`` and ``/{part}/transition_request_info`` (when a part's
  target changes), ``/{system}/transition_event`` and ``/{part}/mode_event`` (when its inferred
  state or mode changes).

Unlike the reference, events go out as soon as inference changes (no 1 s timer), carry their
real start state or mode and a timestamp (ROS time, nanoseconds), and every topic is latched
(transient local, depth 1), so a late joiner gets the current value. ``change_mode`` and
``change_state`` answer ``success`` for an *accepted* request; confirmation comes as
``mode_event``/``transition_event`` (or through the behaviours). The same engine serves the
behaviours of a mission tree in the same process.
"""

from __future__ import annotations

from typing import Any

from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableStates, GetState
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from system_modes_msgs.msg import Mode, ModeEvent
from system_modes_msgs.srv import ChangeMode, GetAvailableModes, GetMode

from sm_bt.engine.events import Event, EventKind, Subscription
from sm_bt.engine.inference import Actual
from sm_bt.engine.lifecycle import PlanError, plan
from sm_bt.engine.manager import ModeManager
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import SystemPart

#: Latched: a subscriber that joins late still gets the last message.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: What a system's ``change_state`` can lead to (``get_available_states``).
SYSTEM_STATES = (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE)


def _mode_label(actual: Actual) -> str:
    if not actual.known:
        return "unknown"
    return actual.mode or ""


class ModeManagerServer:
    """Serve ``manager``'s parts on ``node``; ``close()`` removes the services and topics."""

    def __init__(self, node: Node, manager: ModeManager) -> None:
        self._node = node
        self._manager = manager
        self._log = node.get_logger()
        self._services: list[Any] = []
        self._publishers: list[Any] = []
        self._mode_events: dict[str, Any] = {}
        self._transition_events: dict[str, Any] = {}
        self._mode_requests: dict[str, Any] = {}
        self._transition_requests: dict[str, Any] = {}
        # The last published values, so each event carries its real start.
        self._modes: dict[str, str] = {}
        self._states: dict[str, State] = {}
        for name, part in manager.model.parts.items():
            self._serve(name, isinstance(part, SystemPart))
        with manager.lock:  # the current values first, then every change: none missed, none stale
            for name in manager.model.parts:
                self._publish_actual(name, manager.actual(name))
            self._subscription: Subscription | None = manager.subscribe(
                self._on_event, kinds=(EventKind.ACTUAL, EventKind.TARGET))

    def close(self) -> None:
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        for service in self._services:
            self._node.destroy_service(service)
        for publisher in self._publishers:
            self._node.destroy_publisher(publisher)
        self._services.clear()
        self._publishers.clear()

    # -- set-up --------------------------------------------------------------------------------------

    def _serve(self, part: str, system: bool) -> None:
        base = "/" + part.lstrip("/")
        node = self._node

        def service(kind: Any, name: str, callback: Any) -> None:
            self._services.append(node.create_service(kind, f"{base}/{name}", callback))

        def publisher(kind: Any, name: str) -> Any:
            created = node.create_publisher(kind, f"{base}/{name}", LATCHED)
            self._publishers.append(created)
            return created

        service(ChangeMode, "change_mode", lambda req, res: self._change_mode(part, req, res))
        service(GetMode, "get_mode", lambda req, res: self._get_mode(part, res))
        service(GetAvailableModes, "get_available_modes", lambda req, res: self._get_available_modes(part, res))
        self._mode_events[part] = publisher(ModeEvent, "mode_event")
        self._mode_requests[part] = publisher(ModeEvent, "mode_request_info")
        self._transition_requests[part] = publisher(TransitionEvent, "transition_request_info")
        if system:
            service(ChangeState, "change_state", lambda req, res: self._change_state(part, req, res))
            service(GetState, "get_state", lambda req, res: self._get_state(part, res))
            service(GetAvailableStates, "get_available_states", lambda req, res: self._get_available_states(res))
            self._transition_events[part] = publisher(TransitionEvent, "transition_event")

    # -- services (executor thread) --------------------------------------------------------------------

    def _change_mode(self, part: str, request: Any, response: Any) -> Any:
        self._log.info(f"-> callback change_mode of {part} to {request.mode_name}")
        handle = self._manager.change_mode(part, request.mode_name)
        response.success = not (handle.done and not handle.succeeded)
        if not response.success:
            self._log.error(f"mode change of {part} to {request.mode_name!r} refused: {handle.reason}")
        return response

    def _change_state(self, part: str, request: Any, response: Any) -> Any:
        transition: str | int = request.transition.label or int(request.transition.id)
        self._log.info(f"-> request for transition of {part}: {transition}")
        handle = self._manager.change_state(part, transition)
        response.success = not (handle.done and not handle.succeeded)
        if not response.success:
            self._log.error(f"transition {transition} of {part} refused: {handle.reason}")
        return response

    def _get_mode(self, part: str, response: Any) -> Any:
        response.current_mode = _mode_label(self._manager.actual(part))
        return response

    def _get_available_modes(self, part: str, response: Any) -> Any:
        response.available_modes = self._manager.available_modes(part)
        return response

    def _get_state(self, part: str, response: Any) -> Any:
        response.current_state = _state_message(self._manager.actual(part).state)
        return response

    @staticmethod
    def _get_available_states(response: Any) -> Any:
        response.available_states = [_state_message(state) for state in SYSTEM_STATES]
        return response

    # -- topics (the thread of the manager's event) ----------------------------------------------------

    def _on_event(self, event: Event) -> None:
        if event.kind is EventKind.ACTUAL and event.actual is not None:
            self._publish_actual(event.part, event.actual)
        elif event.kind is EventKind.TARGET and event.target is not None:
            self._publish_request(event.part, event.target, event.actual)

    def _publish_actual(self, part: str, actual: Actual) -> None:
        stamp = self._stamp()
        mode = _mode_label(actual)
        previous_mode = self._modes.get(part)
        if mode != previous_mode:
            self._modes[part] = mode
            self._mode_events[part].publish(_mode_event(stamp, previous_mode or "", mode))
        if part in self._transition_events:
            previous_state = self._states.get(part, State.UNKNOWN)
            if actual.state is not previous_state or part not in self._states:
                self._states[part] = actual.state
                event = TransitionEvent(timestamp=stamp, start_state=_state_message(previous_state),
                                        goal_state=_state_message(actual.state))
                self._transition_events[part].publish(event)

    def _publish_request(self, part: str, target: StateMode, actual: Actual | None) -> None:
        stamp = self._stamp()
        current = actual.state if actual is not None else State.UNKNOWN
        if target.state is State.ACTIVE:
            start = _mode_label(actual) if actual is not None else ""
            self._mode_requests[part].publish(_mode_event(stamp, start, target.mode or ""))
        event = TransitionEvent(timestamp=stamp, start_state=_state_message(current),
                                goal_state=_state_message(target.state))
        step = _first_step(current, target.state)
        if step is not None:
            event.transition = TransitionMsg(id=int(step), label=step.label)
        self._transition_requests[part].publish(event)

    def _stamp(self) -> int:
        return int(self._node.get_clock().now().nanoseconds)


def _state_message(state: State) -> Any:
    return StateMsg(id=int(state), label=state.label)


def _mode_event(stamp: int, start: str, goal: str) -> Any:
    return ModeEvent(timestamp=stamp, start_mode=Mode(label=start), goal_mode=Mode(label=goal))


def _first_step(start: State, goal: State) -> Any:
    """The first transition from ``start`` towards ``goal``, when both are primary and differ."""
    if not (start.is_primary and goal.is_primary) or start is goal:
        return None
    try:
        steps = plan(start, goal)
    except PlanError:
        return None
    return steps[0].transition if steps else None
