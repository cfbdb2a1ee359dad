"""The ROS 2 backend of a fleet: remote parts driven through the system_modes interface of their managers.

Each remote part (``type: remote``, :mod:`sm_bt.model.remote_parts`) is a system that another mode
manager serves at ``Remote.fqn`` (``/robot1/pilot``): ``sm-bt manager`` in the robot's namespace, or
the reference's ``mode_manager``. :class:`RemoteBackend` speaks to it as any client does:

* its state and mode are read with ``get_state``/``get_mode`` when it appears and after it was out
  of reach (the heal), then followed on its ``transition_event``/``mode_event`` (the reference
  sends those from a 1 s timer), and on the liveness probes' answers (below): a state event that
  never came (the reference sometimes sends none) is corrected by the next probe;
* a change of state is its ``change_state`` (transition id and label: the reference reads the
  id), except activation, which is its ``change_mode`` to the mode the fleet wants it in: both
  managers activate a system into the mode asked for, while the reference's ``activate`` means
  ``__DEFAULT__``. A change of mode of an active robot is its ``change_mode``; of one that is not
  active, it is kept for its activation (to the engine, the mode of a robot that is not active is
  the one it will be activated in). An answer ``success`` means accepted, and the change counts
  as done once the robot reports it;
* liveness: ``get_state`` every ``probe_interval`` s; no answer for ``liveness_timeout`` s makes it
  out of reach ("no answer from the manager of robot1 ..."), and the fleet's rules react. While
  out of reach it is asked again every probe; the first answer is its reappearance. A manager
  that answers ``unknown`` has lost its part (its nodes are out of its reach), except before it
  has ever known it: the reference (``served_by: reference``) learns states only from its nodes'
  events, so until a node moves it knows nothing of nodes that wait unconfigured, and the part is
  taken for unconfigured;
* liveliness (a robot served by sm-bt manager): each probe costs this process about a millisecond
  of Python, so fast probes of many robots cost a few percent of a core. sm-bt manager's
  ``mode_event`` offers a DDS liveliness lease (``sm_bt.ros.manager_node.MODE_EVENT_LEASE``),
  which DDS asserts from its own threads; the fleet asks for a lease of ``liveness_timeout`` s on
  a second subscription of that topic, and DDS tells it when no assertion came for that long (the
  manager's process stopped, exited or was cut off): the same "no answer" verdict as above,
  counted from the manager's last word, ``LIVELINESS_GRACE`` s later. While DDS vouches for it,
  the robot is probed only every ``slow_probe_interval`` s (3 s): a manager whose Python hangs
  while its DDS threads live still asserts its liveliness, and a probe left unanswered for
  ``liveness_timeout`` s (asked again at once) makes it out of reach too, a fast probe interval
  later. Out of reach, while a change it accepted is unconfirmed, or before DDS has vouched for it,
  it is probed at the fast pace as above; a manager that offers no lease (an older sm-bt
  manager) is told once, as a warning, and its events are still heard on the first subscription,
  which asks for no lease. The liveliness subscriptions are on a node of the backend's own, spun
  by a plain executor in a thread of its own (:class:`~sm_bt.ros.remote_liveliness.Liveliness`): rclpy's EventsExecutor,
  which spins the backend's node, calls no liveliness callback;
* the reference's answers run ahead of its events, and it takes its own node ``mode_event``s (sent
  at its next tick) for news of its nodes: a request made before that tick is then planned from a
  wrong view and never ends (seen: ``deactivating`` for good). So after a change it accepted, the
  fleet takes the reference's word from its events, from its answers only ``REFERENCE_EVENTS`` s
  later (it sometimes sends no event at all), and makes its next request no sooner.

Every call has a timeout. Calls and reports run on the backend's node and clock; the listener is
never called with this backend's lock held.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from lifecycle_msgs.msg import Transition as TransitionMessage
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import WallClock
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.remote_parts import MixedModel, check_fleet
from sm_bt.model.states import State
from sm_bt.model.types import DEFAULT_MODE, REMOTE_MODE, Model, ParamValue
from sm_bt.ros.peers import SLACK, Link, state_of
from sm_bt.ros.remote_liveliness import Liveliness, liveliness_qos

log = logging.getLogger("sm_bt.ros.remote_parts")

#: The reference sends a change's events at its 1 s timer's next tick, or the one after: its answers
#: are taken for news that long after a change it accepted (it sometimes sends no event at all).
REFERENCE_EVENTS = 2.2
#: After an event of the reference, its next request waits this long: its own node mode_events of
#: the same tick, which it takes for news of its nodes, are back with it by then.
REFERENCE_ECHO = 0.2

#: A liveliness lost is judged this much later. Right after this process stood still (stopped,
#: starved), DDS's lease timer may fire before the assertions that waited in its sockets are read:
#: seen over UDP after stalls of 1-5 s, the writer alive again 1-5 ms after its loss, while the clock
#: had not always seen the stall yet (it sees one only at a timer due meanwhile).
LIVELINESS_GRACE = 0.05

#: Volatile: it matches sm-bt manager's latched writers and the reference's volatile ones alike;
#: what came before is read with get_state/get_mode instead.
_EVENTS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


@dataclass
class _Robot:
    part: str
    fqn: str
    change_state: Any
    get_state: Any
    change_mode: Any
    get_mode: Any
    reference: bool  # served by the reference's mode_manager
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


class RemoteBackend:
    """Drives ``model``'s remote parts (all its nodes must be remote parts) through their managers."""

    #: The keyword options it takes (of those RosRuntime's ``backend_options`` may hold).
    OPTIONS = frozenset({"call_timeout", "probe_interval", "liveness_timeout", "slow_probe_interval"})

    def __init__(self, node: Node, model: Model, *, clock: WallClock | None = None, call_timeout: float = 10.0,
                 probe_interval: float = 0.3, liveness_timeout: float = 0.9, slow_probe_interval: float = 3.0) -> None:
        if not check_fleet(model) and model.nodes:
            raise MixedModel(f"{model.path}: it has no remote parts: its nodes are RosBackend's")
        self._node = node
        self._clock = clock if clock is not None else WallClock("sm_bt-remote-clock")
        self.call_timeout = call_timeout
        self.probe_interval = probe_interval
        self.liveness_timeout = liveness_timeout
        # A robot whose liveliness DDS tells: its probe only finds a manager hung with its DDS threads
        # alive. Every 3 s such a hang is told within about 4 s, and the probes of ten robots cost
        # about 0.4 % of a core here (at 0.3 s: 4-5 %).
        self.slow_probe_interval = slow_probe_interval
        self._lock = threading.Lock()
        self._listener: BackendListener | None = None
        self._robots: dict[str, _Robot] = {}
        for part in model.nodes:
            assert part.remote is not None
            fqn = part.remote.fqn
            self._robots[part.name] = _Robot(
                part.name, fqn, node.create_client(ChangeState, f"{fqn}/change_state"),
                node.create_client(GetState, f"{fqn}/get_state"), node.create_client(ChangeMode, f"{fqn}/change_mode"),
                node.create_client(GetMode, f"{fqn}/get_mode"), part.remote.served_by == "reference")
        self._liveliness: Liveliness | None = None

    @property
    def clock(self) -> WallClock:
        return self._clock

    def link(self, part: str) -> Link:
        """How the robot's manager answers: probed, with the liveness window (no round-trip estimate)."""
        return Link(None, self.liveness_timeout, False)

    # -- the backend protocol ---------------------------------------------------------------------------

    def attach(self, nodes: Sequence[str], listener: BackendListener) -> None:
        with self._lock:
            self._listener = listener
        robots = [self._robots[name] for name in nodes]
        leased = [robot for robot in robots if not robot.reference]  # the reference offers no lease
        if leased:
            self._liveliness = Liveliness(self._node)
            for robot in leased:
                robot.liveliness = self._liveliness.subscribe(
                    f"{robot.fqn}/mode_event", liveliness_qos(self.liveness_timeout),
                    SubscriptionEventCallbacks(liveliness=functools.partial(self._lively, robot),
                                               incompatible_qos=functools.partial(self._no_lease, robot),
                                               use_default_callbacks=False))
            self._liveliness.start()
        for robot in robots:
            self._follow(robot)

    def _follow(self, robot: _Robot) -> None:
        """Its events, and the first probe (which reads it)."""
        robot.subscriptions = [
            self._node.create_subscription(TransitionEvent, f"{robot.fqn}/transition_event",
                                           lambda message: self._transition_event(robot, message), _EVENTS),
            self._node.create_subscription(ModeEvent, f"{robot.fqn}/mode_event",
                                           lambda message: self._mode_event(robot, message), _EVENTS)]
        with self._lock:
            self._schedule(robot, 0.0)

    def detach(self) -> None:
        with self._lock:
            self._listener = None
            for robot in self._robots.values():
                if robot.timer is not None:
                    robot.timer.cancel()
                robot.timer = None
        if self._liveliness is not None:  # its thread stopped before its node goes
            self._liveliness.close()
            self._liveliness = None
        for robot in self._robots.values():
            robot.liveliness = None
            for subscription in robot.subscriptions:
                self._node.destroy_subscription(subscription)
            robot.subscriptions = []

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        robot = self._robots[node]
        if transition is Transition.ACTIVATE:
            mode = robot.mode or DEFAULT_MODE
            refusal = f"the manager of {node} refused to activate it in mode {mode}"
            self._change(robot, robot.change_mode, ChangeMode.Request(mode_name=mode), f"change_mode {mode} (activate)",
                         lambda response: self._accepted(robot, response.success, mode, done, refusal),
                         lambda why: done(CallResult(False, why)))
            return
        message = TransitionMessage(id=int(transition.value), label=transition.label)
        refused = CallResult(False, f"the manager of {node} refused {transition.label}", refused=True)
        label = f"change_state {transition.label}"
        self._change(robot, robot.change_state, ChangeState.Request(transition=message), label,
                     lambda response: done(CallResult(True) if response.success else refused),
                     lambda why: done(CallResult(False, why)))

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        robot = self._robots[node]
        mode = parameters.get(REMOTE_MODE)
        if not isinstance(mode, str) or set(parameters) != {REMOTE_MODE}:
            self._clock.call_later(0.0, lambda: done(CallResult(False, f"{node} is a remote part: only its mode "
                                                                         "can be asked")))
            return
        with self._lock:
            kept = robot.state is not State.ACTIVE
            if kept:
                robot.mode = mode
        if kept:  # for its activation
            self._clock.call_later(0.0, lambda: self._kept(robot, mode, done))
            return
        self._change(robot, robot.change_mode, ChangeMode.Request(mode_name=mode), f"change_mode {mode}",
                     lambda response: self._accepted(robot, response.success, mode, done,
                                                     f"the manager of {node} refused mode {mode}"),
                     lambda why: done(CallResult(False, why)))

    def _kept(self, robot: _Robot, mode: str, done: Done) -> None:
        self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))
        done(CallResult(True))

    def _accepted(self, robot: _Robot, success: bool, mode: str, done: Done, refusal: str) -> None:
        """A ``change_mode`` answered. Accepted: until its manager reports the mode, each probe (at
        the fast pace) reads it too, since a manager that is there already answers ``success`` and
        sends no event (the reference: "redundant"). Not at once: a switch's events come first, and a
        read per robot per switch is work for the fleet's every switch (over ten robots: 1.76x the
        robots' own switch in one run with it, 1.39x in the next without it)."""
        if success:
            with self._lock:
                robot.asked = mode
                if robot.lively:  # probed at the fast pace until its manager reports the mode
                    self._schedule(robot, self.probe_interval)
        done(CallResult(True) if success else CallResult(False, refusal))

    # -- liveness and reading ------------------------------------------------------------------------------

    def _schedule(self, robot: _Robot, delay: float) -> None:
        """(With the lock held.) Its next probe in ``delay`` s, instead of the one planned."""
        if robot.timer is not None:
            robot.timer.cancel()
        robot.generation += 1
        generation = robot.generation
        robot.timer = self._clock.call_later(delay, lambda: self._probe(robot, generation))

    def _probe(self, robot: _Robot, generation: int) -> None:
        with self._lock:
            if self._listener is None or generation != robot.generation:
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
            self._call(robot, robot.get_state, GetState.Request(), "get_state (liveness)",
                       lambda response: self._state_answer(robot, state_of(response.current_state.id), events),
                       lambda why: self._probe_failed(robot, sent), timeout=self.liveness_timeout)
        if reading is not None:  # a manager that sends no event (the reference, at times) is read
            self._read_mode(robot, reading)
        if due < self.probe_interval:
            self._clock.call_later(due + SLACK, lambda: self._judge(robot))

    def _judge(self, robot: _Robot) -> None:
        """Out of reach once nothing was heard from its manager for the window, unless DDS vouches
        for its process (then its probes tell a hang: :meth:`_probe_failed`)."""
        with self._lock:
            # Not before this process last stood still itself: it heard nothing meanwhile.
            heard = max(robot.last_heard, self._clock.resumed)
            silent = (self._listener is not None and robot.present and not robot.lively
                      and self._clock.now() - heard >= self.liveness_timeout)
            if silent:
                robot.present = False
        if silent:
            self._unanswered(robot, "it exited, or the network is cut")

    def _lively(self, robot: _Robot, info: Any) -> None:
        """(The liveliness thread.) DDS's word on its manager's lease (``info``: a
        QoSLivelinessChangedInfo): ``alive_count`` writers of its ``mode_event`` assert it. None
        left: judged :data:`LIVELINESS_GRACE` s later (its last word came at least a window ago,
        unless an answer came later), and probed at the fast pace; back: heard, and read afresh at once if it was out of
        reach."""
        alive = int(info.alive_count)
        with self._lock:
            if self._listener is None:
                return
            was, lively = robot.lively, alive > 0
            robot.lively = lively
            if lively and not was:
                robot.last_heard = max(robot.last_heard, self._clock.now())
                if not robot.present:
                    self._schedule(robot, 0.0)
            elif was and not lively:  # the probe judges it, on the clock's thread (after its late timers)
                self._schedule(robot, LIVELINESS_GRACE)
        if lively != was:
            log.debug("%s: its manager's liveliness %s (%d alive)", robot.part, "back" if lively else "lost", alive)

    def _no_lease(self, robot: _Robot, info: Any) -> None:
        """(The liveliness thread.) A writer of its ``mode_event`` offers no lease the fleet can use."""
        log.warning("%s: a writer of %s/mode_event offers no liveliness lease of at most %g s (the reference, or "
                    "an older sm-bt manager?): its manager is probed every %g s", robot.part, robot.fqn,
                    self.liveness_timeout, self.probe_interval)

    def _probe_failed(self, robot: _Robot, sent: float) -> None:
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
                self._schedule(robot, 0.0)
        if suspect:
            self._clock.call_later(self.probe_interval, lambda: self._hung(robot, sent))

    def _hung(self, robot: _Robot, sent: float) -> None:
        with self._lock:
            hung = (self._listener is not None and robot.present and robot.lively and robot.last_heard < sent
                    and self._clock.now() - max(sent, self._clock.resumed) >= self.liveness_timeout)
            if hung:
                robot.present = False
        if hung:
            self._unanswered(robot, "DDS still sees its process: it hangs?")

    def _unanswered(self, robot: _Robot, why: str) -> None:
        self._report(lambda listener: listener.node_vanished(
            robot.part, f"no answer from the manager of {robot.part} ({robot.fqn}) for {self.liveness_timeout:g} s "
                        f"({why})"))

    def _state_answer(self, robot: _Robot, state: State, events: int) -> None:
        with self._lock:
            robot.probing = False
            robot.last_heard = self._clock.now()
            if state is State.UNKNOWN:
                action = "keep" if robot.assumed else "assume" if (
                    not robot.known and not robot.present and robot.reference) else "lost"
            elif not robot.present:
                action = "read"
            else:  # no event since it was asked: the answer is the newer news
                action = "correct" if (events == robot.events and state is not robot.state
                                       and self._clock.now() >= robot.reads_from) else "keep"
        if action == "lost":
            self._unknown(robot)
        elif action == "assume":
            self._appear(robot, State.UNCONFIGURED, "", assumed=True)
        elif action == "read":  # at start, or after it was out of reach: read its mode too, then report it
            self._call(robot, robot.get_mode, GetMode.Request(), "get_mode",
                       lambda response: self._appear(robot, state, str(response.current_mode)), lambda why: None)
        elif action == "correct":
            self._state(robot, state)

    def _unknown(self, robot: _Robot) -> None:
        """Its manager answers, but does not know where its part is (its own nodes out of reach): out
        of reach for the fleet too, and read afresh once its manager knows (its events will not
        repeat a mode it had before)."""
        with self._lock:
            was = robot.present
            robot.present = robot.assumed = False
        if was:
            self._report(lambda listener: listener.node_vanished(
                robot.part, f"the manager of {robot.part} does not know where {robot.fqn} is"))

    def _appear(self, robot: _Robot, state: State, mode: str, *, assumed: bool = False) -> None:
        if mode == "unknown" and not assumed:  # not known yet after all: the next probe reads it again
            return
        with self._lock:
            if robot.present or self._listener is None:
                return
            robot.present, robot.state, robot.mode = True, state, mode
            robot.assumed, robot.known = assumed, robot.known or not assumed
            robot.last_heard = self._clock.now()
        if assumed:
            log.info("%s: its manager (the reference) knows no state of %s yet: taken for unconfigured",
                     robot.part, robot.fqn)
        self._report(lambda listener: listener.node_appeared(robot.part, NodeReport(state, {REMOTE_MODE: mode})))

    def _state(self, robot: _Robot, state: State) -> None:
        """Its manager says it is in ``state``: reported if news; once active, its mode is read."""
        with self._lock:
            changed = robot.present and state is not robot.state
            if changed:
                robot.state = state
                robot.assumed, robot.known = False, True
        if changed:
            self._report(lambda listener: listener.node_state(robot.part, state))
            if state is State.ACTIVE:
                self._read_mode(robot)

    def _read_mode(self, robot: _Robot, only: str | None = None) -> None:
        """Its mode, asked of its manager (at its activation; after an accepted change, ``only`` the
        mode asked for, not a switch's intermediate inference): reported if it is news and no mode
        event came meanwhile (which is newer)."""
        with self._lock:
            events = robot.events

        def answered(response: Any) -> None:
            mode = str(response.current_mode)
            with self._lock:
                news = (robot.present and robot.state is State.ACTIVE and events == robot.events
                        and self._clock.now() >= robot.reads_from
                        and mode not in ("", "unknown") and mode != robot.mode and only in (None, mode))
                if news:
                    robot.mode = mode
                if mode == robot.asked and robot.state is State.ACTIVE and self._clock.now() >= robot.reads_from:
                    robot.asked = None
            if news:
                self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))

        self._call(robot, robot.get_mode, GetMode.Request(), "get_mode", answered, lambda why: None)

    def _transition_event(self, robot: _Robot, message: Any) -> None:
        state = state_of(message.goal_state.id)
        with self._lock:
            self._heard_event(robot)
            assumed = robot.assumed
        if state is State.UNKNOWN:
            if not assumed:
                self._unknown(robot)
            return
        self._state(robot, state)

    def _mode_event(self, robot: _Robot, message: Any) -> None:
        """Its mode, unless it is inactive or unconfigured (the mode of such a robot is the one it
        will be activated in; an empty one is the reference's intermediate inference). A mode event
        says "active in it", and may overtake the state event of a switch's end: taken while the
        robot is activating, the fleet never sees it back in its old mode meanwhile."""
        mode = str(message.goal_mode.label)
        with self._lock:
            self._heard_event(robot)
            changed = (robot.present and robot.state not in (State.INACTIVE, State.UNCONFIGURED)
                       and mode not in ("", robot.mode))
            if changed:
                robot.mode = mode
            if mode == robot.asked and robot.state is State.ACTIVE:
                robot.asked = None
        if changed:
            self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))

    def _heard_event(self, robot: _Robot) -> None:
        """(With the lock held.) An event of its manager: the reference has ticked."""
        robot.events += 1
        robot.last_heard = self._clock.now()
        if robot.reference:
            robot.requests_from = min(robot.requests_from, robot.last_heard + REFERENCE_ECHO)

    # -- calls ------------------------------------------------------------------------------------------------

    def _change(self, robot: _Robot, client: Any, request: Any, label: str, answered: Callable[[Any], None],
                failed: Callable[[str], None]) -> None:
        """A change request (see :meth:`_call`); to the reference, no sooner than its view of the last
        one is whole (``REFERENCE_EVENTS``, ``REFERENCE_ECHO``), and its answers are news only after that."""
        with self._lock:
            wait = robot.requests_from - self._clock.now() if robot.reference else 0.0
        if wait > 0:
            self._clock.call_later(wait, lambda: self._change(robot, client, request, label, answered, failed))
            return

        def accepted(response: Any) -> None:
            if robot.reference and response.success:
                with self._lock:
                    robot.reads_from = robot.requests_from = self._clock.now() + REFERENCE_EVENTS
            answered(response)

        self._call(robot, client, request, label, accepted, failed)

    def _call(self, robot: _Robot, client: Any, request: Any, label: str, answered: Callable[[Any], None],
              failed: Callable[[str], None], timeout: float | None = None) -> None:
        """``request`` on ``client``: ``answered(response)``, or ``failed(why)`` once ``timeout`` passed."""
        if not client.service_is_ready():
            self._clock.call_later(0.0, lambda: failed(f"{robot.fqn}: no manager serves it ({label})"))
            return
        future = client.call_async(request)
        finished = threading.Event()

        def on_done(_: Any) -> None:
            if finished.is_set():
                return
            finished.set()
            response = future.result()
            with self._lock:
                robot.last_heard = self._clock.now()
            answered(response)

        def on_timeout() -> None:
            if finished.is_set():
                return
            finished.set()
            client.remove_pending_request(future)
            failed(f"the manager of {robot.part} did not answer {label} within {limit:g} s")

        limit = timeout if timeout is not None else self.call_timeout
        future.add_done_callback(on_done)
        self._clock.call_later(limit, on_timeout)

    def _report(self, tell: Callable[[BackendListener], None]) -> None:
        listener = self._listener
        if listener is not None:
            tell(listener)
