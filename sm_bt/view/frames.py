"""What the web view gets after a tick: a frame that carries only what changed since the frame before.

A frame is a plain dict (JSON-ready), format 2::

    {"tick": 12, "time": 3.5, "status": "RUNNING",   # always: tick count, seconds since the start, the root's status
     "key": true,                                     # a key frame (the first one, and after the tree's shape changed):
     "behaviours": {id: {...}},                       #   every behaviour in py_trees_js's format
     "changes": {id: {"status", "feedback", "details"}},  # otherwise the behaviours that changed, only what changed
     "visited": [id, ...],                            # the path ticked last, when it changed (always in a key frame)
     "blackboard": {key: value},                      # the visited behaviours' blackboard values that changed
     "modes": [{"part", "kind", "target", "actual", "inferred", "cause", "error", "held_by"}, ...],  # the table
     "modes_summary": "111,111 parts (...): 3 diverge, 1 an error; 60 shown",  # with "modes", when parts are left out
     "events": [{"time", "kind", "part", "text", ...}, ...]}  # the manager's events since the frame before, if any

A request's events also carry ``request`` (its number), ``done`` and ``ok`` (the timeline draws
its band); its start, ``plan``: the lines of its preview (:meth:`ModeManager.plan_of`, shown with its
band and in the list). Parts' actual and target changes are not events here: the ``modes`` table says them.
The table shows at most :data:`TABLE_ROWS` parts (:mod:`sm_bt.monitor_rows`: errors, then the other
divergences, then the top of the hierarchy). The list leaves out the divergences a request in
flight explains (its band shows them), and a frame lists at most :data:`DIVERGENCES_LISTED`
divergence events, summing up the rest in one line.
:mod:`sm_bt.view.recording` writes frames to a file, reads them back (format 1, a whole tree in
every frame, too) and folds a delta into the key frame before it.

:class:`FrameMaker` is a post-tick handler. It looks only at what can have changed: the
behaviours ticked this time and those that were not INVALID before (only a tick or a stop changes
a status), the mode table after a manager event; the whole tree every ``rescan`` ticks, which
catches a change of the tree's shape or of a behaviour left alone. A tick where nothing changed
makes no frame.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable
from typing import Any

import py_trees
from py_trees.blackboard import Blackboard
from py_trees.common import Status

from sm_bt.engine.events import Cause, Event, EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.monitor_rows import ROW_EVENTS, Row, Rows, Selection
from sm_bt.tree_snapshot import detail_of, kind_of

Frame = dict[str, Any]
Behaviour = py_trees.behaviour.Behaviour
#: py_trees_js colours by kind (its own palette).
_COLOURS = {"sequence": "#FFA500", "selector": "#00FFFF", "parallel": "#FFFF00", "chooser": "#808080",
            "decorator": "#DDDDDD", "behaviour": "#555555"}
#: Manager events that go into frames; the rest (actual, target) only mark the table as due.
_LISTED = frozenset({EventKind.DIVERGENCE, EventKind.REQUEST, EventKind.RULE, EventKind.FAILED, EventKind.HOLD})
#: Lines of a request's plan a frame carries (the rest is summed up).
PLAN_LINES = 40
#: Ticks between looks at the whole tree (its shape, every behaviour, the mode table).
RESCAN = 200
#: Parts the mode table shows at most, and divergence events a frame lists at most.
TABLE_ROWS, DIVERGENCES_LISTED = 8, 8


def behaviour_json(behaviour: Behaviour, ident: str, ids: dict[Behaviour, str]) -> dict[str, Any]:
    """One behaviour in py_trees_js's format."""
    detail = detail_of(behaviour)
    data = {"Class": f"{type(behaviour).__module__}.{type(behaviour).__name__}",
            "Feedback": behaviour.feedback_message}
    if detail:
        data["Detail"] = detail
    json: dict[str, Any] = {"id": ident, "status": behaviour.status.value, "name": behaviour.name,
                            "colour": _COLOURS[kind_of(behaviour)], "details": detail or "...", "data": data}
    if behaviour.children:
        json["children"] = [ids[child] for child in behaviour.children]
    return json


