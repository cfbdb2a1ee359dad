"""The ROS 2 backend of a fleet: remote parts driven through the system_modes interface of their managers.

Each remote part (``type: remote``, :mod:`sm_bt.model.remote_parts`) is a system that another mode
manager serves at ``Remote.fqn`` (``/robot1/pilot``): ``sm-bt manager`` in the robot's namespace, or
the reference's ``mode_manager``. :class:`RemoteBackend` speaks to it as any client does:

* its state and mode are read with ``get_state``/``get_mode`` when it appears and after it was out
  of reach (the heal), then followed on its ``transition_event``/``mode_event`` (the reference
  sends those from a 1 s timer), and on the liveness probes' answers (below): a state event that
  never came (the reference sometimes sends none) is corrected by the next probe;
* a change of state is a transition asked of it, except activation, which asks for the mode the
  fleet wants it in: both managers activate a system into the mode asked for, while the
  reference's ``activate`` means ``__DEFAULT__``. A change of mode of an active robot is asked
  of it; of one that is not active, it is kept for its activation (to the engine, the mode of a
  robot that is not active is the one it will be activated in). An sm-bt robot is asked through
  its ``request_change``, as the fleet's requester, and the change is done when the robot's
  request ends (its ``request_outcome``, :mod:`~sm_bt.ros.remote_requests`): its failure fails the
  fleet's at once, with its reason. The reference is asked through ``change_mode`` and
  ``change_state`` (transition id and label: it reads the id); its ``success`` means accepted, and
  the change counts as done then (the robot's reports confirm it);
* liveness: ``get_state`` every ``probe_interval`` s; no answer for ``liveness_timeout`` s makes it
  out of reach ("no answer from the manager of robot1 ..."), and the fleet's rules react; what its
  manager owed the fleet fails. While out of reach it is asked again every probe; the first answer
  is its reappearance. A manager that answers ``unknown`` has lost its part (its nodes are out of
  its reach), with two exceptions. The reference (``served_by: reference``) learns states only
  from its nodes' events, so until a node moves it knows nothing of nodes that wait unconfigured:
  before it has ever known the part, it is taken for unconfigured. sm-bt manager with no target
  knows no mode of nodes left between modes (by a predecessor it replaced): its preview of a change
  is possible then, and the part is taken for active in no mode, which the fleet's recovery asks
  for its target;
* liveliness (sm-bt manager): its ``mode_event`` offers a DDS liveliness lease
  (:mod:`~sm_bt.ros.remote_liveliness`), and DDS tells the fleet, from its own threads, when no
  assertion came for ``liveness_timeout`` s (the process stopped, exited or was cut off): the same
  verdict (:mod:`~sm_bt.ros.remote_probes`). While DDS vouches for it, a robot is probed every
  ``slow_probe_interval`` s (3 s; a probe costs this process about a millisecond of Python), which
  tells a manager whose Python hangs while its DDS threads live: a probe unanswered for the window
  is asked again at once, and a fast interval later it is out of reach. Out of reach, with a change
  unconfirmed, or before DDS vouched for it, it is probed every ``probe_interval`` s; a manager that
  offers no lease (an older sm-bt manager) is told once, as a warning;
* the reference is paced: after a change it accepted, its events are its word, and its next
  request waits for them (:mod:`~sm_bt.ros.remote_robots`).

Every call has a timeout. Calls and reports run on the backend's node and clock; the listener is
never called with this backend's lock held.
"""

from __future__ import annotations

import functools
import json
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from lifecycle_msgs.msg import Transition as TransitionMessage
from lifecycle_msgs.msg import TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sm_bt_msgs.msg import RequestOutcome
from sm_bt_msgs.srv import PreviewChange, RequestChange
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import WallClock
from sm_bt.engine.lifecycle import TRANSITION_GOALS, Transition
from sm_bt.model.remote_parts import MixedModel, check_fleet
from sm_bt.model.states import State
from sm_bt.model.types import DEFAULT_MODE, FLEET_REQUESTER, REMOTE_MODE, Model, ParamValue
from sm_bt.ros.manager_node import OUTCOMES
from sm_bt.ros.peers import Link, state_of
from sm_bt.ros.remote_liveliness import Liveliness, liveliness_qos
from sm_bt.ros.remote_probes import RobotProbes
from sm_bt.ros.remote_requests import RobotRequests
from sm_bt.ros.remote_robots import Robot, RobotCalls

log = logging.getLogger("sm_bt.ros.remote_parts")

#: Volatile: it matches sm-bt manager's latched writers and the reference's volatile ones alike;
#: what came before is read with get_state/get_mode instead.
_EVENTS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


