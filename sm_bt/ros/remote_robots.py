"""One robot of a fleet as :class:`~sm_bt.ros.remote_parts.RemoteBackend` knows it, and the calls
to its manager, each with a timeout and paced as its kind of manager needs.

The reference's answers run ahead of its events, and it takes its own node ``mode_event``s (sent
at its next 1 s tick) for news of its nodes: a request made before that tick is planned from a
wrong view and never ends (seen: ``deactivating`` for good). So after a change it accepted, its
word is taken from its events, from its answers only :data:`REFERENCE_EVENTS` s later (it
sometimes sends no event at all), and its next request is made no sooner, nor sooner than
:data:`REFERENCE_ECHO` s after its last event. sm-bt manager needs no pacing: a request to it only
waits, once after it comes in reach, for the fleet to hear its request outcomes (:data:`OUTCOMES_MATCH`).
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from sm_bt.engine.clock import WallClock
from sm_bt.model.states import State
from sm_bt.ros.node_calls import on_answer
from sm_bt.ros.remote_requests import RobotRequests

#: The reference sends a change's events at its 1 s timer's next tick, or the one after: its answers
#: are taken for news that long after a change it accepted (it sometimes sends no event at all).
REFERENCE_EVENTS = 2.2
#: After an event of the reference, its next request waits this long: its own node mode_events of
#: the same tick, which it takes for news of its nodes, are back with it by then.
REFERENCE_ECHO = 0.2
#: An sm-bt robot's request waits up to this long for the fleet's reader of its ``request_outcome``
#: to match the robot's writer (then until it is next out of reach, no more): that topic is volatile,
#: and it alone tells the end of a request whose answer was lost, as a new client's first answers are
#: when its reply reader matches late (seen under load: the fleet's first change over ten robots
#: waited the call's timeout for four of them).
OUTCOMES_MATCH = 2.0
#: How often the match is looked at meanwhile.
OUTCOMES_POLL = 0.02


@dataclass(frozen=True)
class Owed:
    """A change call its manager has not answered: ``fail(why)`` ends it failed. It may also end from
    the robot's own word, ``told(result)`` (False if the call had ended), once ``told_by`` (what it
    asked: ``("change_mode", mode)``) matches what an sm-bt robot's request outcome says it asked, or
    what the reference's event says its system reached."""

    fail: Callable[[str], None]
    told: Callable[[Any], bool] | None = None
    told_by: tuple[str, str] = ("", "")


@dataclass
class Robot:
    """A remote part, its manager's clients, and what the fleet knows of it (guarded by the
    backend's lock)."""

    part: str
    fqn: str
    change_state: Any
    get_state: Any
    change_mode: Any
    get_mode: Any
    reference: bool  # served by the reference's mode_manager
    request_change: Any  # an sm-bt manager's (None for the reference)
    preview_change: Any  # an sm-bt manager's (None for the reference)
    requests: RobotRequests | None  # what an sm-bt manager accepted and has not ended yet
    subscriptions: list[Any] = field(default_factory=list)
    liveliness: Any = None  # the subscription that asks for the lease of its manager's mode_event
    lively: bool = False  # DDS vouches for its manager's process (the lease's writer is alive)
    present: bool = False
    last_heard: float = float("-inf")
    probing: bool = False
    failed_at: float = float("-inf")  # when the last probe left unanswered was sent
    timer: Any = None  # the next probe
    generation: int = 0  # of the probes' chain: a probe of an older one does nothing
    #: As reported to the engine; ``mode`` of a robot that is not active: the one to activate it in.
    state: State = State.UNKNOWN
    mode: str = ""
    known: bool = False  # its manager has known its state
    assumed: bool = False  # taken for unconfigured while the reference still answers unknown
    reads_from: float = float("-inf")  # its answers are news from then on (the reference, after a change)
    requests_from: float = float("-inf")  # its next change request no sooner (the reference, after a change)
    events: int = 0  # events received: an answer to a call sent before the last one is older news
    asked: str | None = None  # a mode its manager accepted and has not reported yet: read at each probe
    mode_told: bool = False  # its manager's mode event came since the robot was last told in another state
    owed: dict[int, Owed] = field(default_factory=dict)  # change calls unanswered
    #: Its manager's services the graph showed this client since it was last in reach (see RobotCalls.change).
    seen_ready: set[Any] = field(default_factory=set)
    outcomes: Any = None  # the subscription to an sm-bt manager's request_outcome
    outcomes_matched: bool = False  # it matched the manager's writer since the robot was last in reach
    outcomes_due: float | None = None  # a request waits for that match until then (OUTCOMES_MATCH)


