"""A client of a running mode manager, over the system_modes interface (``sm-bt mode/state ...``).

It speaks only the reference's services and topics, so it commands ``sm-bt manager`` and the
reference's ``mode_manager`` alike:

* ``/{part}/get_mode``, ``get_available_modes``, ``change_mode`` (system_modes_msgs), served by the
  manager for every part;
* ``/{part}/get_state``, ``change_state`` (lifecycle_msgs): the manager's for a system, the
  node's own for a node;
* ``/{part}/mode_event`` and ``/{part}/transition_event``: what wakes a wait for confirmation,
  which then asks ``get_mode``/``get_state`` to be sure (a latched event may be an old one);
* ``/diagnostics``, where ``sm-bt manager`` tells a request's failure at once: a wait ends then,
  with the manager's reason, rather than at its timeout (the reference's manager has no such
  signal: a wait on it ends at the confirmation or the timeout).

Every call has a timeout. Names that nobody serves raise :class:`UnknownName` with the names that
are served ("did you mean ...?"); no answer at all raises :class:`ManagerUnreachable`, saying what
to check. One rclpy node of its own, in a context of its own or one it is given (the client
daemon's, :mod:`sm_bt.ros.client_daemon`, whose graph is already known), spun only inside its calls;
:meth:`close` ends them.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, TRANSITION_GOALS, transition_by_label
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.errors import Error
from sm_bt.model.states import State
from sm_bt.ros.environment import prepare, require_ros

#: Discovery time after which a manager that serves other parts, but not the one asked for, means
#: a wrong name rather than a slow network.
DISCOVERY_GRACE = 2.0
#: ... once the parts served have stopped growing for this long: on a loaded machine a manager's
#: dozens of services are discovered over seconds, and a part not seen yet is no typo.
DISCOVERY_SETTLED = 1.0
#: How often a wait asks get_mode/get_state when no event wakes it (events wake it at once).
POLL = 0.5
#: The services a node serves itself (a system's are its manager's).
NODE_SERVICES = frozenset({"get_state", "change_state"})
#: How long to look for the manager of a node that does not answer, to say which of the two is out of reach.
PEEK = 2.0
#: Seconds a fresh process's graph may take to show a manager's services at all (1-3 s in about
#: half of the runs measured, docs/cli.md): a node with no manager waits this long before its
#: transition is sent; a managed node or a system is told at once.
GRAPH_SETTLE = 3.5
#: A graph watched this long has shown every service there is (the client daemon's): no settling.
GRAPH_WARM = 10.0


class ManagerUnreachable(Error, RuntimeError):
    """No manager (or node) answers: the message says which service and what to check."""


class UnknownName(Error, ValueError):
    """A part, mode or transition that is not served: the message has the closest served names."""


class NotConfirmed(Error, RuntimeError):
    """A change was accepted but not confirmed in time, or the manager says it failed: the message
    says why and where the part is."""


def _namespace(part: str) -> str:
    """``robot1`` of ``robot1/pilot``; ``""`` of a part at the root."""
    return part.strip("/").rpartition("/")[0]


def _closest(word: str, served: list[str], what: str) -> str:
    """The closest served name, or else the ones served (``what``: how to call them)."""
    return did_you_mean(word, served) or (f" ({what}: {', '.join(served)})" if served else "")


class ModeClient:
    """Ask a mode manager over ROS 2; every method waits at most ``timeout`` seconds."""

    def __init__(self, timeout: float = 10.0, node_name: str = "sm_bt_client", context: Any = None,
                 graph_since: float | None = None) -> None:
        """``context``: an rclpy context to make the node in, which :meth:`close` leaves running;
        ``graph_since``: when that context started watching the graph (``time.monotonic()``)."""
        if context is None:
            prepare(local_only=False)  # the user's discovery settings: the manager may be on another host
            require_ros()
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self.timeout = timeout
        self._owns_context = context is None
        if context is None:
            context = Context()
            rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        self.context = context
        self.graph_since = time.monotonic() if graph_since is None else graph_since
        self.node = rclpy.create_node(node_name, context=self.context, start_parameter_services=False)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._clients: dict[str, Any] = {}
        #: Event subscriptions made by :meth:`listen` before a request, by topic: each with what it heard.
        self._listening: dict[str, tuple[Any, list[tuple[float, Any]]]] = {}
        #: When the last request went out (``time.monotonic()``), once its service was found.
        self.sent = 0.0

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        if self._owns_context:
            self.context.try_shutdown()

    def __enter__(self) -> ModeClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what is served ------------------------------------------------------------------------------

    def served_parts(self) -> list[str]:
        """The parts whose ``change_mode`` some manager serves (from the ROS graph)."""
        return sorted(name[1:-len("/change_mode")] for name, types in self.node.get_service_names_and_types()
                      if name.endswith("/change_mode") and "system_modes_msgs/srv/ChangeMode" in types)

    def _client(self, service_type: Any, name: str) -> Any:
        if name not in self._clients:
            self._clients[name] = self.node.create_client(service_type, name)
        return self._clients[name]

    def _found(self, client: Any, part: str) -> bool:
        """Wait for ``client``'s service; :class:`UnknownName` as soon as discovery shows a manager
        serving other parts of its namespace but not this one, and no more appearing (a typo need
        not wait for the whole timeout)."""
        start = time.monotonic()
        seen: set[str] = set()
        grew = start
        # Polled every 20 ms: rclpy's wait_for_service sleeps 0.25 s between looks, which every
        # service of a command paid at least once (the graph usually shows it within a few ms).
        while not client.service_is_ready():
            time.sleep(0.02)
            now = time.monotonic()
            elapsed = now - start
            if elapsed >= DISCOVERY_GRACE or elapsed >= self.timeout:
                # Only the parts of its namespace tell: robots of a fleet share a domain, and one
                # robot's manager seen first says nothing of another's, still being discovered.
                served = [name for name in self.served_parts() if _namespace(name) == _namespace(part)]
                if not seen.issuperset(served):
                    seen.update(served)
                    grew = now
                if served and part not in served and now - grew >= DISCOVERY_SETTLED:
                    raise UnknownName(f"no manager serves the part {part!r}{_closest(part, served, 'parts served')}")
            if elapsed >= self.timeout:
                return False
        return True

    def _call(self, service_type: Any, part: str, service: str, request: Any) -> Any:
        name = f"/{part}/{service}"
        client = self._client(service_type, name)
        if not self._found(client, part):
            raise ManagerUnreachable(
                f"nothing answers {name} within {self.timeout:g} s: " + self._what_to_check(part, service))
        self.sent = time.monotonic()  # "after the request" counts from here: finding the service is not the manager's
        future = client.call_async(request)
        self.executor.spin_until_future_complete(future, timeout_sec=self.timeout)
        if not future.done():
            client.remove_pending_request(future)
            raise ManagerUnreachable(f"{name} did not answer within {self.timeout:g} s: "
                                     + self._what_to_check(part, service))
        return future.result()

    def _what_to_check(self, part: str, service: str) -> str:
        if service in NODE_SERVICES and self._manager_answers(part):
            if self._is_system(part):  # the manager serves this service itself: it answered another one
                return (f"{part} is a system, and its mode manager answers get_mode but not {service} in time: "
                        "it is busy or the network is slow; try again, or with a longer --timeout")
            # Its manager answers but its lifecycle services do not: they are a node's own.
            return (f"{part} is a node, and its mode manager answers but the node does not: it is not running, or "
                    f"the network to it is down (`sm-bt mode get {part}` shows what the manager knows)")
        same = "with the same ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as this shell?"
        if service in NODE_SERVICES:  # a node's own service, or a system's through its manager
            return (f"if {part} is a node, is it running (its own lifecycle service answers this)? If a system, is "
                    f"its mode manager (`sm-bt manager MODEL`) running? Either {same}")
        return f"is a mode manager (`sm-bt manager MODEL`) running, {same}"

    def managed_node(self, part: str) -> bool:
        """Is ``part`` a node (its own ``change_state`` server) that a mode manager manages (one
        serves the part's ``get_mode``)? Looked up once ``change_state`` is found (which the call
        needs anyway), a young graph given :data:`GRAPH_SETTLE` s more to show who serves what."""
        from lifecycle_msgs.srv import ChangeState

        if not self._found(self._client(ChangeState, f"/{part}/change_state"), part):
            return False  # the call that follows says what answers not
        young = time.monotonic() - self.graph_since < GRAPH_WARM
        give_up = time.monotonic() + (GRAPH_SETTLE if young else 0.0)
        while True:
            server = self._server_of(f"/{part}/change_state")
            if server is not None and server != f"/{part}":
                return False  # a system: its manager serves its lifecycle services
            if server is not None and any(name == f"/{part}/get_mode" for name, _ in
                                          self.node.get_service_names_and_types()):
                return True  # a node of its own name, and a manager of it
            if time.monotonic() >= give_up:
                return False
            time.sleep(0.05)

    def _server_of(self, service: str) -> str | None:
        """The fully qualified name of a node that serves ``service`` (as the graph shows it now)."""
        for name, namespace in self.node.get_node_names_and_namespaces():
            with contextlib.suppress(Exception):  # a node that left the graph meanwhile
                if any(found == service for found, _ in self.node.get_service_names_and_types_by_node(name, namespace)):
                    return f"{namespace.rstrip('/')}/{name}"
        return None

    def state_after(self, part: str, seconds: float) -> str:
        """The node's state once ``seconds`` passed with no change, or more (each change starts
        the wait again; at most ``timeout`` s in all): what holds once its manager had its say."""
        from lifecycle_msgs.msg import TransitionEvent

        changed: list[float] = []
        subscription = self.node.create_subscription(TransitionEvent, f"/{part}/transition_event",
                                                     lambda event: changed.append(time.monotonic()), _volatile())
        try:
            began = time.monotonic()
            while True:
                now = time.monotonic()
                quiet_since = max([began, *changed])
                if now - quiet_since >= seconds or now - began >= max(self.timeout, seconds):
                    return self.get_state(part)
                self.executor.spin_once(timeout_sec=0.05)
        finally:
            self.node.destroy_subscription(subscription)

    def _is_system(self, part: str) -> bool:
        """Does a manager serve ``part`` as a system (``get_available_states`` is a system's only)?"""
        return any(name == f"/{part}/get_available_states" for name, _ in self.node.get_service_names_and_types())

    def _manager_answers(self, part: str) -> bool:
        """Does a manager answer ``get_mode`` of ``part`` within ``PEEK`` s?"""
        from system_modes_msgs.srv import GetMode

        client = self._client(GetMode, f"/{part}/get_mode")
        if not client.wait_for_service(timeout_sec=PEEK):
            return False
        future = client.call_async(GetMode.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=PEEK)
        if not future.done():
            client.remove_pending_request(future)
        return bool(future.done())

    # -- modes -----------------------------------------------------------------------------------------

    def get_mode(self, part: str) -> str:
        """The part's current mode as the manager infers it (``""``: none, e.g. not active)."""
        from system_modes_msgs.srv import GetMode

        return str(self._call(GetMode, part, "get_mode", GetMode.Request()).current_mode)

    def available_modes(self, part: str) -> list[str]:
        from system_modes_msgs.srv import GetAvailableModes

        return list(self._call(GetAvailableModes, part, "get_available_modes",
                               GetAvailableModes.Request()).available_modes)

    def check_mode(self, part: str, mode: str) -> None:
        """:class:`UnknownName` unless ``mode`` is one of the part's modes."""
        modes = self.available_modes(part)
        if mode not in modes and mode != "__DEFAULT__":
            raise UnknownName(f"{part} has no mode {mode!r}{_closest(mode, modes, 'modes')}")

    def preview_change(self, part: str, mode: str = "", transition: str = "") -> tuple[bool, list[str]]:
        """What ``sm-bt manager`` would do for a change of ``mode`` (or ``transition``) of ``part``,
        without doing it: whether it could be made, and the plan's lines (sm_bt's own
        ``/{part}/preview_change``; the reference's manager has none: :class:`ManagerUnreachable`
        says so)."""
        from sm_bt_msgs.srv import PreviewChange

        try:
            response = self._call(PreviewChange, part, "preview_change",
                                  PreviewChange.Request(mode=mode, transition=transition))
        except ManagerUnreachable as error:
            raise ManagerUnreachable(f"{error} (a preview needs sm-bt manager: the reference's manager has none)") \
                from None
        return bool(response.possible), list(response.lines)

    def request_change(self, part: str, mode: str = "", transition: str = "", requester: str = "",
                       priority: int = -1, queue: bool = False) -> tuple[bool, str]:
        """Ask ``sm-bt manager`` for ``mode`` (or ``transition``) of ``part`` as ``requester`` at
        ``priority`` (-1: the requester's) through sm_bt's own ``/{part}/request_change``: whether
        it was accepted (with ``queue``, it may wait for a hold to end: the reason says so), and why
        not. The reference's manager has none: :class:`ManagerUnreachable`."""
        from sm_bt_msgs.srv import RequestChange

        try:
            response = self._call(RequestChange, part, "request_change", RequestChange.Request(
                mode=mode, transition=transition, requester=requester, priority=priority, queue=queue))
        except ManagerUnreachable as error:
            raise ManagerUnreachable(f"{error} (a requester or a priority needs sm-bt manager: the reference's "
                                     "manager has neither)") from None
        return bool(response.accepted), str(response.reason)

    def hold_mode(self, part: str, mode: str = "", requester: str = "", priority: int = -1, lease: float = 0.0,
                  hold: int = 0, release: bool = False) -> tuple[bool, str, int]:
        """Hold ``part`` in ``mode`` through ``sm-bt manager``'s ``/{part}/hold_mode``, or renew
        (``hold``: its number) or release it: (accepted, why not, the hold's number)."""
        from sm_bt_msgs.srv import HoldMode

        try:
            response = self._call(HoldMode, part, "hold_mode", HoldMode.Request(
                mode=mode, requester=requester, priority=priority, lease=lease, hold=hold, release=release))
        except ManagerUnreachable as error:
            raise ManagerUnreachable(f"{error} (a hold needs sm-bt manager: the reference's manager has none)") \
                from None
        return bool(response.accepted), str(response.reason), int(response.hold)

    def offers(self, part: str, service: str) -> bool:
        """Does the graph show ``/{part}/{service}`` now (``request_change``: an ``sm-bt manager``)?"""
        name = f"/{part}/{service}"
        return any(found == name for found, _ in self.node.get_service_names_and_types())

    def change_mode(self, part: str, mode: str) -> bool:
        """Ask for ``mode``; whether the manager accepted the request (not that it is done)."""
        from system_modes_msgs.srv import ChangeMode

        return bool(self._call(ChangeMode, part, "change_mode", ChangeMode.Request(mode_name=mode)).success)

    def wait_for_mode(self, part: str, mode: str, since: float) -> float:
        """Seconds from ``since`` (``time.monotonic()``) until ``get_mode`` answers ``mode``;
        :class:`NotConfirmed` after ``timeout``."""
        return self._wait(*_event_topic(part, "mode"), lambda: self.get_mode(part) == mode, since,
                          lambda: f"{part} is in mode {self.get_mode(part) or '(none)'!r}, not {mode!r}",
                          lambda event: bool(event.goal_mode.label == mode),
                          _Watched(part, f"change_mode {part} {mode}"))

    # -- lifecycle states ------------------------------------------------------------------------------

    def get_state(self, part: str) -> str:
        from lifecycle_msgs.srv import GetState

        return str(self._call(GetState, part, "get_state", GetState.Request()).current_state.label)

    def change_state(self, part: str, transition: str) -> bool:
        """Ask for a lifecycle transition by label; whether it was accepted.

        The request carries the label and its id: lifecycle nodes (rclcpp, rclpy) and ``sm-bt
        manager`` go by the label, the reference's ``mode_manager`` by the id alone (id 0 is
        ``create``). ``shutdown`` has one id per start state: the part's state is asked first."""
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        if transition not in REQUESTABLE_LABELS:
            hint = _closest(transition, list(REQUESTABLE_LABELS), "transitions")
            raise UnknownName(f"{transition!r} is not a transition{hint}")
        start = State.UNCONFIGURED
        if transition == "shutdown":
            with contextlib.suppress(ValueError):
                start = State.from_label(self.get_state(part))
        transition_id = int(transition_by_label(transition, start))
        request = ChangeState.Request(transition=Transition(id=transition_id, label=transition))
        return bool(self._call(ChangeState, part, "change_state", request).success)

    def wait_for_state(self, part: str, transition: str, since: float) -> float:
        goal = TRANSITION_GOALS[transition]
        return self._wait(*_event_topic(part, "state"), lambda: self.get_state(part) == goal, since,
                          lambda: f"{part} is {self.get_state(part)}, not {goal}",
                          lambda event: bool(event.goal_state.label == goal),
                          # a node's own service was asked, not the manager: only a system's counts
                          _Watched(part, f"change_state {part} {transition}", systems_only=True))

    # -- waiting ---------------------------------------------------------------------------------------

    def listen(self, part: str, kind: str) -> None:
        """Subscribe now to the part's ``kind`` events ("mode" or "state"), before a request whose
        confirmation will be waited for is sent. A subscription needs discovery before it hears
        anything: made only when the wait starts, it can miss a quick transition's event, and a
        node's manager may undo that transition before a poll sees it."""
        message_type, topic = _event_topic(part, kind)
        if topic not in self._listening:
            woken: list[tuple[float, Any]] = []
            self._listening[topic] = (self._subscribe(message_type, topic, woken), woken)

    def stop_listening(self) -> None:
        """Drop what :meth:`listen` subscribed to and no wait took."""
        for subscription, _ in self._listening.values():
            self.node.destroy_subscription(subscription)
        self._listening.clear()

    def _subscribe(self, message_type: Any, topic: str, woken: list[tuple[float, Any]]) -> Any:
        return self.node.create_subscription(message_type, topic, lambda event: woken.append((time.monotonic(), event)),
                                             _volatile())

    def _wait(self, message_type: Any, topic: str, reached: Callable[[], bool], since: float,
              where: Callable[[], str], tells: Callable[[Any], bool], request: _Watched) -> float:
        """Seconds from ``since`` until the part is there: an event that ``tells`` so (timed when it
        arrived), or ``reached()`` asked now and then (and after any other event); the failure of
        ``request`` on ``/diagnostics`` ends it with :class:`NotConfirmed`."""
        from diagnostic_msgs.msg import DiagnosticArray

        failures: list[str] = []
        listened = self._listening.pop(topic, None)
        if listened is None:
            woken: list[tuple[float, Any]] = []
            listened = (self._subscribe(message_type, topic, woken), woken)
        else:  # heard since listen(): only what came after the request counts
            woken = listened[1]
            woken[:] = [(at, event) for at, event in woken if at >= since]
        # Made after the manager accepted the request, so every /diagnostics message heard was sent after that.
        subscriptions = [
            listened[0],
            self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                          lambda message: failures.extend(request.failures(message)), _volatile())]
        try:
            deadline = since + self.timeout
            next_poll = 0.0
            while True:
                now = time.monotonic()
                told = next((at for at, event in woken if tells(event)), None)
                if told is not None:
                    return told - since
                if woken or now >= next_poll:
                    woken.clear()
                    next_poll = now + POLL
                    if reached():
                        return time.monotonic() - since
                if failures:
                    raise NotConfirmed(f"{failures[0]}: {where()}")
                if now >= deadline:
                    raise NotConfirmed(f"not confirmed within {self.timeout:g} s: {where()}")
                self.executor.spin_once(timeout_sec=min(0.05, max(0.0, deadline - now)))
        finally:
            for subscription in subscriptions:
                self.node.destroy_subscription(subscription)


