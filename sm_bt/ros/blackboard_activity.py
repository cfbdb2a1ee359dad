"""py_trees' blackboard activity stream, shared by the streams that send it (snapshot streams,
blackboard streams): on while any of them wants it, off again once none does (unless it was on
before any did), and cleared before each tick so that every post-tick handler sees that tick's."""

from __future__ import annotations

import threading

import py_trees

_lock = threading.Lock()
_users: set[int] = set()
_enabled_here = False


def want(owner: object, wanted: bool) -> None:
    """``owner`` wants the activity stream on (or no longer)."""
    global _enabled_here
    Blackboard = py_trees.blackboard.Blackboard
    with _lock:
        if wanted:
            _users.add(id(owner))
        else:
            _users.discard(id(owner))
        if _users and Blackboard.activity_stream is None:
            Blackboard.enable_activity_stream()
            _enabled_here = True
        elif not _users and _enabled_here:
            Blackboard.disable_activity_stream()
            _enabled_here = False


def clear_for_tick() -> None:
    """Forget the previous tick's activity (a pre-tick handler), if the stream is ours to clear."""
    activity = py_trees.blackboard.Blackboard.activity_stream
    if _enabled_here and activity is not None:
        activity.clear()
