"""The requests a fleet made of one robot's ``sm-bt manager``, until each one's outcome comes.

A fleet asks an sm-bt robot through its ``request_change`` service (with the fleet's requester, so
that the robot's holds and log name it), whose answer carries the robot's number of the request;
the robot says how each request ended on ``request_outcome`` (:mod:`sm_bt.ros.manager_node`). The
fleet's call is done when that outcome comes: a robot whose request fails fails the fleet's at once,
with the robot's reason, rather than at the fleet's timeout, as the simulated fleet's
(:class:`sm_bt.sim.remotes.RemoteManagers`) does.

An outcome may come before the answer that names its number (the topic and the service are two
channels): the fleet's own outcomes are kept until then. An answer may also never come: a server
that has not yet discovered a new client's reply reader drops its reply (seen under load, the
fleet's first change of a robot just started). So an outcome still unclaimed :data:`ANSWER_GRACE` s
later ends the one unanswered call that asked what it says (``settle``; what it asked is read from
the outcome's description, ``change_mode PART MODE``). A robot that goes out of reach fails the
requests it owes (its numbers start again if its manager restarts), and an outcome that never comes
fails its request after ``timeout`` seconds (the robot's requests all end within its own request
timeout: only a lost message gets there), unless the robot's events say it got where the request
leads (``reached``): under load a new fleet's first requests lost both their answers and their
outcomes (the robot had not yet matched the fleet's readers), while the robot's latched events came.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sm_bt.engine.backend import CallResult, Done
from sm_bt.engine.clock import Clock
from sm_bt.model.types import FLEET_REQUESTER

#: Outcomes of the fleet's requests kept while their answers are on the way (a few at most).
EARLY_OUTCOMES = 16
#: An outcome whose answer has not come this long after it ends the call without it: answers come
#: within milliseconds of their outcome, before or after.
ANSWER_GRACE = 0.5


@dataclass
class _Pending:
    label: str
    done: Done
    told_by: tuple[str, str] = ("", "")
    timer: Any = None


class RobotRequests:
    """The fleet's requests that ``part``'s manager accepted and has not ended yet. ``settle(told_by,
    result)``: end the unanswered call that asked ``told_by`` (``("change_mode", mode)``) with
    ``result``; True if there was one."""

    def __init__(self, part: str, clock: Clock, timeout: float, *,
                 settle: Callable[[tuple[str, str], CallResult], bool] = lambda told_by, result: False) -> None:
        self.part = part
        self._clock = clock
        self.timeout = timeout
        self._settle = settle
        self._lock = threading.Lock()
        self._pending: dict[int, _Pending] = {}
        self._early: OrderedDict[int, tuple[CallResult, tuple[str, str]]] = OrderedDict()

    def accepted(self, number: int, label: str, done: Done, told_by: tuple[str, str] = ("", "")) -> None:
        """Its manager accepted ``label`` (which asked ``told_by``) as request ``number``: ``done`` when
        it ends."""
        with self._lock:
            early = self._early.pop(number, None)
            if early is None:
                pending = _Pending(label, done, told_by)
                self._pending[number] = pending
                pending.timer = self._clock.call_later(self.timeout, lambda: self._expired(number, pending))
        if early is not None:
            done(early[0])

    def ended(self, message: Any) -> None:
        """A ``RequestOutcome`` of its manager (anybody's: only the fleet's own count)."""
        if message.requester != FLEET_REQUESTER:
            return
        number = int(message.request)
        outcome = str(message.outcome)
        result = CallResult(True) if outcome == "succeeded" else CallResult(
            False, f"its manager's request #{number} {outcome}: {message.reason}")
        words = str(message.description).split()
        told_by = (words[0], words[2]) if len(words) >= 3 else ("", "")
        with self._lock:
            pending = self._pending.pop(number, None)
            if pending is None:
                self._early[number] = (result, told_by)
                while len(self._early) > EARLY_OUTCOMES:
                    self._early.popitem(last=False)
        if pending is None:
            self._clock.call_later(ANSWER_GRACE, lambda: self._unclaimed(number))
            return
        self._finish(pending, result)

    def _unclaimed(self, number: int) -> None:
        """Outcome ``number`` is still without its answer: it ends the call that asked it, if one does."""
        with self._lock:
            early = self._early.get(number)
        if early is not None and self._settle(early[1], early[0]):
            with self._lock:
                self._early.pop(number, None)

    def reached(self, told_by: tuple[str, str]) -> bool:
        """Its manager's events say the robot is where the one request of the fleet's that asked
        ``told_by`` leads: that request succeeded, though its outcome did not come (lost: its writer
        had not matched the fleet's reader yet). False, and nothing done, unless exactly one did."""
        with self._lock:
            asked = [(number, pending) for number, pending in self._pending.items() if pending.told_by == told_by]
            if len(asked) != 1:
                return False
            del self._pending[asked[0][0]]
        self._finish(asked[0][1], CallResult(True))
        return True

    def lost(self, why: str) -> None:
        """Its manager is out of reach: what it owes fails (a new process numbers its requests anew)."""
        with self._lock:
            owed, self._pending = self._pending, {}
            self._early.clear()
        for number, pending in owed.items():
            self._finish(pending, CallResult(False, f"its manager went out of reach during its request #{number} "
                                                    f"({pending.label}): {why}"))

    def _expired(self, number: int, pending: _Pending) -> None:
        with self._lock:
            if self._pending.get(number) is not pending:
                return
            del self._pending[number]
        self._finish(pending, CallResult(False, f"its manager told no outcome of its request #{number} "
                                                f"({pending.label}) within {self.timeout:g} s"))

    @staticmethod
    def _finish(pending: _Pending, result: CallResult) -> None:
        if pending.timer is not None:
            pending.timer.cancel()
        pending.done(result)