class RobotCalls:
    """Calls to robots' managers on ``clock``, ``lock`` being the backend's (it guards the robots)."""

    def __init__(self, clock: WallClock, lock: threading.Lock, call_timeout: float) -> None:
        self._clock = clock
        self._lock = lock
        self.call_timeout = call_timeout
        self._keys = itertools.count()

    def heard_event(self, robot: Robot) -> None:
        """(With the lock held.) An event of its manager: the reference has ticked."""
        robot.events += 1
        robot.last_heard = self._clock.now()
        if robot.reference:
            robot.requests_from = min(robot.requests_from, robot.last_heard + REFERENCE_ECHO)

    def change(self, robot: Robot, client: Any, request: Any, label: str, answered: Callable[[Any], None],
               failed: Callable[[str], None], *, told: Callable[[Any], None] | None = None,
               told_by: tuple[str, str] = ("", "")) -> None:
        """A change request (see :meth:`call`), owed until answered (:meth:`abandon`); to the
        reference, paced (see the module); to sm-bt manager, once its request outcomes reach the fleet
        (:data:`OUTCOMES_MATCH`). To a manager whose process DDS vouches for, it is sent
        without asking the graph whether the service is there, once the graph has shown it since the
        robot was last out of reach: a fleet's switch asks every robot at once, and that question,
        slow under load, let the first robots' work delay the rest of the sends (README, "Fleets").
        The first time, it is asked: until a client has seen the service, the answer may find no
        way back to it."""
        with self._lock:
            wait = robot.requests_from - self._clock.now() if robot.reference else self._unmatched(robot)
            vouched = robot.present and robot.lively
        if wait > 0:
            self._clock.call_later(wait, lambda: self.change(robot, client, request, label, answered, failed,
                                                             told=told, told_by=told_by))
            return

        def paced() -> None:
            if robot.reference:
                with self._lock:
                    robot.reads_from = robot.requests_from = self._clock.now() + REFERENCE_EVENTS

        def accepted(response: Any) -> None:
            if robot.reference and response.success:  # an sm-bt robot's answer has no success
                paced()
            answered(response)

        def told_so(result: Any) -> None:
            paced()
            assert told is not None
            told(result)

        self.call(robot, client, request, label, accepted, failed, checked=not vouched, owed=True,
                  told=None if told is None else told_so, told_by=told_by)

    def _unmatched(self, robot: Robot) -> float:
        """(With the lock held.) How long an sm-bt robot's request waits before it looks again whether
        its request_outcome reader matched (0: it did, or waited long enough; see OUTCOMES_MATCH)."""
        if robot.outcomes is None or robot.outcomes_matched:
            return 0.0
        if robot.outcomes.get_publisher_count() > 0:
            robot.outcomes_matched, robot.outcomes_due = True, None
            return 0.0
        now = self._clock.now()
        if robot.outcomes_due is None:
            robot.outcomes_due = now + OUTCOMES_MATCH
        return OUTCOMES_POLL if now < robot.outcomes_due else 0.0

    def abandon(self, robot: Robot, why: str) -> None:
        """Its manager is out of reach: the change requests it has not answered fail with ``why``, and
        its services are asked of the graph again (it may come back as another process), its
        request_outcome's match looked at again."""
        with self._lock:
            owed, robot.owed = list(robot.owed.values()), {}
            robot.seen_ready.clear()
            robot.outcomes_matched, robot.outcomes_due = False, None
        for call in owed:
            call.fail(why)

    def settle(self, robot: Robot, told_by: tuple[str, str], result: Any) -> bool:
        """Its manager told how a request of the fleet's ended (``told_by``: what it asked; the
        reference: an event saying it is there) while the call that made it is still unanswered: the
        answer was lost (a server that has not discovered a new client's reply reader drops the reply)
        or is late. The one such call ends with ``result`` and its answer, if it comes, is ignored.
        False, and nothing done, unless exactly one owed call asked that."""
        with self._lock:
            told = [call.told for call in robot.owed.values() if call.told is not None and call.told_by == told_by]
        return len(told) == 1 and told[0](result)

    def call(self, robot: Robot, client: Any, request: Any, label: str, answered: Callable[[Any], None],
             failed: Callable[[str], None], timeout: float | None = None, *, checked: bool = True,
             owed: bool = False, told: Callable[[Any], None] | None = None,
             told_by: tuple[str, str] = ("", "")) -> None:
        """``request`` on ``client``: ``answered(response)``, or ``failed(why)`` once ``timeout`` passed
        (the call timeout unless given); ``checked`` (or never seen since it was in reach): at once if
        the graph shows no such service. ``owed``: :meth:`abandon` fails it too, and ``told(result)``
        ends it instead of its answer when :meth:`settle` says so. Any answer is word from its manager."""
        with self._lock:
            checked = checked or client not in robot.seen_ready
        if checked:
            if not client.service_is_ready():
                self._clock.call_later(0.0, lambda: failed(f"{robot.fqn}: no manager serves it ({label})"))
                return
            with self._lock:
                robot.seen_ready.add(client)
        future = client.call_async(request)
        key = next(self._keys)
        ended = [False]

        def first() -> bool:
            """The first of its answer, its timeout and its abandonment (each from its own thread)."""
            with self._lock:
                was, ended[0] = ended[0], True
                robot.owed.pop(key, None)
            return not was

        def on_done(_: Any) -> None:
            if not first():
                return
            response = future.result()
            with self._lock:
                robot.last_heard = self._clock.now()
            answered(response)

        def given_up(why: str) -> None:
            if first():
                client.remove_pending_request(future)
                failed(why)

        def settled(result: Any) -> bool:
            if not first():
                return False
            client.remove_pending_request(future)
            assert told is not None
            told(result)
            return True

        limit = timeout if timeout is not None else self.call_timeout
        if owed:  # before it can end: its callbacks are not attached yet
            with self._lock:
                robot.owed[key] = Owed(given_up, settled if told is not None else None, told_by)
        on_answer(future, on_done, f"{label} to {robot.fqn}")
        self._clock.call_later(limit, lambda: given_up(f"the manager of {robot.part} did not answer {label} "
                                                        f"within {limit:g} s"))
