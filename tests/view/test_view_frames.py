"""The view's frames carry only what changed, and lose nothing: folded together they are the
whole tree, table and path at every tick of the demo; a recording is small, round-trips, and a
format-1 recording (a whole tree per frame) still reads. No browser here."""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import py_trees
import pytest
from rich.console import Console

from sm_bt.engine.manager import ModeManager
from sm_bt.monitor_rows import snapshot
from sm_bt.trees.pilot.demo import Demo, Options
from sm_bt.view import read_recording
from sm_bt.view.frames import Frame, FrameMaker, _mode_json, behaviour_json
from sm_bt.view.recording import HEADER, VERSION, fold


def table(manager: ModeManager) -> list[dict[str, Any]]:
    """Every part's row (the pilot has fewer parts than the view's table shows)."""
    return [_mode_json(row) for row in snapshot(manager)]

def _demo(**options: Any) -> Demo:
    return Demo(Options(speed=0.0, quiet=True, **options), Console(file=io.StringIO(), width=120))


def _whole(tree: py_trees.trees.BehaviourTree) -> dict[str, Any]:
    """What a frame of the whole tree would say now (made from scratch)."""
    behaviours = list(tree.root.iterate())
    ids = {behaviour: str(behaviour.id) for behaviour in behaviours}
    return {ids[b]: behaviour_json(b, ids[b], ids) for b in behaviours}


def _checking(demo: Demo, check: Callable[[Frame | None, Frame], None], rescan: int = 200) -> list[Frame]:
    """The frames of a demo run, ``check(frame or None, folded)`` after every tick."""
    frames: list[Frame] = []
    state: dict[str, Frame] = {}
    maker = FrameMaker(demo.tree, demo.manager, rescan=rescan)

    def sink(frame: Frame) -> None:
        frames.append(frame)
        state["now"] = fold(state["now"], frame) if state else frame

    made: dict[str, int] = {"count": 0}

    def after_tick(_: py_trees.trees.BehaviourTree) -> None:  # runs after the maker's handler
        new = len(frames) > made["count"]
        made["count"] = len(frames)
        check(frames[-1] if new else None, state["now"])

    maker.sinks.append(sink)
    demo.tree.add_post_tick_handler(after_tick)
    assert demo.run() == 0
    maker.close()
    return frames


def test_frames_folded_are_the_whole_tree_table_and_path_at_every_tick() -> None:
    demo = _demo(cycles=1)
    ticks = {"all": 0}

    def check(frame: Frame | None, state: Frame) -> None:
        ticks["all"] += 1
        assert state["behaviours"] == _whole(demo.tree), f"tick {ticks['all']}"
        assert set(state["visited"]) == {str(ident) for ident in demo.snapshot.visited}
        assert state["modes"] == table(demo.manager), f"the table at tick {ticks['all']}"
        if frame is not None:  # values go out with the frames that something else made
            for key in demo.snapshot.visited_blackboard_keys:
                stored = py_trees.blackboard.Blackboard.storage.get(key, "-")
                assert state["blackboard"][key] == str(stored), (key, ticks["all"])

    frames = _checking(demo, check)
    assert frames[0]["key"] and not any(frame.get("key") for frame in frames[1:])
    assert ticks["all"] > len(frames) > 100  # idle ticks make no frame
    changes = [frame for frame in frames if "changes" in frame]
    assert all(set(change) <= {"status", "feedback", "details"}
               for frame in changes for change in frame["changes"].values())
    kinds = {event["kind"] for frame in frames for event in frame.get("events", ())}
    assert {"request", "divergence", "failed"} <= kinds and not kinds & {"actual", "target"}
    requests = [event for frame in frames for event in frame.get("events", ()) if event["kind"] == "request"]
    assert all(isinstance(event["request"], int) and isinstance(event["done"], bool) for event in requests)
    assert any(event["done"] and event["ok"] for event in requests)


def test_a_change_of_the_trees_shape_makes_a_key_frame() -> None:
    demo = _demo(cycles=1, laser_failure_at=None)
    ticks = {"count": 0}
    gather = demo.root.children[0]  # ticked every time
    start_up = demo.root.children[1].children[0]  # never ticked again once done
    assert isinstance(gather, py_trees.composites.Sequence) and isinstance(start_up, py_trees.composites.Sequence)
    assert (gather.name, start_up.name) == ("Gather", "Start-up")

    def check(frame: Frame | None, state: Frame) -> None:
        ticks["count"] += 1
        late = 121 <= ticks["count"] < 140  # until the next look at the whole tree
        assert (state["behaviours"] == _whole(demo.tree)) is not late, f"tick {ticks['count']}"
        if ticks["count"] == 50:
            gather.add_child(py_trees.behaviours.Success("Added where ticked"))
        if ticks["count"] == 120:
            start_up.add_child(py_trees.behaviours.Success("Added where not ticked"))

    frames = _checking(demo, check, rescan=20)  # a look at the whole tree every 20 ticks
    keys = [frame["tick"] for frame in frames if frame.get("key")]
    assert keys == [1, 51, 140]


