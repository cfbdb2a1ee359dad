"""The backend's calls: a call that ends while its "late" timer is firing leaves no timer behind."""

from __future__ import annotations

import threading
from typing import Any

import pytest

from sm_bt.engine.clock import VirtualClock

pytestmark = pytest.mark.ros


class _Future:
    def __init__(self) -> None:
        self.callbacks: list[Any] = []

    def add_done_callback(self, callback: Any) -> None:
        self.callbacks.append(callback)

    def done(self) -> bool:
        return False

    def cancelled(self) -> bool:
        return False

    def cancel(self) -> None:
        pass


class _Client:
    srv_name = "/amcl/get_state"

    def call_async(self, request: Any) -> _Future:
        return _Future()

    def remove_pending_request(self, future: Any) -> None:
        pass


def test_a_call_ended_while_its_late_timer_fires_keeps_no_timer_and_is_not_reported_late() -> None:
    """Seen under load: the "late" timer fired in the clock's thread while an answer ended the call
    in another; it re-armed the timeout, which then held the finished call until it fired."""
    from sm_bt.ros.node_calls import NodeCalls
    from sm_bt.ros.peers import Peer

    clock = VirtualClock()
    calls = NodeCalls(None, threading.Lock(), clock, process_heard=lambda peer: 0.0,  # type: ignore[arg-type]
                      on_answered=lambda call, now: None, heard=lambda handler, *args: handler(*args),
                      listening=lambda: True)
    peer = Peer("amcl", "/amcl", (), None, None, None, None, None, None)
    late: list[object] = []
    call = calls.call(peer, _Client(), object(), "get_state (liveness)", 1.0, lambda response: None,
                      lambda reason: None, busy=False, probe=True, late=(0.1, late.append))
    assert call.timer is not None
    firing = call.timer.callback  # the "late" timer's callback, as the clock thread is about to run it
    calls.finish(call, response=object())  # the answer, in another thread
    firing()
    assert late == [] and call.timer is None
    assert clock.next_due() is None, "a live timer still holds the finished call"