class RemoteBackend:
    """Drives ``model``'s remote parts (all its nodes must be remote parts) through their managers."""

    #: The keyword options it takes (of those RosRuntime's ``backend_options`` may hold).
    OPTIONS = frozenset({"call_timeout", "probe_interval", "liveness_timeout", "slow_probe_interval",
                         "outcome_timeout"})

    def __init__(self, node: Node, model: Model, *, clock: WallClock | None = None, call_timeout: float = 10.0,
                 probe_interval: float = 0.3, liveness_timeout: float = 0.9, slow_probe_interval: float = 3.0,
                 outcome_timeout: float = 60.0) -> None:
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
        self._calls = RobotCalls(self._clock, self._lock, call_timeout)
        self._listener: BackendListener | None = None
        self._probes = RobotProbes(self._clock, self._lock, self._calls, probe_interval=probe_interval,
                                   liveness_timeout=liveness_timeout, slow_probe_interval=slow_probe_interval,
                                   listening=lambda: self._listener is not None, answered=self._state_answer,
                                   read=self._read_mode, unanswered=self._unanswered)
        self._robots: dict[str, Robot] = {}
        for part in model.nodes:
            assert part.remote is not None
            fqn = part.remote.fqn
            reference = part.remote.served_by == "reference"
            self._robots[part.name] = Robot(
                part.name, fqn, node.create_client(ChangeState, f"{fqn}/change_state"),
                node.create_client(GetState, f"{fqn}/get_state"), node.create_client(ChangeMode, f"{fqn}/change_mode"),
                node.create_client(GetMode, f"{fqn}/get_mode"), reference,
                None if reference else node.create_client(RequestChange, f"{fqn}/request_change"),
                None if reference else node.create_client(PreviewChange, f"{fqn}/preview_change"),
                None if reference else RobotRequests(part.name, self._clock, outcome_timeout,
                                                     settle=functools.partial(self._settle, part.name)))
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
                    SubscriptionEventCallbacks(liveliness=functools.partial(self._probes.lively, robot),
                                               incompatible_qos=functools.partial(self._probes.no_lease, robot),
                                               use_default_callbacks=False))
            self._liveliness.start()
        for robot in robots:
            self._follow(robot)

    def _follow(self, robot: Robot) -> None:
        """Its events, and the first probe (which reads it)."""
        robot.subscriptions = [
            self._node.create_subscription(TransitionEvent, f"{robot.fqn}/transition_event",
                                           lambda message: self._transition_event(robot, message), _EVENTS),
            self._node.create_subscription(ModeEvent, f"{robot.fqn}/mode_event",
                                           lambda message: self._mode_event(robot, message), _EVENTS)]
        if robot.requests is not None:
            outcomes = self._node.create_subscription(RequestOutcome, f"{robot.fqn}/request_outcome",
                                                      robot.requests.ended, OUTCOMES)
            robot.subscriptions.append(outcomes)
            with self._lock:
                robot.outcomes = outcomes
        with self._lock:
            self._probes.schedule(robot, 0.0)

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
            with self._lock:
                robot.outcomes, robot.outcomes_matched = None, False
            for subscription in robot.subscriptions:
                self._node.destroy_subscription(subscription)
            robot.subscriptions = []
            if robot.requests is not None:
                robot.requests.lost("the fleet stopped following it")

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        robot = self._robots[node]
        if transition is Transition.ACTIVATE:
            mode = robot.mode or DEFAULT_MODE
            self._ask_mode(robot, mode, f"change_mode {mode} (activate)", done,
                           f"the manager of {node} refused to activate it in mode {mode}")
            return
        label = f"change_state {transition.label}"
        refusal = f"the manager of {node} refused {transition.label}"
        if robot.requests is not None:
            self._request(robot, RequestChange.Request(transition=transition.label, requester=FLEET_REQUESTER,
                                                       priority=-1), label, done, refusal, refused=True)
            return
        message = TransitionMessage(id=int(transition.value), label=transition.label)
        refused = CallResult(False, refusal, refused=True)
        self._calls.change(robot, robot.change_state, ChangeState.Request(transition=message), label,
                           lambda response: done(CallResult(True) if response.success else refused),
                           lambda why: done(CallResult(False, why)), told=done,
                           told_by=("change_state", transition.label))

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
        self._ask_mode(robot, mode, f"change_mode {mode}", done, f"the manager of {node} refused mode {mode}")

    def _kept(self, robot: Robot, mode: str, done: Done) -> None:
        self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))
        done(CallResult(True))

    def _ask_mode(self, robot: Robot, mode: str, label: str, done: Done, refusal: str) -> None:
        if robot.requests is not None:
            self._request(robot, RequestChange.Request(mode=mode, requester=FLEET_REQUESTER, priority=-1), label,
                          done, refusal, asked=mode)
            return

        def answered(response: Any) -> None:  # the reference's request is done once accepted
            if response.success:
                self._accepted(robot, mode)
            done(CallResult(True) if response.success else CallResult(False, refusal))

        self._calls.change(robot, robot.change_mode, ChangeMode.Request(mode_name=mode), label, answered,
                           lambda why: done(CallResult(False, why)),
                           told=lambda _: answered(ChangeMode.Response(success=True)), told_by=("change_mode", mode))

    def _request(self, robot: Robot, request: Any, label: str, done: Done, refusal: str, *,
                 asked: str | None = None, refused: bool = False) -> None:
        """``request`` (a ``RequestChange``) of an sm-bt robot: ``done`` when the robot's request ends
        (refused: the robot's reason, ``refused`` for a transition planned from an old report)."""
        requests = robot.requests
        assert requests is not None

        def answered(response: Any) -> None:
            if not response.accepted:
                done(CallResult(False, f"{refusal}: {response.reason}", refused=refused))
                return
            if asked is not None:
                self._accepted(robot, asked)
            requests.accepted(int(response.request), label, done, asks)

        def told(result: CallResult) -> None:  # its outcome came, its answer did not
            if asked is not None and result.ok:
                self._accepted(robot, asked)
            done(result)

        asks = ("change_mode", request.mode) if request.mode else ("change_state", request.transition)
        self._calls.change(robot, robot.request_change, request, label, answered,
                           lambda why: done(CallResult(False, why)), told=told, told_by=asks)

    def _reached(self, robot: Robot, told_by: tuple[str, str]) -> None:
        """Its events say it is where a change of the fleet's that asked ``told_by`` leads: the change
        is done, its answer (and, from an sm-bt robot, the request's outcome) lost or late."""
        if not self._calls.settle(robot, told_by, CallResult(True)) and robot.requests is not None:
            robot.requests.reached(told_by)

    def _settle(self, part: str, told_by: tuple[str, str], result: CallResult) -> bool:
        return self._calls.settle(self._robots[part], told_by, result)

    def _accepted(self, robot: Robot, mode: str) -> None:
        """A mode accepted: until its manager reports it, each probe (at the fast pace) reads it too,
        since a manager that is there already sends no event (the reference: "redundant"). Not at
        once: a switch's events come first, and a read per robot per switch is work for the fleet's
        every switch (over ten robots: 1.76x the robots' own switch in one run with it, 1.39x in the
        next without it). Nor when its mode event has come already (it usually comes before the
        answer): the reads would land on the fleet's next switch."""
        with self._lock:
            if robot.present and robot.state is State.ACTIVE and robot.mode == mode:
                return
            robot.asked = mode
            if robot.lively:  # probed at the fast pace until its manager reports the mode
                self._probes.schedule(robot, self.probe_interval)

    # -- liveness and reading ------------------------------------------------------------------------------

    def _unanswered(self, robot: Robot, why: str) -> None:
        reason = f"no answer from the manager of {robot.part} ({robot.fqn}) for {self.liveness_timeout:g} s ({why})"
        self._report(lambda listener: listener.node_vanished(robot.part, reason))
        self._calls.abandon(robot, reason)
        if robot.requests is not None:
            robot.requests.lost(reason)

    def _state_answer(self, robot: Robot, state: State, events: int) -> None:
        with self._lock:
            robot.probing = False
            robot.last_heard = self._clock.now()
            if state is State.UNKNOWN:
                action = "keep" if robot.assumed else "assume" if (
                    not robot.known and not robot.present and robot.reference) else "unknown"
            elif not robot.present:
                action = "read"
            else:  # no event since it was asked: the answer is the newer news
                action = "correct" if (events == robot.events and state is not robot.state
                                       and self._clock.now() >= robot.reads_from) else "keep"
        if action == "unknown":
            self._unknown(robot)
        elif action == "assume":
            self._appear(robot, State.UNCONFIGURED, "", assumed=True)
        elif action == "read":  # at start, or after it was out of reach: read its mode too, then report it
            self._calls.call(robot, robot.get_mode, GetMode.Request(), "get_mode",
                             lambda response: self._appear(robot, state, str(response.current_mode)),
                             lambda why: None)
        elif action == "correct":
            self._state(robot, state)

    def _unknown(self, robot: Robot) -> None:
        """Its manager answers, but knows no state of its part: its nodes are out of its reach, or (sm-bt
        manager) they answer between modes and it has no target, as a manager finds them that was
        started after its predecessor left them so. sm-bt manager's preview of a change tells which:
        possible, with no node to wait for, only in the second case."""
        if robot.preview_change is None:
            self._lost(robot)
            return

        def answered(response: Any) -> None:
            waits = json.loads(response.json).get("waits", []) if response.possible and response.json else []
            if response.possible and not any(wait.endswith(" to appear") for wait in waits):
                self._between(robot)
            else:
                self._lost(robot)

        self._calls.call(robot, robot.preview_change, PreviewChange.Request(mode=DEFAULT_MODE), "preview_change",
                         answered, lambda why: self._lost(robot))

    def _lost(self, robot: Robot) -> None:
        """Its manager does not know where its part is (its own nodes out of reach): out of reach for
        the fleet too, and read afresh once its manager knows (its events will not repeat a mode it
        had before)."""
        with self._lock:
            was = robot.present
            robot.present = robot.assumed = False
            robot.seen_ready.clear()
        if was:
            self._report(lambda listener: listener.node_vanished(
                robot.part, f"the manager of {robot.part} does not know where {robot.fqn} is"))

    def _between(self, robot: Robot) -> None:
        """Its nodes answer between modes: active in no mode to the fleet (a mode asked of it is then
        asked of its manager, as a deactivation is), which the fleet's divergence and recovery see."""
        with self._lock:
            if self._listener is None:
                return
            appeared, news = not robot.present, robot.present and (robot.state, robot.mode) != (State.ACTIVE, "")
            was = robot.state
            robot.present, robot.state, robot.mode, robot.assumed, robot.known = True, State.ACTIVE, "", False, True
            robot.last_heard = self._clock.now()
        if appeared or news:
            log.info("%s: its manager knows no mode of %s (its nodes answer, between modes, and it has no target): "
                     "taken for active in no mode", robot.part, robot.fqn)
        if appeared:
            report = NodeReport(State.ACTIVE, {REMOTE_MODE: ""})
            self._report(lambda listener: listener.node_appeared(robot.part, report))
        elif news:
            if was is not State.ACTIVE:
                self._report(lambda listener: listener.node_state(robot.part, State.ACTIVE))
            self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: ""}))

    def _appear(self, robot: Robot, state: State, mode: str, *, assumed: bool = False) -> None:
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

    def _state(self, robot: Robot, state: State) -> None:
        """Its manager says it is in ``state``: reported if news; once active, its mode is read,
        unless its mode event came on the way (a switch's comes before or after its end)."""
        with self._lock:
            changed = robot.present and state is not robot.state
            if changed:
                robot.state = state
                robot.assumed, robot.known = False, True
                told, robot.mode_told = robot.mode_told, robot.mode_told and state is State.ACTIVE
        if changed:
            self._report(lambda listener: listener.node_state(robot.part, state))
            if state is State.ACTIVE and not told:
                self._read_mode(robot)

    def _read_mode(self, robot: Robot, only: str | None = None) -> None:
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
                there = robot.present and robot.state is State.ACTIVE and self._clock.now() >= robot.reads_from
                if mode == robot.asked and there:
                    robot.asked = None
            if news:
                self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))
            if there and mode not in ("", "unknown"):  # its events may have come the other way round
                self._reached(robot, ("change_mode", mode))

        self._calls.call(robot, robot.get_mode, GetMode.Request(), "get_mode", answered, lambda why: None)

    def _transition_event(self, robot: Robot, message: Any) -> None:
        state = state_of(message.goal_state.id)
        with self._lock:
            self._calls.heard_event(robot)
            assumed = robot.assumed
        # A transition's answer lost (and an sm-bt robot's outcome): its event says it was done.
        for label in (label for label, goal in TRANSITION_GOALS.items() if goal == state.label):
            self._reached(robot, ("change_state", label))
        if state is State.UNKNOWN:
            if not assumed:
                self._unknown(robot)
            return
        self._state(robot, state)

    def _mode_event(self, robot: Robot, message: Any) -> None:
        """Its mode, unless it is inactive or unconfigured (the mode of such a robot is the one it
        will be activated in; an empty one is the reference's intermediate inference). A mode event
        says "active in it", and may overtake the state event of a switch's end: taken while the
        robot is activating, the fleet never sees it back in its old mode meanwhile."""
        mode = str(message.goal_mode.label)
        with self._lock:
            self._calls.heard_event(robot)
            taken = robot.present and robot.state not in (State.INACTIVE, State.UNCONFIGURED) and mode != ""
            changed = taken and mode != robot.mode
            if changed:
                robot.mode = mode
            robot.mode_told = robot.mode_told or taken
            if mode == robot.asked and robot.state is State.ACTIVE:
                robot.asked = None
        if mode and (robot.reference or taken):  # a change_mode's answer (or outcome) lost: its event says it was done
            self._reached(robot, ("change_mode", mode))
        if changed:
            self._report(lambda listener: listener.node_parameters(robot.part, {REMOTE_MODE: mode}))

    # -- calls ------------------------------------------------------------------------------------------------

    def _report(self, tell: Callable[[BackendListener], None]) -> None:
        listener = self._listener
        if listener is not None:
            tell(listener)
