"""The calls :class:`~sm_bt.ros.backend.RosBackend` makes to its nodes' services, each with a timeout.

A call that times out fails and is removed from the client (rclpy would keep it forever); a change
(``busy``) waits for as long as the node's process gives signs of life, since a node in a long
transition answers nothing meanwhile; a change abandoned unanswered gets its client replaced, so
that DDS never delivers it late. A finished call lets go of everything that refers back to it.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable
from typing import Any

from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParametersAtomically
from rclpy.node import Node

from sm_bt.engine.clock import Clock
from sm_bt.ros.peers import SLACK, NodeCall, Peer

log = logging.getLogger("sm_bt.ros.backend")


def answer(client: Any, request: Any, timeout: float) -> Any | None:
    """``client``'s answer to ``request``, waited for up to ``timeout`` s while another thread spins
    its node; None if none came (the request is then removed: the client would keep it forever). An
    error the call ended with is raised."""
    done = threading.Event()
    future = client.call_async(request)
    future.add_done_callback(lambda _: done.set())
    if not done.wait(timeout):
        client.remove_pending_request(future)
        return None
    return future.result()


def on_answer(future: Any, handle: Callable[[Any], None], what: str) -> None:
    """``future.add_done_callback(handle)``, what ``handle`` raises logged (with ``what``, the call).
    Under rclpy's EventsExecutor an exception out of a future's done-callback ends the process with a
    segmentation fault (rclpy 7.1.6; out of a timer, it ends the spin): a bug in a handler must cost
    one call, said in the log, not the manager."""

    def handled(done: Any) -> None:
        try:
            handle(done)
        except Exception:
            log.exception("%s: handling its answer failed", what)

    future.add_done_callback(handled)


class NodeCalls:
    """Calls through the clients of ``node``, timed by ``clock``, booked under ``lock`` (the
    backend's). ``process_heard(peer)``: when ``peer``'s process was last heard (lock held);
    ``on_answered(call, now)``: an answer came (lock held); ``heard(handler, *args)`` runs an rclpy
    callback (the backend's hand-off); ``listening()``: the backend is attached."""

    def __init__(self, node: Node, lock: threading.Lock, clock: Clock, *, process_heard: Callable[[Peer], float],
                 on_answered: Callable[[NodeCall, float], None], heard: Callable[..., None],
                 listening: Callable[[], bool]) -> None:
        self._node = node
        self._lock = lock
        self._clock = clock
        self._process_heard = process_heard
        self._on_answered = on_answered
        self._heard = heard
        self._listening = listening

    def call(self, peer: Peer, client: Any, request: Any, label: str, timeout: float,
             on_result: Callable[[Any], None], on_failure: Callable[[str], None], *, busy: bool = True,
             probe: bool = False, late: tuple[float, Callable[[NodeCall], None]] | None = None) -> NodeCall:
        """Send ``request``; ``late=(after, on_late)``: ``on_late(call)`` if unanswered ``after`` s
        (the timer of the timeout serves both: nothing more to arm for a call answered in time)."""
        call = NodeCall(peer, label, client, on_result=on_result, on_failure=on_failure, busy=busy,
                        sent=self._clock.now(), probe=probe)
        with self._lock:
            peer.calls.add(call)

        expire = functools.partial(self._expire, call, timeout)
        if late is not None and late[0] < timeout:
            after, on_late = late

            def overdue() -> None:
                if call.finished:  # its end cancelled this timer too late: nothing to re-arm
                    return
                timer = self._clock.call_later(timeout - after, expire)
                call.timer = timer
                if call.finished:  # ended by another thread meanwhile, which cancelled the timer before
                    timer.cancel()
                    call.timer = None
                    return
                on_late(call)
            call.timer = self._clock.call_later(after, overdue)
        else:
            call.timer = self._clock.call_later(timeout, expire)
        future = client.call_async(request)
        call.future = future
        on_answer(future, lambda done: self._on_answer(call, done), f"{label} on {peer.part}")
        return call

    def _expire(self, call: NodeCall, timeout: float) -> None:
        """``call``'s timeout: a change waits for as long as its process gives signs of life (see
        :meth:`~sm_bt.ros.liveness.Liveness.working`); a query fails ``timeout`` s after it was sent."""
        if call.finished:
            return
        if call.busy:
            with self._lock:
                heard = max(call.sent, self._process_heard(call.peer))
            wait = heard + timeout - self._clock.now()
            if wait > SLACK:
                call.timer = self._clock.call_later(wait, functools.partial(self._expire, call, timeout))
                return
            failure = f"{call.label} on {call.peer.part}: no answer, and no word from its process for {timeout:g} s"
        else:
            failure = f"{call.label} on {call.peer.part}: no answer within {timeout:g} s"
        self.finish(call, failure=failure)

    def _on_answer(self, call: NodeCall, future: Any) -> None:
        # A cancelled one calls back in the thread that cancelled it (maybe inside the manager):
        # nothing to report. Answers come from the executor.
        if not future.cancelled():
            self._heard(self._answered, call, future)

    def _answered(self, call: NodeCall, future: Any) -> None:
        error = future.exception()
        if error is not None:
            self.finish(call, failure=f"{call.label} on {call.peer.part} failed: {error}")
            return
        with self._lock:
            call.peer.last_heard = now = self._clock.now()
            self._on_answered(call, now)
        self.finish(call, response=future.result())

    def finish(self, call: NodeCall, *, response: Any = None, failure: str | None = None) -> None:
        with self._lock:
            if call.finished:
                return
            call.finished = True
            call.peer.calls.discard(call)
            if call.busy:  # its outcome is reported next (outside the lock): a probe answered meanwhile is stale
                call.peer.settled = self._clock.now()
            retired = call.client in call.peer.retired and not any(
                other.client is call.client for other in call.peer.calls)
            if retired:
                call.peer.retired.remove(call.client)
        # The call lets go of its timer, future and callbacks: each refers back to it, and a cycle
        # is left to the garbage collector (hundreds of objects per request of 20 nodes).
        timer, future, on_result, on_failure = call.timer, call.future, call.on_result, call.on_failure
        call.timer = call.future = call.on_result = call.on_failure = None
        if timer is not None:
            timer.cancel()
        if future is not None and not future.done():  # its answer, if it comes, is dropped
            call.client.remove_pending_request(future)
            if failure is not None:  # (cancelling runs its callbacks in the executor: not for a success)
                future.cancel()
                if call.busy and self._listening():
                    self._renew_client(call)
        if retired:  # replaced earlier; this was the last call of ours on it
            self._node.destroy_client(call.client)
        if failure is not None:
            if on_failure is not None:
                on_failure(failure)
        elif on_result is not None:
            on_result(response)

    def _renew_client(self, call: NodeCall) -> None:
        """A change abandoned unanswered must never be carried out late: its request may still sit
        in the client's DDS writer, which re-sends it once the network heals. A fresh client takes
        its place; the old one (with its writer) goes once no call of ours is left on it."""
        peer, old = call.peer, call.client
        kind, attribute = ((ChangeState, "change_state") if old is peer.change_state
                           else (SetParametersAtomically, "set_parameters") if old is peer.set_parameters
                           else (None, ""))
        if kind is None:
            return  # renewed already
        with self._lock:
            fresh = self._node.create_client(kind, old.srv_name)
            setattr(peer, attribute, fresh)
            in_use = any(other.client is old and not other.finished for other in peer.calls)
            if in_use:
                peer.retired.append(old)
        if not in_use:
            self._node.destroy_client(old)
        log.debug("%s: a fresh client, the abandoned request is dropped with the old one", old.srv_name)
