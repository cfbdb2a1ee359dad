"""What serving a py_trees tree to py_trees_ros's tools takes, whatever the stream: the tree's
visitor and tick handlers, the services, the open streams (each with its publisher) under a lock,
the shared blackboard activity stream, and closing it all (:class:`TreeStreams`)."""

from __future__ import annotations

import threading
from typing import Any, Generic, Protocol, TypeVar

import py_trees

from sm_bt.ros import blackboard_activity


class _Stream(Protocol):
    publisher: Any


S = TypeVar("S", bound=_Stream)


class TreeStreams(Generic[S]):
    """The base of :class:`~sm_bt.ros.snapshot_streams.SnapshotStreams` and
    :class:`~sm_bt.ros.blackboard_streams.BlackboardStreams`: ``visitor`` and the tick handlers go
    on ``tree``; a subclass adds its services to ``_services`` and streams to ``_streams``, and
    says in :meth:`_wants_activity` whether a stream needs the blackboard's activity."""

    def __init__(self, node: Any, tree: py_trees.trees.BehaviourTree, visitor: py_trees.visitors.VisitorBase) -> None:
        self._node = node
        self._tree = tree
        self._visitor = visitor
        self._lock = threading.Lock()
        self._streams: dict[str, S] = {}
        self._services: list[Any] = []
        self._counter = 0  # numbers the streams opened without a name
        tree.add_visitor(visitor)
        tree.add_pre_tick_handler(self._before_tick)
        tree.add_post_tick_handler(self._after_tick)

    def _wants_activity(self, stream: S) -> bool:
        raise NotImplementedError

    def _update_activity(self) -> None:
        blackboard_activity.want(self, any(self._wants_activity(stream) for stream in self._streams.values()))

    def _before_tick(self, tree: py_trees.trees.BehaviourTree) -> None:
        blackboard_activity.clear_for_tick()

    def _after_tick(self, tree: py_trees.trees.BehaviourTree) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Remove the services and streams and stop publishing (the tree keeps running)."""
        with self._lock:
            for stream in self._streams.values():
                self._node.destroy_publisher(stream.publisher)
            self._streams.clear()
            self._update_activity()
            for service in self._services:
                self._node.destroy_service(service)
            self._services.clear()
        for handlers, handler in ((self._tree.pre_tick_handlers, self._before_tick),
                                  (self._tree.post_tick_handlers, self._after_tick)):
            if handler in handlers:
                handlers.remove(handler)
        if self._visitor in self._tree.visitors:
            self._tree.visitors.remove(self._visitor)
