"""The collector pause around big builds: it nests, it is shared by threads, and it restores what
the process had (a process that turned the collector off keeps it off)."""

from __future__ import annotations

import gc
import threading
from collections.abc import Iterator

import pytest

from sm_bt.engine.manager import ModeManager
from sm_bt.model.errors import ModelError
from sm_bt.model.gc_tuning import LONG_RUN_THRESHOLDS, freeze_long_lived, gc_paused
from sm_bt.model.loader import load_model_text
from sm_bt.sim import SimBackend

MODEL = """
robot:
  ros__parameters:
    type: system
    parts: [camera]
    modes:
      __DEFAULT__: {camera: active}
camera:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters: {rate: 10}
"""


@pytest.fixture()
def collector_on() -> Iterator[None]:
    was = gc.isenabled()
    gc.enable()
    yield
    if not was:
        gc.disable()


def test_nested_pauses_turn_the_collector_back_on_only_when_the_outer_one_ends(collector_on: None) -> None:
    with gc_paused():
        assert not gc.isenabled()
        with gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled(), "the inner pause ended, the outer one still holds"
    assert gc.isenabled()


def test_a_process_that_turned_the_collector_off_keeps_it_off(collector_on: None) -> None:
    gc.disable()
    with gc_paused():
        pass
    assert not gc.isenabled()


def test_an_error_inside_still_ends_the_pause(collector_on: None) -> None:
    with pytest.raises(RuntimeError), gc_paused():
        raise RuntimeError("boom")
    assert gc.isenabled()


def test_overlapping_pauses_of_two_threads_leave_the_collector_on(collector_on: None) -> None:
    # A first, B inside it, A ends before B: a save-and-restore per pause would leave it off.
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen_by_b: list[bool] = []

    def first() -> None:
        with gc_paused():
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def second() -> None:
        a_in.wait(5)
        with gc_paused():
            b_in.set()
            a_out.wait(5)
            seen_by_b.append(gc.isenabled())

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(10)
    assert a_out.is_set() and b_in.is_set()
    assert seen_by_b == [False], "B's pause still holds after A's ended"
    assert gc.isenabled()


def test_loading_a_model_and_building_a_manager_leave_the_collector_as_it_was(collector_on: None) -> None:
    model = load_model_text(MODEL, "robot.yaml")
    assert gc.isenabled()
    manager = ModeManager(model, SimBackend(model))
    assert gc.isenabled()
    assert manager.actual("camera").known
    with pytest.raises(ModelError, match=r"robot\.yaml"):
        load_model_text(MODEL.replace("type: node", "type: nod"), "robot.yaml")
    assert gc.isenabled(), "a model error ends the pause too"


def test_freezing_keeps_what_exists_out_of_the_passes_and_makes_them_rarer() -> None:
    before = gc.get_threshold()
    kept = [object() for _ in range(10)], {"a": [1]}
    try:
        freeze_long_lived()
        assert gc.get_threshold() == LONG_RUN_THRESHOLDS
        assert gc.get_freeze_count() > 0
        assert not any(item is kept for item in gc.get_objects()), "frozen objects are out of every generation"
    finally:
        gc.unfreeze()
        gc.set_threshold(*before)
