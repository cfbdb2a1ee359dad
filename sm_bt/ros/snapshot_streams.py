"""py_trees_ros's snapshot-stream protocol, served for any py_trees tree: the tree watcher
(``py-trees-tree-watcher``) and viewer (``py-trees-tree-viewer``) show sm_bt trees.

``SnapshotStreams(node, tree)`` offers, on ``node``, the three services the tools find by type:
``~/snapshot_streams/open``, ``close`` and ``reconfigure``
(``py_trees_ros_interfaces/srv/{Open,Close,Reconfigure}SnapshotStream``). Each open stream is a
latched ``py_trees_ros_interfaces/msg/BehaviourTree`` topic, published after a tick when the tree
changed (a status or the visited path: at once; a feedback message, such as a new step of a mode
change, see :class:`~sm_bt.behaviours.FeedbackSnapshotVisitor`: at most every
:data:`FEEDBACK_INTERVAL` s, the latest one) or its period elapsed, with blackboard
data on the visited path and blackboard activity when the stream asked for them. sm_bt
behaviours carry their part and mode in ``additional_detail``.

Service callbacks run in ``node``'s executor thread, snapshots are made in the ticking thread;
a lock keeps the streams consistent between them. Needs the ``py_trees_ros_interfaces`` package
(``tools/ensure_interfaces.sh`` builds it), not py_trees_ros.
"""

from __future__ import annotations

import logging
import math
import statistics
import time
import uuid
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import BlackBoxLevel, Status

from sm_bt.behaviours.visitors import FeedbackSnapshotVisitor
from sm_bt.ros import removable
from sm_bt.ros.tree_streams import TreeStreams
from sm_bt.tree_snapshot import BehaviourView, behaviours, blackboard_values

log = logging.getLogger("sm_bt.ros.snapshot_streams")

_STATUS = {Status.INVALID: 1, Status.RUNNING: 2, Status.SUCCESS: 3, Status.FAILURE: 4}
_KIND = {"behaviour": 1, "sequence": 2, "selector": 3, "parallel": 4, "chooser": 5, "decorator": 6}
_BLACKBOX = {BlackBoxLevel.DETAIL: 1, BlackBoxLevel.COMPONENT: 2, BlackBoxLevel.BIG_PICTURE: 3,
             BlackBoxLevel.NOT_A_BLACKBOX: 4}
#: The tools' own margin: a periodic snapshot due within 2 % of its period is sent now.
_CLOSE_ENOUGH = 0.98
#: Seconds between snapshots sent for feedback alone: a feedback that counts time changes on every
#: tick, and a snapshot per tick buried the Qt viewer (seconds behind on two cores).
FEEDBACK_INTERVAL = 0.5


@dataclass
class _Stream:
    topic: str
    publisher: Any
    period: float = math.inf
    blackboard_data: bool = False
    blackboard_activity: bool = False
    last: float | None = None  # when the last snapshot went out (monotonic)
    held: bool = False  # feedback changed since then, not sent yet


@dataclass
class _Statistics:
    count: int = 0
    started: float = 0.0
    intervals: list[float] = field(default_factory=list)
    durations: list[float] = field(default_factory=list)


