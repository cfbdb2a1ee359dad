"""The backend's calls: a call that ends while its "late" timer is firing leaves no timer behind; a
handler of an answer that raises, under rclpy's EventsExecutor, is logged and the process goes on."""

from __future__ import annotations

import subprocess
import sys
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


#: A process that calls a service of its own under rclpy's EventsExecutor, the answer's handler raising:
#: attached with on_answer (argv[1] == "guarded") or as rclpy has it.
_RAISING_HANDLER = """
import logging, sys
import rclpy
from lifecycle_msgs.srv import GetState
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.task import Future
from sm_bt.ros.node_calls import on_answer

logging.basicConfig(level=logging.ERROR, format="%(levelname)s %(message)s")
context = Context()
rclpy.init(context=context)
node = rclpy.create_node("raising", context=context)
node.create_service(GetState, "/raising/get_state", lambda request, response: response)
executor = rclpy_implementation.EventsExecutor(context)
executor.add_node(node)
client = node.create_client(GetState, "/raising/get_state")
assert client.wait_for_service(timeout_sec=10.0)

def handle(future):
    raise AttributeError("a bug in the handler")

future = client.call_async(GetState.Request())
if sys.argv[1] == "guarded":
    on_answer(future, handle, "get_state on raising")
else:
    future.add_done_callback(handle)
executor.spin_until_future_complete(Future(), timeout_sec=1.0)
print("went on", flush=True)
"""


@pytest.mark.parametrize("attached", ["guarded", "plain"])
def test_a_handler_of_an_answer_that_raises_is_logged_and_the_process_goes_on(attached: str) -> None:
    done = subprocess.run([sys.executable, "-c", _RAISING_HANDLER, attached], capture_output=True, text=True,
                          timeout=30)
    if attached == "plain":  # why on_answer exists: should rclpy change, this says so
        assert done.returncode == -11 and "went on" not in done.stdout, (done.returncode, done.stdout, done.stderr)
        return
    assert (done.returncode, done.stdout) == (0, "went on\n"), done.stderr
    assert "ERROR get_state on raising: handling its answer failed" in done.stderr, done.stderr
    assert "AttributeError: a bug in the handler" in done.stderr, done.stderr
