"""The backend's queue of reports: in order, one drainer at a time, run by the thread that heard them.

What an rclpy callback (an answer, an event) reports is run by that thread when the callback is
done, not handed to the clock's thread: a hop costs a wake-up on every change (docs/performance.md).
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import pytest

from sm_bt.engine.clock import VirtualClock
from sm_bt.ros.dispatch import Dispatcher

pytestmark = pytest.mark.ros


def recorder() -> tuple[list[tuple[str, str]], Callable[[str], Callable[[], None]]]:
    ran: list[tuple[str, str]] = []

    def action(name: str) -> Callable[[], None]:
        return lambda: ran.append((name, threading.current_thread().name))

    return ran, action


def test_outside_a_callback_the_clock_runs_the_reports_in_order() -> None:
    clock = VirtualClock()
    dispatcher = Dispatcher(clock)
    ran, action = recorder()
    dispatcher.put(action("a"))
    dispatcher.put(action("b"))
    assert ran == []  # never from inside the call that made them
    clock.run_pending()
    assert [name for name, _ in ran] == ["a", "b"]


def test_a_callback_runs_what_it_reported_when_it_is_done_in_its_own_thread() -> None:
    clock = VirtualClock()
    dispatcher = Dispatcher(clock)
    ran, action = recorder()

    def callback() -> None:
        with dispatcher.held():
            dispatcher.put(action("state"))
            with dispatcher.held():  # a nested callback (a future's done callback inside a handler)
                dispatcher.put(action("done"))
            assert ran == []  # not before the outer callback is done
        assert clock.next_due() is None  # no hop to the clock's thread

    heard = threading.Thread(target=callback, name="executor")
    heard.start()
    heard.join(5.0)
    assert ran == [("state", "executor"), ("done", "executor")]


def test_a_report_made_while_another_thread_drains_is_run_by_that_thread_in_turn() -> None:
    clock = VirtualClock()
    dispatcher = Dispatcher(clock)
    ran, action = recorder()
    inside, release = threading.Event(), threading.Event()

    def slow() -> None:
        inside.set()
        release.wait(5.0)
        ran.append(("slow", threading.current_thread().name))

    dispatcher.put(slow)
    draining = threading.Thread(target=clock.run_pending, name="clock")
    draining.start()
    assert inside.wait(5.0)

    def callback() -> None:
        with dispatcher.held():
            dispatcher.put(action("answer"))

    heard = threading.Thread(target=callback, name="executor")
    heard.start()
    heard.join(5.0)
    assert not heard.is_alive() and ran == []  # the callback did not wait for the other drainer
    release.set()
    draining.join(5.0)
    assert ran == [("slow", "clock"), ("answer", "clock")]


def test_a_report_that_fails_does_not_hold_back_the_next() -> None:
    dispatcher = Dispatcher(VirtualClock())
    ran, action = recorder()

    def broken() -> None:
        raise RuntimeError("a listener's bug")

    with dispatcher.held():
        dispatcher.put(broken)
        dispatcher.put(action("next"))
    assert [name for name, _ in ran] == ["next"]


def test_a_callback_that_reported_nothing_leaves_the_others_reports_to_them() -> None:
    dispatcher = Dispatcher(VirtualClock())
    ran, action = recorder()
    queued, leave = threading.Event(), threading.Event()

    def backend_callback() -> None:
        with dispatcher.held():
            dispatcher.put(action("answer"))
            queued.set()
            leave.wait(5.0)

    backend = threading.Thread(target=backend_callback, name="backend")
    backend.start()
    assert queued.wait(5.0)
    with dispatcher.held():  # the watching executor's probe answer, which reports nothing
        pass
    assert ran == []  # not run here: this thread's next answer is not held back by them
    leave.set()
    backend.join(5.0)
    assert ran == [("answer", "backend")]