class SnapshotStreams(TreeStreams[_Stream]):
    """Serve snapshot streams of ``tree`` on ``node`` until :meth:`close`."""

    def __init__(self, node: Any, tree: py_trees.trees.BehaviourTree) -> None:
        from py_trees_ros_interfaces.srv import CloseSnapshotStream, OpenSnapshotStream, ReconfigureSnapshotStream

        self._visitor: FeedbackSnapshotVisitor = FeedbackSnapshotVisitor()
        super().__init__(node, tree, self._visitor)
        self._statistics = _Statistics()
        self._services = [
            node.create_service(OpenSnapshotStream, "~/snapshot_streams/open", self._open),
            node.create_service(CloseSnapshotStream, "~/snapshot_streams/close", self._close),
            node.create_service(ReconfigureSnapshotStream, "~/snapshot_streams/reconfigure", self._reconfigure),
        ]

    # -- services (the node's executor thread) -------------------------------------------------------

    def _open(self, request: Any, response: Any) -> Any:
        from py_trees_ros_interfaces.msg import BehaviourTree
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        try:
            with self._lock:
                topic = self._topic(request.topic_name)
                if topic in self._streams:
                    response.topic_name = topic  # the tools reopen after a restart: same stream
                    return response
                stream = _Stream(topic, removable.publisher(self._node, BehaviourTree, topic, latched))
                self._streams[topic] = stream
                self._configure(stream, request.parameters)
                self._publish(stream, status_changed=True)  # the tree as it is now, at once
            log.info("snapshot stream opened: %s", topic)
            response.topic_name = topic
        except Exception:  # an rclpy callback that raises stops the executor: answer empty instead
            log.exception("opening a snapshot stream (%r) failed", request.topic_name)
            response.topic_name = ""
        return response

    def _close(self, request: Any, response: Any) -> Any:
        with self._lock:
            stream = self._streams.pop(request.topic_name, None)
            if stream is not None:
                self._node.destroy_publisher(stream.publisher)
                self._update_activity()
        response.result = stream is not None
        if stream is not None:
            log.info("snapshot stream closed: %s", request.topic_name)
        return response

    def _reconfigure(self, request: Any, response: Any) -> Any:
        with self._lock:
            stream = self._streams.get(request.topic_name)
            if stream is not None:
                self._configure(stream, request.parameters)
        response.result = stream is not None
        return response

    def _topic(self, hint: str) -> str:
        """The tools' naming: none → a numbered one; ``~...`` or relative → under the node's
        ``~/snapshot_streams/``; absolute → itself."""
        from rclpy.expand_topic_name import expand_topic_name

        if not hint:
            hint = f"~/snapshot_streams/_snapshots_{self._counter}"
            self._counter += 1
        elif not hint.startswith(("~", "/")):
            hint = f"~/snapshot_streams/{hint}"
        if hint.startswith("/"):
            return hint
        return str(expand_topic_name(hint, self._node.get_name(), self._node.get_namespace()))

    def _configure(self, stream: _Stream, parameters: Any) -> None:
        period = float(parameters.snapshot_period)
        stream.period = period if period > 0 else math.inf
        stream.blackboard_data = bool(parameters.blackboard_data)
        stream.blackboard_activity = bool(parameters.blackboard_activity)
        self._update_activity()

    def _wants_activity(self, stream: _Stream) -> bool:
        return stream.blackboard_activity

    # -- ticks (the ticking thread) ------------------------------------------------------------------

    def _before_tick(self, tree: py_trees.trees.BehaviourTree) -> None:
        super()._before_tick(tree)
        now = time.monotonic()
        stats = self._statistics
        if stats.started:
            stats.intervals = ([*stats.intervals, now - stats.started])[-10:]
        stats.started = now

    def _after_tick(self, tree: py_trees.trees.BehaviourTree) -> None:
        stats = self._statistics
        stats.count += 1
        stats.durations = ([*stats.durations, time.monotonic() - stats.started])[-10:]
        status_changed = self._visitor.status_changed
        feedback_changed = self._visitor.changed and not status_changed
        with self._lock:
            for stream in list(self._streams.values()):
                try:
                    self._publish(stream, status_changed=status_changed, feedback_changed=feedback_changed)
                except Exception:  # a publisher destroyed under us (shutdown): not the tree's problem
                    log.debug("snapshot on %s not sent", stream.topic, exc_info=True)

    def _publish(self, stream: _Stream, *, status_changed: bool, feedback_changed: bool = False) -> None:
        now = time.monotonic()
        since = math.inf if stream.last is None else now - stream.last
        held = stream.held or feedback_changed
        changed = status_changed or since == math.inf or (held and since >= FEEDBACK_INTERVAL)
        if not changed and since < _CLOSE_ENOUGH * stream.period:
            stream.held = held  # sent with the next snapshot that goes out
            return
        stream.publisher.publish(self._message(stream, changed or held))
        stream.last = now
        stream.held = False

    def _message(self, stream: _Stream, changed: bool) -> Any:
        from diagnostic_msgs.msg import KeyValue as DiagnosticKeyValue
        from py_trees_ros_interfaces.msg import ActivityItem, BehaviourTree

        message = BehaviourTree(changed=changed)
        message.behaviours = [_behaviour_message(view)
                              for view in behaviours(self._tree.root, self._visitor.visited)]
        if stream.blackboard_data:
            message.blackboard_on_visited_path = [
                DiagnosticKeyValue(key=key, value=value)
                for key, value in blackboard_values(self._visitor.visited_blackboard_client_ids)]
        activity = py_trees.blackboard.Blackboard.activity_stream
        if stream.blackboard_activity and activity is not None:
            message.blackboard_activity = [
                ActivityItem(key=item.key, client_name=item.client_name, activity_type=item.activity_type,
                             previous_value=_text(item.previous_value), current_value=_text(item.current_value))
                for item in activity.data]
        message.statistics = self._statistics_message()
        return message

    def _statistics_message(self) -> Any:
        from py_trees_ros_interfaces.msg import Statistics

        stats = self._statistics
        message = Statistics(count=stats.count)
        message.stamp = self._node.get_clock().now().to_msg()
        for name, values in (("tick_duration", stats.durations), ("tick_interval", stats.intervals)):
            if values:
                setattr(message, name, float(values[-1]))
                setattr(message, f"{name}_average", float(statistics.fmean(values)))
                setattr(message, f"{name}_variance", float(statistics.pvariance(values)))
        return message


def _text(value: object) -> str:
    return "-" if value is None else str(value)


def _uuid(value: uuid.UUID | None) -> Any:
    from unique_identifier_msgs.msg import UUID

    return UUID(uuid=list(value.bytes)) if value is not None else UUID()


def _behaviour_message(view: BehaviourView) -> Any:
    from py_trees_ros_interfaces.msg import Behaviour, KeyValue

    message = Behaviour(name=view.name, class_name=view.class_name, type=_KIND[view.kind],
                        additional_detail=view.detail, blackbox_level=_BLACKBOX[view.blackbox],
                        status=_STATUS[view.status], message=view.feedback, is_active=view.active)
    message.own_id = _uuid(view.id)
    message.parent_id = _uuid(view.parent)
    message.tip_id = _uuid(view.tip)
    message.child_ids = [_uuid(child) for child in view.children]
    message.current_child_id = _uuid(view.current_child)
    message.blackboard_access = [KeyValue(key=key, value=access) for key, access in view.access]
    return message
