"""When each robot of a fleet is probed, and the verdict that its manager is out of reach.

:class:`~sm_bt.ros.remote_parts.RemoteBackend` asks each robot's manager ``get_state`` (a probe) at
a pace set by what it knows: every ``probe_interval`` s while the robot is out of reach, while a
change it accepted is unconfirmed, or before DDS has vouched for its manager; every
``slow_probe_interval`` s while DDS vouches for it (its liveliness, :mod:`~sm_bt.ros.remote_liveliness`).
Nothing heard for ``liveness_timeout`` s from a manager DDS does not vouch for, or DDS's word that
its lease was lost, makes it out of reach; so does a probe left unanswered for the window, asked
again at once and still unanswered a fast interval later, from a manager DDS vouches for (its Python
hangs while its DDS threads live). Silence counts only from when this process last went on after
standing still itself (:attr:`~sm_bt.engine.clock.WallClock.resumed`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from lifecycle_msgs.srv import GetState

from sm_bt.engine.clock import WallClock
from sm_bt.model.states import State
from sm_bt.ros.peers import SLACK, state_of
from sm_bt.ros.remote_robots import Robot, RobotCalls

log = logging.getLogger("sm_bt.ros.remote_parts")  # the fleet backend's, as its users configure it

#: A liveliness lost is judged this much later. Right after this process stood still (stopped,
#: starved), DDS's lease timer may fire before the assertions that waited in its sockets are read:
#: seen over UDP after stalls of 1-5 s, the writer alive again 1-5 ms after its loss, while the clock
#: had not always seen the stall yet (it sees one only at a timer due meanwhile).
LIVELINESS_GRACE = 0.05


class RobotProbes:
    """The probes of robots whose records ``lock`` guards, on ``clock``, through ``calls``.
    ``listening()`` (lock held): the backend is attached; ``answered(robot, state, events)``: a probe's
    answer (``events``: the robot's events count when it was sent); ``read(robot, mode)``: read its
    mode, a change to ``mode`` being unconfirmed; ``unanswered(robot, why)``: it is out of reach."""

    def __init__(self, clock: WallClock, lock: threading.Lock, calls: RobotCalls, *, probe_interval: float,
                 liveness_timeout: float, slow_probe_interval: float, listening: Callable[[], bool],
                 answered: Callable[[Robot, State, int], None], read: Callable[[Robot, str], None],
                 unanswered: Callable[[Robot, str], None]) -> None:
        self._clock = clock
        self._lock = lock
        self._calls = calls
        self.probe_interval = probe_interval
        self.liveness_timeout = liveness_timeout
        self.slow_probe_interval = slow_probe_interval
        self._listening = listening
        self._answered = answered
        self._read = read
        self._unanswered = unanswered

    def schedule(self, robot: Robot, delay: float) -> None:
        """(With the lock held.) Its next probe in ``delay`` s, instead of the one planned."""
        if robot.timer is not None:
            robot.timer.cancel()
        robot.generation += 1
        generation = robot.generation
        robot.timer = self._clock.call_later(delay, lambda: self._probe(robot, generation))

    def _probe(self, robot: Robot, generation: int) -> None:
        with self._lock:
            if not self._listening() or generation != robot.generation:
                return
            asking = not robot.probing
            robot.probing = True
            sent = self._clock.now()
            events = robot.events
            reading = robot.asked if robot.present and robot.state is State.ACTIVE else None
            # The verdict falls due one window after the last word, not at the next probe's tick.
            due = max(0.0, robot.last_heard + self.liveness_timeout - sent)
            # DDS vouches for its process, it answered its last probe and owes no report: at the slow pace.
            vouched = robot.present and robot.lively and robot.asked is None and robot.failed_at <= robot.last_heard
            interval = self.slow_probe_interval if vouched else self.probe_interval
            robot.timer = self._clock.call_later(interval, lambda: self._probe(robot, generation))
        self._judge(robot)
        if asking:
            self._calls.call(robot, robot.get_state, GetState.Request(), "get_state (liveness)",
                             lambda response: self._answered(robot, state_of(response.current_state.id), events),
                             lambda why: self._probe_failed(robot, sent), timeout=self.liveness_timeout)
        if reading is not None:  # a manager that sends no event (the reference, at times) is read
            self._read(robot, reading)
        if due < self.probe_interval:
            self._clock.call_later(due + SLACK, lambda: self._judge(robot))

    def _judge(self, robot: Robot) -> None:
        """Out of reach once nothing was heard from its manager for the window, unless DDS vouches
        for its process (then its probes tell a hang: :meth:`_probe_failed`)."""
        with self._lock:
            # Not before this process last stood still itself: it heard nothing meanwhile.
            heard = max(robot.last_heard, self._clock.resumed)
            silent = (self._listening() and robot.present and not robot.lively
                      and self._clock.now() - heard >= self.liveness_timeout)
            if silent:
                robot.present = False
        if silent:
            self._unanswered(robot, "it exited, or the network is cut")

    def lively(self, robot: Robot, info: Any) -> None:
        """(The liveliness thread.) DDS's word on its manager's lease (``info``: a
        QoSLivelinessChangedInfo): ``alive_count`` writers of its ``mode_event`` assert it. None
        left: judged :data:`LIVELINESS_GRACE` s later (its last word came at least a window ago,
        unless an answer came later), and probed at the fast pace; back: heard, and read afresh at once if it was out of
        reach."""
        alive = int(info.alive_count)
        with self._lock:
            if not self._listening():
                return
            was, lively = robot.lively, alive > 0
            robot.lively = lively
            if lively and not was:
                robot.last_heard = max(robot.last_heard, self._clock.now())
                if not robot.present:
                    self.schedule(robot, 0.0)
            elif was and not lively:  # the probe judges it, on the clock's thread (after its late timers)
                self.schedule(robot, LIVELINESS_GRACE)
        if lively != was:
            log.debug("%s: its manager's liveliness %s (%d alive)", robot.part, "back" if lively else "lost", alive)

    def no_lease(self, robot: Robot, info: Any) -> None:
        """(The liveliness thread.) A writer of its ``mode_event`` offers no lease the fleet can use."""
        log.warning("%s: a writer of %s/mode_event offers no liveliness lease of at most %g s (the reference, or "
                    "an older sm-bt manager?): its manager is probed every %g s", robot.part, robot.fqn,
                    self.liveness_timeout, self.probe_interval)

    def _probe_failed(self, robot: Robot, sent: float) -> None:
        """A probe sent at ``sent`` unanswered (or no manager serves it). While DDS vouches for its
        process, a probe unanswered for the window is asked again at once (out of reach: it is about
        to answer, busy with what piled up while it stood still); in reach, if still nothing has come
        a fast probe interval later, its manager is out of reach (hung, its DDS threads alive)."""
        with self._lock:
            robot.probing = False
            timed_out = self._clock.now() - max(sent, self._clock.resumed) >= self.liveness_timeout - SLACK
            doubted = robot.present and robot.lively and robot.last_heard < sent
            suspect = doubted and timed_out
            if doubted:
                robot.failed_at = max(robot.failed_at, sent)
            if robot.lively and timed_out and (suspect or not robot.present):
                self.schedule(robot, 0.0)
        if suspect:
            self._clock.call_later(self.probe_interval, lambda: self._hung(robot, sent))

    def _hung(self, robot: Robot, sent: float) -> None:
        with self._lock:
            hung = (self._listening() and robot.present and robot.lively and robot.last_heard < sent
                    and self._clock.now() - max(sent, self._clock.resumed) >= self.liveness_timeout)
            if hung:
                robot.present = False
        if hung:
            self._unanswered(robot, "DDS still sees its process: it hangs?")
