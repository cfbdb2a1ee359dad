"""The targets another mode manager publishes, followed by a manager that only watches.

A manager on ROS (``sm-bt manager``, or the reference's ``mode_manager``) announces every target
it sets on ``/{part}/transition_request_info`` (``lifecycle_msgs/TransitionEvent``: the target's
state) and ``/{part}/mode_request_info`` (``system_modes_msgs/ModeEvent``: its mode, when active).
:class:`RemoteTargets` hands them to a watching :class:`~sm_bt.engine.manager.ModeManager`
(:meth:`~sm_bt.engine.manager.ModeManager.observe_target`), so that ``sm-bt monitor --ros`` shows
the target columns and divergences next to a running manager. Each topic is read twice: latched
(sm_bt's manager keeps the last target for late readers) and volatile (the reference's are).
"""

from __future__ import annotations

import functools
from typing import Any

from sm_bt.engine.manager import ModeManager
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model
from sm_bt.ros import removable


class RemoteTargets:
    """Follow the request topics of ``model``'s parts on ``node`` into ``manager`` until :meth:`close`."""

    def __init__(self, node: Any, manager: ModeManager, model: Model) -> None:
        from lifecycle_msgs.msg import TransitionEvent
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from system_modes_msgs.msg import ModeEvent

        self._node = node
        self._manager = manager
        self._subscriptions: list[Any] = []
        for durability in (DurabilityPolicy.TRANSIENT_LOCAL, DurabilityPolicy.VOLATILE):
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=durability)
            for part in model.parts:
                self._subscriptions += [
                    removable.subscription(node, TransitionEvent, f"/{part}/transition_request_info",
                                           functools.partial(self._state, part), qos),
                    removable.subscription(node, ModeEvent, f"/{part}/mode_request_info",
                                           functools.partial(self._mode, part), qos)]

    def _state(self, part: str, message: Any) -> None:
        try:
            state = State.from_label(message.goal_state.label)
        except ValueError:
            return  # not a state: nothing to show
        if state not in (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE, State.FINALIZED):
            return
        known = self._manager.target(part)
        mode = known.mode if known is not None and state is State.ACTIVE else None
        self._manager.observe_target(part, StateMode(state, mode))  # the mode request, if any, follows

    def _mode(self, part: str, message: Any) -> None:
        mode = message.goal_mode.label
        if mode in self._manager.model.parts[part].modes:  # else not one of this model's: not shown
            self._manager.observe_target(part, StateMode(State.ACTIVE, mode))

    def close(self) -> None:
        for subscription in self._subscriptions:
            self._node.destroy_subscription(subscription)
        self._subscriptions.clear()
