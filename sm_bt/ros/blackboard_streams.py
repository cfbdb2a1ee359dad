"""py_trees_ros's blackboard-stream protocol, served for any py_trees tree: the blackboard watcher
(``py-trees-blackboard-watcher``) shows what sm_bt trees keep there (``/system_modes/<part>``...).

``BlackboardStreams(node, tree)`` offers, on ``node``, the three services the watcher finds by type:
``~/blackboard_streams/get_variables`` (every key, and the attributes of values that are objects:
``/system_modes/pilot.mode``), ``open`` and ``close``
(``py_trees_ros_interfaces/srv/{GetBlackboardVariables,OpenBlackboardStream,CloseBlackboardStream}``).
Each open stream is a latched ``std_msgs/String`` topic of text, one ``name: value`` line per
variable it asked for (all of them if none; only the ones of behaviours on the path ticked last
with ``filter_on_visited_path``), published after a tick when that text changed or a new reader
came (the watcher subscribes volatile), followed by the tick's blackboard activity when asked. A
value shows as ``str(value)``; values are read by name, not copied, so nothing on the blackboard
has to be picklable.

Service callbacks run in ``node``'s executor thread, the streams are published in the ticking
thread; a lock keeps the streams consistent between them.
"""

from __future__ import annotations

import logging
import uuid
from dataclasses import dataclass, field
from typing import Any

import py_trees

from sm_bt.ros import removable
from sm_bt.ros.tree_streams import TreeStreams

log = logging.getLogger("sm_bt.ros.blackboard_streams")

#: Attributes of blackboard values that the variable list goes into, at most this deep.
_NESTING = 2


@dataclass
class _Stream:
    topic: str
    publisher: Any
    variables: frozenset[str]
    on_visited_path: bool
    with_activity: bool
    last: str | None = None  # the text sent last
    keys: set[str] = field(default_factory=set)  # the keys shown last
    readers: int = 0  # subscriptions matched when it was sent


class BlackboardStreams(TreeStreams[_Stream]):
    """Serve blackboard streams of ``tree``'s blackboard on ``node`` until :meth:`close`."""

    def __init__(self, node: Any, tree: py_trees.trees.BehaviourTree) -> None:
        from py_trees_ros_interfaces.srv import CloseBlackboardStream, GetBlackboardVariables, OpenBlackboardStream

        self._visitor: py_trees.visitors.SnapshotVisitor = py_trees.visitors.SnapshotVisitor()
        super().__init__(node, tree, self._visitor)
        self._services = [
            node.create_service(GetBlackboardVariables, "~/blackboard_streams/get_variables", self._variables),
            node.create_service(OpenBlackboardStream, "~/blackboard_streams/open", self._open),
            node.create_service(CloseBlackboardStream, "~/blackboard_streams/close", self._close),
        ]

    # -- services (the node's executor thread) -------------------------------------------------------

    def _variables(self, request: Any, response: Any) -> Any:
        response.variables = variable_names()
        return response

    def _open(self, request: Any, response: Any) -> Any:
        from rclpy.expand_topic_name import expand_topic_name
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        try:
            with self._lock:
                topic = str(expand_topic_name(f"~/blackboard_streams/_watcher_{self._counter}",
                                              self._node.get_name(), self._node.get_namespace()))
                self._counter += 1
                stream = _Stream(topic, removable.publisher(self._node, String, topic, latched),
                                 frozenset(request.variables), bool(request.filter_on_visited_path),
                                 bool(request.with_activity_stream))
                self._streams[topic] = stream
                self._update_activity()
                self._publish(stream)  # the blackboard as it is now, at once
            log.info("blackboard stream opened: %s", topic)
            response.topic = topic
        except Exception:  # an rclpy callback that raises stops the executor: answer empty instead
            log.exception("opening a blackboard stream failed")
            response.topic = ""
        return response

    def _close(self, request: Any, response: Any) -> Any:
        with self._lock:
            stream = self._streams.pop(request.topic_name, None)
            if stream is not None:
                self._node.destroy_publisher(stream.publisher)
                self._update_activity()
        response.result = stream is not None
        if stream is not None:
            log.info("blackboard stream closed: %s", request.topic_name)
        return response

    def _wants_activity(self, stream: _Stream) -> bool:
        return stream.with_activity

    # -- ticks (the ticking thread) ------------------------------------------------------------------

    def _after_tick(self, tree: py_trees.trees.BehaviourTree) -> None:
        with self._lock:
            for stream in list(self._streams.values()):
                try:
                    self._publish(stream)
                except Exception:  # a publisher destroyed under us (shutdown): not the tree's problem
                    log.debug("blackboard on %s not sent", stream.topic, exc_info=True)

    def _publish(self, stream: _Stream) -> None:
        from std_msgs.msg import String

        names = self._names(stream)
        text = "\n".join(f"{name}: {_value(name)}" for name in names)
        activity = _activity(stream.keys | {name.split(".")[0] for name in names}) if stream.with_activity else ""
        # The watcher reads volatile: what went out before its subscription matched never reaches it,
        # so a new reader gets the text again, and nothing is sent while nobody reads.
        readers = stream.publisher.get_subscription_count()
        if readers == 0 or (text == stream.last and not activity and readers <= stream.readers):
            stream.readers = readers
            return
        stream.last, stream.keys, stream.readers = text, {name.split(".")[0] for name in names}, readers
        stream.publisher.publish(String(data=text + (f"\n{activity}" if activity else "")))

    def _names(self, stream: _Stream) -> list[str]:
        Blackboard = py_trees.blackboard.Blackboard
        names = set(stream.variables) if stream.variables else set(Blackboard.keys())
        if stream.on_visited_path:
            visited: set[uuid.UUID] = self._visitor.visited_blackboard_client_ids
            keys = Blackboard.keys_filtered_by_clients(client_ids=visited)
            names = {name for name in names if name.split(".")[0] in keys}
        return sorted(names)


def variable_names() -> list[str]:
    """Every blackboard key, and below each the public data attributes of its value (``key.attr``,
    ``_NESTING`` levels deep), sorted: what a watcher may ask to see."""
    names: list[str] = []

    def below(value: Any, name: str, depth: int) -> None:
        if depth == 0 or isinstance(value, (bool, int, float, str, bytes, list, tuple, dict, set)) or value is None:
            return
        for attribute in dir(type(value)):
            if attribute.startswith("_") or attribute.isupper():
                continue
            try:
                inner = getattr(value, attribute)
            except Exception:  # a property that fails: not a variable to offer
                continue
            if not callable(inner):
                names.append(f"{name}.{attribute}")
                below(inner, f"{name}.{attribute}", depth - 1)

    for key in sorted(py_trees.blackboard.Blackboard.keys()):
        names.append(key)
        try:
            below(py_trees.blackboard.Blackboard.get(key), key, _NESTING)
        except KeyError:
            continue
    return names


def _value(name: str) -> str:
    try:
        return str(py_trees.blackboard.Blackboard.get(name))
    except (KeyError, AttributeError):
        return "-"


def _activity(keys: set[str]) -> str:
    """The tick's activity on ``keys``, one line per item (empty if none)."""
    stream = py_trees.blackboard.Blackboard.activity_stream
    if stream is None:
        return ""
    return "\n".join(f"  {item.activity_type}: {item.key} by {item.client_name}"
                     + ("" if item.current_value is None else f" = {item.current_value}")
                     for item in stream.data if item.key in keys)
