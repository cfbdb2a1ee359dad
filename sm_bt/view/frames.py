"""What the web view gets after a tick: one JSON frame with the tree, the modes and what happened.

A frame is a plain dict (JSON-ready)::

    {"tick": 12, "time": 3.5,                # the tick count; seconds since the run started
     "tree": {...},                          # py_trees_js's tree format (behaviours by id, ...)
     "modes": [{"part", "kind", "target", "actual", "inferred", "cause", "error"}, ...],
     "events": [{"time", "kind", "part", "text"}, ...]}   # the manager's events since the last frame

:class:`FrameMaker` is a post-tick handler: attach it to a ``py_trees.trees.BehaviourTree`` and it
hands each frame to its sinks (the web server, a ``.jsonl`` recording).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.visitors import FeedbackSnapshotVisitor
from sm_bt.engine.events import Event, EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.monitor import snapshot as mode_rows
from sm_bt.tree_snapshot import BehaviourView, behaviours, blackboard_values

Frame = dict[str, Any]
#: py_trees_js colours by kind (its own palette).
_COLOURS = {"sequence": "#FFA500", "selector": "#00FFFF", "parallel": "#FFFF00", "chooser": "#808080",
            "decorator": "#DDDDDD", "behaviour": "#555555"}
_EVENT_KINDS = (EventKind.TARGET, EventKind.ACTUAL, EventKind.DIVERGENCE, EventKind.REQUEST, EventKind.RULE,
                EventKind.FAILED)


def tree_json(views: list[BehaviourView], changed: bool, timestamp: float,
              blackboard: list[tuple[str, str]] | None = None) -> dict[str, Any]:
    """The tree in py_trees_js's format (``changed`` as the string it expects)."""
    tree: dict[str, Any] = {
        "changed": "true" if changed else "false",
        "timestamp": timestamp,
        "visited_path": [str(view.id) for view in views if view.active],
        "behaviours": {str(view.id): _behaviour_json(view) for view in views},
    }
    if blackboard is not None:
        tree["blackboard"] = {"behaviours": {}, "data": dict(blackboard)}
    return tree


def _behaviour_json(view: BehaviourView) -> dict[str, Any]:
    data = {"Class": view.class_name, "Feedback": view.feedback}
    if view.detail:
        data["Detail"] = view.detail
    behaviour: dict[str, Any] = {
        "id": str(view.id), "status": view.status.value, "name": view.name, "colour": _COLOURS[view.kind],
        "details": view.detail or "...", "data": data,
    }
    if view.children:
        behaviour["children"] = [str(child) for child in view.children]
    return behaviour


class FrameMaker:
    """A post-tick handler that makes a frame of ``tree`` and ``manager`` after each tick and
    gives it to every sink (``sink(frame)``; a sink must not block: the tick waits for it).

    Only ticks where something changed (a status, the visited path, a feedback message, a mode,
    an event) make a frame, so a recording stays small over long idle stretches.
    """

    def __init__(self, tree: py_trees.trees.BehaviourTree, manager: ModeManager, *,
                 sinks: list[Callable[[Frame], None]] | None = None) -> None:
        self._tree = tree
        self._manager = manager
        self.sinks: list[Callable[[Frame], None]] = list(sinks or [])
        self._visitor = FeedbackSnapshotVisitor()
        tree.add_visitor(self._visitor)
        tree.add_post_tick_handler(self)
        self._epoch = manager.clock.now()
        self._events: list[dict[str, Any]] = []
        self._events_lock = threading.Lock()  # on ROS, manager events come from its executors' and clock's threads
        self._ticks = 0
        self._last_modes: list[dict[str, Any]] | None = None
        self.last: Frame | None = None
        self._subscription = manager.subscribe(self._on_event, kinds=_EVENT_KINDS)

    def _on_event(self, event: Event) -> None:
        text = str(event.text) if event.text else _describe(event)
        if event.kind is EventKind.REQUEST and event.request is not None and not event.request.done:
            text += f" [{event.request.requester}]"  # who asked: tree, user, rule, recovery
        with self._events_lock:
            self._events.append({"time": round(event.time - self._epoch, 3), "kind": event.kind.value,
                                 "part": event.part, "text": text})

    def __call__(self, tree: py_trees.trees.BehaviourTree) -> None:
        self._ticks += 1
        with self._events_lock:
            events, self._events = self._events, []
        modes = [_mode_json(row) for row in mode_rows(self._manager)]
        changed = self._visitor.changed or bool(events) or modes != self._last_modes
        if not changed and self.last is not None:
            return
        self._last_modes = modes
        now = round(self._manager.clock.now() - self._epoch, 3)
        views = behaviours(tree.root, self._visitor.visited)
        frame: Frame = {
            "tick": self._ticks, "time": now,
            "tree": tree_json(views, self._visitor.changed, now,
                              blackboard_values(self._visitor.visited_blackboard_client_ids)),
            "status": tree.root.status.value, "modes": modes, "events": events,
        }
        self.last = frame
        for sink in self.sinks:
            sink(frame)

    def close(self) -> None:
        self._subscription.cancel()
        if self in self._tree.post_tick_handlers:
            self._tree.post_tick_handlers.remove(self)


def _describe(event: Event) -> str:
    if event.kind is EventKind.ACTUAL and event.actual is not None:
        return f"{event.part} is {event.actual}"
    if event.kind is EventKind.TARGET and event.target is not None:
        return f"{event.part} targeted at {event.target}"
    if event.kind is EventKind.DIVERGENCE:
        return str(event.divergence) if event.divergence is not None else f"{event.part} back on target"
    return f"{event.kind.value} {event.part}"


def _mode_json(row: Any) -> dict[str, Any]:
    target = f"{row.target_state}.{row.target_mode}" if row.target_mode else row.target_state
    actual = f"{row.raw_state}.{row.raw_mode}" if row.raw_mode else row.raw_state
    return {"part": row.part, "kind": row.kind, "target": target, "actual": actual,
            "inferred": bool(row.state_inferred or row.mode_inferred),
            "cause": row.cause.value if row.cause is not None else None, "error": bool(row.error)}


class Recorder:
    """A sink that appends every frame to a ``.jsonl`` file (one JSON object per line)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = self.path.open("w", encoding="utf-8")

    def __call__(self, frame: Frame) -> None:
        self._file.write(json.dumps(frame, separators=(",", ":")) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()


def read_recording(path: str | Path) -> list[Frame]:
    """The frames of a recording; ``ValueError`` naming the line for one that is not a frame."""
    frames = []
    with Path(path).open(encoding="utf-8") as file:
        for number, line in enumerate(file, 1):
            if not line.strip():
                continue
            try:
                frame = json.loads(line)
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}:{number}: not JSON ({error.msg})") from None
            if not isinstance(frame, dict) or not {"tick", "tree", "modes"} <= frame.keys():
                raise ValueError(f"{path}:{number}: not a frame of sm-bt's view (tick, tree, modes)")
            frames.append(frame)
    return frames


__all__ = ["Frame", "FrameMaker", "Recorder", "Status", "read_recording", "tree_json"]