def test_a_recording_of_the_demo_is_small_and_reads_back(tmp_path: Path) -> None:
    recording = tmp_path / "run.jsonl"
    demo = _demo(record=str(recording))
    sent: list[Frame] = []
    assert demo.view is not None
    demo.view.maker.sinks.append(sent.append)
    assert demo.run() == 0
    size = recording.stat().st_size
    assert size <= 3_000_000, f"{size} bytes"  # format 1 wrote 28.8 MB
    first = json.loads(recording.read_text().splitlines()[0])
    assert first == HEADER and first["version"] == VERSION
    frames = read_recording(recording)
    assert frames == sent
    assert frames[-1]["status"] == "SUCCESS"
    whole = frames[0]
    for frame in frames[1:]:
        whole = fold(whole, frame)
    assert whole["behaviours"] == _whole(demo.tree)
    assert whole["modes"] == table(demo.manager)


def test_a_format_1_recording_reads_as_format_2(tmp_path: Path) -> None:
    """Format 1 (sm_bt before deltas): no header, the whole tree in every frame, and the parts'
    actual and target changes among the events."""
    frames = _checking(_demo(cycles=1), lambda frame, state: None)
    old = tmp_path / "old.jsonl"
    whole: Frame = {}
    with old.open("w") as file:
        for frame in frames:
            whole = fold(whole, frame) if whole else frame
            events = [*frame.get("events", ()), {"time": frame["time"], "kind": "actual", "part": "pilot",
                                                 "text": "pilot is active"}]
            file.write(json.dumps({
                "tick": frame["tick"], "time": frame["time"], "status": frame["status"], "modes": whole["modes"],
                "events": events,
                "tree": {"changed": "true", "timestamp": frame["time"], "visited_path": whole["visited"],
                         "behaviours": whole["behaviours"],
                         "blackboard": {"behaviours": {}, "data": whole["blackboard"]}},
            }) + "\n")
    read = read_recording(old)
    assert len(read) == len(frames) and read[0]["key"] and not any(frame.get("key") for frame in read[1:])
    assert old.stat().st_size > 5 * sum(len(json.dumps(frame)) for frame in read)  # deltas again
    again = read[0]
    for index, frame in enumerate(read[1:], 1):
        again = fold(again, frame)
        assert frame.get("events", []) == frames[index].get("events", [])
    assert again["behaviours"] == whole["behaviours"] and again["modes"] == whole["modes"]
    assert again["visited"] == whole["visited"] and again["blackboard"] == whole["blackboard"]


@pytest.mark.parametrize(("lines", "error"), [
    ([{"format": "sm-bt view", "version": VERSION + 1}], "newer than this sm-bt reads"),
    ([{"format": "something else", "version": 1}], "not a recording of sm-bt's view"),
    ([HEADER, {"tick": 1, "time": 0.0, "status": "RUNNING", "changes": {}}], ":2: the first frame is not a key frame"),
    ([HEADER, {"tick": 1, "time": 0.0}], ":2: not a frame of sm-bt's view (tick, time, status)"),
    ([{"tick": 1, "tree": {}, "modes": []}, {"oops": True}], ":2: not a frame of sm-bt's view (tick, tree, modes)"),
])
def test_a_recording_that_cannot_be_read_says_why(tmp_path: Path, lines: list[Any], error: str) -> None:
    path = tmp_path / "bad.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))
    with pytest.raises(ValueError, match=error.replace("(", r"\(").replace(")", r"\)")):
        read_recording(path)


def test_holds_begin_and_end_in_the_frames_events() -> None:
    demo = _demo(cycles=1, rules=True)
    frames = _checking(demo, lambda frame, folded: None)
    holds = [event["text"] for frame in frames for event in frame.get("events", []) if event["kind"] == "hold"]
    assert holds == [
        "pilot held in active.f_degraded_mode by rule degrade_from_normal (priority 100), while laser_resender is "
        "unconfigured",
        holds[1]]
    assert holds[1].startswith("pilot no longer held by rule degrade_from_normal: superseded by request #")
