"""Frames on disk, and frames folded together.

A recording (``.jsonl``) is one JSON object per line: a header ``{"format": "sm-bt view",
"version": 2}``, then the frames of :mod:`sm_bt.view.frames` as they were sent, the first a key
frame. Format 1 (no header, the whole tree in every frame, 20 kB a frame) is still read: its frames
are turned into format 2 on the way in. A newer format is refused with a message saying so.

:func:`fold` merges a frame into the key frame before it, giving the key frame of the later one:
the server does it to drop its oldest frames without losing the state they built.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sm_bt.view.frames import Frame

FORMAT = "sm-bt view"
VERSION = 2
HEADER = {"format": FORMAT, "version": VERSION}


class Recorder:
    """A sink that appends every frame to a ``.jsonl`` file, after the format's header."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._file = self.path.open("w", encoding="utf-8")
        self._file.write(encode(HEADER) + "\n")

    def __call__(self, frame: Frame) -> None:
        self._file.write(encode(frame) + "\n")
        self._file.flush()  # a run that is killed still leaves a recording up to its last tick

    def close(self) -> None:
        self._file.close()


def encode(frame: Frame) -> str:
    return json.dumps(frame, separators=(",", ":"))


def read_recording(path: str | Path) -> list[Frame]:
    """The frames of a recording (format 2, or 1 turned into 2); ``ValueError`` naming the first
    line that is not a frame, or saying the format is too new."""
    frames: list[Frame] = []
    version = 0  # not known until the first line
    with Path(path).open(encoding="utf-8") as file:
        for number, line in enumerate(file, 1):
            if not line.strip():
                continue
            try:
                frame = json.loads(line)
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}:{number}: not JSON ({error.msg})") from None
            if not version:
                version = _version(path, number, frame)
                if version == VERSION:
                    continue  # the header
            if version == 1 and (not isinstance(frame, dict) or not {"tick", "tree", "modes"} <= frame.keys()
                                 or not isinstance(frame["tree"], dict)):
                raise ValueError(f"{path}:{number}: not a frame of sm-bt's view (tick, tree, modes)")
            if version == VERSION:
                if not isinstance(frame, dict) or not {"tick", "time", "status"} <= frame.keys():
                    raise ValueError(f"{path}:{number}: not a frame of sm-bt's view (tick, time, status)")
                if not frames and not frame.get("key"):
                    raise ValueError(f"{path}:{number}: the first frame is not a key frame (the recording lost "
                                     "its start)")
            frames.append(frame)
    return upgrade(frames) if version == 1 else frames


def _version(path: str | Path, number: int, first: Any) -> int:
    """The format a recording's first line says (1: no header, the whole tree in every frame)."""
    if not isinstance(first, dict) or "format" not in first:
        return 1
    if first.get("format") != FORMAT or not isinstance(first.get("version"), int):
        raise ValueError(f"{path}:{number}: not a recording of sm-bt's view ({first.get('format')!r})")
    if first["version"] > VERSION:
        raise ValueError(f"{path}: a recording of format {first['version']}, newer than this sm-bt reads "
                         f"(formats 1 to {VERSION}): read it with the sm-bt that wrote it, or a newer one")
    if first["version"] < VERSION:
        raise ValueError(f"{path}:{number}: format {first['version']} has no header line")
    return VERSION


def upgrade(frames: Iterable[Frame]) -> list[Frame]:
    """Format 1 frames (a whole tree each) as format 2: a key frame, then what changed."""
    upgraded: list[Frame] = []
    before: Frame | None = None
    for old in frames:
        tree = old["tree"]
        behaviours: dict[str, Any] = tree.get("behaviours", {})
        blackboard = dict((tree.get("blackboard") or {}).get("data", {}))
        events = [event for event in old.get("events", ()) if event.get("kind") not in ("actual", "target")]
        frame: Frame = {"tick": old["tick"], "time": old.get("time", tree.get("timestamp", 0.0)),
                        "status": old.get("status", "INVALID")}
        if before is None or _shape(before["tree"]["behaviours"]) != _shape(behaviours):
            frame.update(key=True, behaviours=behaviours, visited=tree.get("visited_path", []),
                         blackboard=blackboard, modes=old["modes"])
        else:
            was = before["tree"]
            changes = {ident: change for ident, json in behaviours.items()
                       if (change := _changed(was["behaviours"][ident], json))}
            if changes:
                frame["changes"] = changes
            if tree.get("visited_path") != was.get("visited_path"):
                frame["visited"] = tree.get("visited_path", [])
            old_blackboard = (was.get("blackboard") or {}).get("data", {})
            changed = {key: value for key, value in blackboard.items() if old_blackboard.get(key) != value}
            if changed:
                frame["blackboard"] = changed
            if old["modes"] != before["modes"]:
                frame["modes"] = old["modes"]
        if events:
            frame["events"] = events
        upgraded.append(frame)
        before = old
    return upgraded


def _shape(behaviours: dict[str, Any]) -> dict[str, tuple[Any, ...]]:
    """What a delta cannot change: the behaviours, their names, classes, colours and children."""
    return {ident: (json.get("name"), json.get("colour"), (json.get("data") or {}).get("Class"),
                    tuple(json.get("children", ()))) for ident, json in behaviours.items()}


def _changed(before: dict[str, Any], after: dict[str, Any]) -> dict[str, str]:
    change: dict[str, str] = {}
    if after.get("status") != before.get("status"):
        change["status"] = after.get("status", "INVALID")
    feedback = (after.get("data") or {}).get("Feedback", "")
    if feedback != (before.get("data") or {}).get("Feedback", ""):
        change["feedback"] = feedback
    if after.get("details") != before.get("details"):
        change["details"] = after.get("details", "...")
    return change


def fold(key: Frame, frame: Frame) -> Frame:
    """The key frame of ``frame``'s tick, from the key frame before it (neither is changed)."""
    if frame.get("key") or not key.get("key"):  # nothing to fold into: the frames were not from a FrameMaker
        return frame
    behaviours = dict(key["behaviours"])
    for ident, change in frame.get("changes", {}).items():
        behaviours[ident] = apply(behaviours[ident], change)
    folded: Frame = {"tick": frame["tick"], "time": frame["time"], "status": frame["status"], "key": True,
                     "behaviours": behaviours, "visited": frame.get("visited", key["visited"]),
                     "blackboard": {**key.get("blackboard", {}), **frame.get("blackboard", {})},
                     "modes": frame.get("modes", key["modes"])}
    summary = frame.get("modes_summary") if "modes" in frame else key.get("modes_summary")
    if summary is not None:  # it travels with the table it sums up
        folded["modes_summary"] = summary
    if frame.get("events"):
        folded["events"] = frame["events"]
    return folded


def apply(behaviour: dict[str, Any], change: dict[str, str]) -> dict[str, Any]:
    """A behaviour (py_trees_js's format) with a frame's ``change`` made (a new dict)."""
    data = dict(behaviour.get("data", {}))
    updated = {**behaviour, "data": data}
    if "status" in change:
        updated["status"] = change["status"]
    if "feedback" in change:
        data["Feedback"] = change["feedback"]
    if "details" in change:
        updated["details"] = change["details"]
        data.pop("Detail", None)
        if change["details"] != "...":
            data["Detail"] = change["details"]
    return updated


__all__ = ["FORMAT", "HEADER", "VERSION", "Recorder", "apply", "encode", "fold", "read_recording", "upgrade"]