def _volatile() -> Any:
    """The QoS of every subscription of a wait: volatile, it matches a node's volatile topics and the
    manager's latched ones alike, and hears only what comes now (a wait asks first for what was
    there before)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


def _event_topic(part: str, kind: str) -> tuple[Any, str]:
    """The message type and topic of a part's ``kind`` events: "mode" or "state"."""
    if kind == "mode":
        from system_modes_msgs.msg import ModeEvent

        return ModeEvent, f"/{part}/mode_event"
    from lifecycle_msgs.msg import TransitionEvent

    return TransitionEvent, f"/{part}/transition_event"


@dataclass(frozen=True)
class _Watched:
    """A request waited for, as ``sm-bt manager`` describes it on ``/diagnostics``
    (:mod:`sm_bt.ros.diagnostics`); ``systems_only``: a node's status does not count."""

    part: str
    description: str
    systems_only: bool = False

    def failures(self, message: Any) -> list[str]:
        """What a ``DiagnosticArray`` says of this request's failure (nothing if it does not)."""
        found = []
        for status in message.status:
            if status.hardware_id != self.part:
                continue
            values = {pair.key: pair.value for pair in status.values}
            if self.systems_only and "reachable" in values:  # only a node's status says it
                continue
            last = values.get("last_request", "")  # "#12 change_mode pilot f_normal_mode"
            if values.get("last_request_outcome") == "failed" and last.partition(" ")[2] == self.description:
                found.append(f"the manager says request {last} failed: {values.get('last_request_reason', '')}")
        return found


@dataclass(frozen=True)
class Outcome:
    """How a request to ``sm-bt manager`` ended, as its ``/{part}/request_outcome`` tells it."""

    request: int
    description: str
    requester: str
    outcome: str  # succeeded, failed or refused
    reason: str


def follow_outcomes(node: Any, part: str, told: Callable[[Outcome], None]) -> Any:
    """Subscribe ``node`` (spun by its owner) to ``/{part}/request_outcome``: ``told`` each outcome, in
    that node's executor thread; the subscription (for ``node.destroy_subscription``)."""
    from sm_bt_msgs.msg import RequestOutcome

    from sm_bt.ros.manager_node import OUTCOMES

    def heard(message: Any) -> None:
        told(Outcome(int(message.request), str(message.description), str(message.requester), str(message.outcome),
                     str(message.reason)))

    return node.create_subscription(RequestOutcome, f"/{part.strip('/')}/request_outcome", heard, OUTCOMES)