class _Ticked(py_trees.visitors.VisitorBase):
    """The behaviours ticked this time, in order (what py_trees_js calls the visited path)."""

    def __init__(self) -> None:
        super().__init__(full=False)
        self.behaviours: list[Behaviour] = []

    def initialise(self) -> None:
        self.behaviours = []

    def run(self, behaviour: Behaviour) -> None:
        self.behaviours.append(behaviour)


class FrameMaker:
    """A post-tick handler that makes a frame of ``tree`` and ``manager`` after each tick where
    something changed and gives it to every sink (``sink(frame)``; a sink must not block: the tick
    waits for it)."""

    def __init__(self, tree: py_trees.trees.BehaviourTree, manager: ModeManager, *,
                 sinks: list[Callable[[Frame], None]] | None = None, rescan: int = RESCAN) -> None:
        self._tree = tree
        self._manager = manager
        self.sinks: list[Callable[[Frame], None]] = list(sinks or [])
        self._rescan = rescan
        self._ticked = _Ticked()
        tree.add_visitor(self._ticked)
        tree.add_post_tick_handler(self)
        self._epoch = manager.clock.now()
        self._events: list[dict[str, Any]] = []
        self._table_due = True
        self._events_lock = threading.Lock()  # on ROS, manager events come from its executors' and clock's threads
        self._ticks = 0
        # The tree as last sent: ids (a uuid's str() is not free), each behaviour's status, feedback
        # and detail, and its py_trees_js form (for key frames).
        self._ids: dict[Behaviour, str] = {}
        self._shape: list[tuple[str, tuple[str, ...]]] = []
        self._shown: dict[Behaviour, tuple[Status, str, str]] = {}
        self._json: dict[str, dict[str, Any]] = {}
        self._live: set[Behaviour] = set()  # not INVALID when last looked at: only these can change unticked
        self._last_ticked: list[Behaviour] = []
        self._keys: dict[Behaviour, tuple[str, ...]] = {}  # the blackboard keys each behaviour uses
        self._visited_keys: list[str] = []
        self._blackboard: dict[str, str] = {}
        self._modes: tuple[list[dict[str, Any]], str | None] = ([], None)
        self._rows = Rows(manager, Selection(limit=TABLE_ROWS))
        self._listed: set[str] = set()  # parts whose divergence was listed (so is its end)
        self._divergences = 0  # divergence events listed for the next frame, and those left out
        self._unlisted = 0
        self.last: Frame | None = None
        self._subscription = manager.subscribe(self._on_event)

    def _on_event(self, event: Event) -> None:
        if event.kind in ROW_EVENTS:
            self._rows.changed(event)
        if event.kind not in _LISTED:
            self._table_due = True
            return
        if event.kind is EventKind.DIVERGENCE:
            # A request's own progress (in flight) is its band's to show, and so is its end.
            divergence, listed = event.divergence, self._listed
            if divergence is not None and divergence.cause is not Cause.IN_FLIGHT:
                listed.add(event.part)
            elif event.part in listed and divergence is None:
                listed.discard(event.part)
            else:
                self._table_due = True
                return
            with self._events_lock:
                self._divergences += 1
                if self._divergences > DIVERGENCES_LISTED:
                    self._unlisted += 1
                    self._table_due = True
                    return
        entry: dict[str, Any] = {"time": round(event.time - self._epoch, 3), "kind": event.kind.value,
                                 "part": event.part, "text": str(event.text) if event.text else _describe(event)}
        request = event.request
        if event.kind is EventKind.REQUEST and request is not None:
            entry.update(request=request.id, done=request.done, ok=request.succeeded if request.done else None)
            if not request.done:
                entry["text"] += f" [{request.requester}]"  # who asked: tree, user, rule, recovery
                plan = self._manager.plan_of(request)
                if plan is not None and plan.possible:  # shown with the request's band
                    lines = plan.lines()
                    entry["plan"] = lines[:PLAN_LINES] + ([f"… {len(lines) - PLAN_LINES} more lines"]
                                                         if len(lines) > PLAN_LINES else [])
        with self._events_lock:
            self._events.append(entry)
            self._table_due = True

    def note(self, kind: str, text: str) -> None:
        """An event of the run that is not the manager's (``"expectation"``: a scenario's
        expectation failed), sent with the next frame (or by :meth:`flush`)."""
        with self._events_lock:
            self._events.append({"time": round(self._manager.clock.now() - self._epoch, 3), "kind": kind,
                                 "part": "", "text": text})

    def flush(self) -> None:
        """Send the events not sent yet in a frame of their own (the run is over: no tick will)."""
        events = self._take_events()
        if events and self.last is not None:
            self._emit(self._stamped({"events": events}))

    def __call__(self, tree: py_trees.trees.BehaviourTree) -> None:
        self._ticks += 1
        ticked = self._ticked.behaviours
        ids = self._ids
        same_path = ticked == self._last_ticked  # the usual case: cheap (behaviours compare by identity)
        rescan = self._ticks % self._rescan == 0
        if self.last is None or (not same_path and any(behaviour not in ids for behaviour in ticked)) or \
                (rescan and self._reshaped()):
            self._emit(self._key_frame(ticked))
            return
        frame: Frame = {}
        changes = self._changes(ticked, same_path, tree.root.iterate() if rescan else None)
        if changes:
            frame["changes"] = changes
        if not same_path:
            self._last_ticked = ticked
            self._visited_keys = self._keys_of(ticked)
            frame["visited"] = [ids[behaviour] for behaviour in ticked]
        events = self._take_events()
        with self._events_lock:
            due, self._table_due = self._table_due or rescan, False
        if due:
            modes = self._table()
            if modes != self._modes:
                self._modes = modes
                self._put_table(frame)
        if events:
            frame["events"] = events
        if frame or rescan:  # values alone make no frame: whatever wrote them mostly changed too
            blackboard = self._blackboard_changes()
            if blackboard:
                frame["blackboard"] = blackboard
        if frame:
            self._emit(self._stamped(frame))

    def _take_events(self) -> list[dict[str, Any]]:
        """The events for the next frame, the divergences left out summed up in one."""
        with self._events_lock:
            events, self._events = self._events, []
            unlisted, self._unlisted, self._divergences = self._unlisted, 0, 0
        if unlisted:
            events.append({"time": round(self._manager.clock.now() - self._epoch, 3), "kind": "divergence",
                           "part": "", "text": f"… and {unlisted:,} more divergences started or ended "
                                               "(the table shows the parts that diverge)"})
        return events

    def _table(self) -> tuple[list[dict[str, Any]], str | None]:
        rows, summary = self._rows.current()
        return [_mode_json(row) for row in rows], summary.describe() if summary.shown < summary.parts else None

    def _put_table(self, frame: Frame) -> None:
        frame["modes"], summary = self._modes
        if summary is not None:
            frame["modes_summary"] = summary

    def _stamped(self, frame: Frame) -> Frame:
        return {"tick": self._ticks, "time": round(self._manager.clock.now() - self._epoch, 3),
                "status": self._tree.root.status.value, **frame}

    def _emit(self, frame: Frame) -> None:
        self.last = frame
        for sink in self.sinks:
            sink(frame)

    def _changes(self, ticked: list[Behaviour], same_path: bool,
                 everyone: Iterable[Behaviour] | None) -> dict[str, dict[str, str]]:
        """What changed of the behaviours that can have changed (``everyone``: look at all)."""
        changes: dict[str, dict[str, str]] = {}
        shown = self._shown
        candidates = self._live.union(ticked)
        if everyone is not None:
            candidates.update(everyone)
        for behaviour in candidates:
            before = shown[behaviour]
            status = behaviour.status
            if status is before[0] and behaviour.feedback_message == before[1] and everyone is None:
                continue  # the detail goes with the status, except where a rescan finds otherwise
            feedback, detail = behaviour.feedback_message, detail_of(behaviour)
            if (status, feedback, detail) == before:
                continue
            shown[behaviour] = (status, feedback, detail)
            changes[self._ids[behaviour]] = self._update_json(behaviour, status, feedback, detail, before)
        if changes or not same_path:  # otherwise no status changed: the same ones are not INVALID
            self._live = {behaviour for behaviour in candidates if behaviour.status is not Status.INVALID}
        return changes

    def _update_json(self, behaviour: Behaviour, status: Status, feedback: str, detail: str,
                     before: tuple[Status, str, str]) -> dict[str, str]:
        json = self._json[self._ids[behaviour]]
        data = dict(json["data"], Feedback=feedback)
        change: dict[str, str] = {}
        if status is not before[0]:
            change["status"] = json["status"] = status.value
        if feedback != before[1]:
            change["feedback"] = feedback
        if detail != before[2]:
            change["details"] = json["details"] = detail or "..."
            data.pop("Detail", None)
            if detail:
                data["Detail"] = detail
        json["data"] = data  # a new dict: a key frame already handed on keeps its own
        return change

    def _reshaped(self) -> bool:
        return self._shape_of(list(self._tree.root.iterate())) != self._shape

    def _shape_of(self, behaviours: list[Behaviour]) -> list[tuple[str, tuple[str, ...]]]:
        ids = self._ids
        for behaviour in behaviours:
            if behaviour not in ids:
                ids[behaviour] = str(behaviour.id)
        return [(ids[behaviour], tuple(ids[child] for child in behaviour.children)) for behaviour in behaviours]

    def _key_frame(self, ticked: list[Behaviour]) -> Frame:
        """Every behaviour, the visited path, the blackboard and the table, in full."""
        behaviours = list(self._tree.root.iterate())
        self._ids = {behaviour: self._ids.get(behaviour) or str(behaviour.id) for behaviour in behaviours}
        self._shape = self._shape_of(behaviours)
        self._json = {self._ids[b]: behaviour_json(b, self._ids[b], self._ids) for b in behaviours}
        self._shown = {b: (b.status, b.feedback_message, detail_of(b)) for b in behaviours}
        self._live = {b for b in behaviours if b.status is not Status.INVALID}
        self._keys = {b: tuple(sorted({key for client in b.blackboards
                                       for key in (*client.read, *client.write, *client.exclusive)}))
                      for b in behaviours}
        self._last_ticked = ticked
        self._visited_keys = self._keys_of(ticked)
        self._blackboard = {}
        self._blackboard_changes()
        events = self._take_events()
        with self._events_lock:
            self._table_due = False
        self._modes = self._table()
        frame = {"key": True, "behaviours": {ident: dict(json) for ident, json in self._json.items()},
                 "visited": [self._ids[b] for b in ticked], "blackboard": dict(self._blackboard)}
        self._put_table(frame)
        if events:
            frame["events"] = events
        return self._stamped(frame)

    def _keys_of(self, behaviours: list[Behaviour]) -> list[str]:
        keys = self._keys
        return sorted({key for behaviour in behaviours for key in keys.get(behaviour, ())})

    def _blackboard_changes(self) -> dict[str, str]:
        """The visited behaviours' blackboard values that changed (``-``: not set)."""
        changed: dict[str, str] = {}
        storage, shown = Blackboard.storage, self._blackboard
        for key in self._visited_keys:
            text = str(storage[key]) if key in storage else "-"
            if shown.get(key) != text:
                shown[key] = changed[key] = text
        return changed

    def close(self) -> None:
        self._subscription.cancel()
        if self in self._tree.post_tick_handlers:
            self._tree.post_tick_handlers.remove(self)
        if self._ticked in self._tree.visitors:
            self._tree.visitors.remove(self._ticked)


def _describe(event: Event) -> str:
    if event.kind is EventKind.DIVERGENCE:
        return str(event.divergence) if event.divergence is not None else f"{event.part} back on target"
    return f"{event.kind.value} {event.part}"




def _mode_json(row: Row) -> dict[str, Any]:
    target = f"{row.target_state}.{row.target_mode}" if row.target_mode else row.target_state
    actual = f"{row.raw_state}.{row.raw_mode}" if row.raw_mode else row.raw_state
    return {"part": row.part, "kind": row.kind, "target": target, "actual": actual,
            "inferred": bool(row.state_inferred or row.mode_inferred),
            "cause": row.cause.value if row.cause is not None else None, "error": bool(row.error),
            "held_by": row.held_by or None}


__all__ = ["RESCAN", "Frame", "FrameMaker", "behaviour_json"]
