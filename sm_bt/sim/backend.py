"""SimBackend: the :class:`~sm_bt.engine.backend.Backend` protocol served by simulated lifecycle nodes.

Every node of the model runs as a :class:`~sm_bt.sim.node.SimNode`. Time is a
:class:`~sm_bt.engine.clock.VirtualClock`: nothing happens until its owner advances it, so runs are
deterministic. Requests reach a node through the clock (delay 0) and never answer from inside the
call; callbacks take ``transition_delay`` (``error_delay`` for ``on_error``), parameter sets take
``parameter_delay``.

Faults are injected from outside (tests, demos) and each one is recorded in :attr:`SimBackend.events`:
:meth:`~SimBackend.fail_next`, :meth:`~SimBackend.hang_next`, :meth:`~SimBackend.reject_parameters`,
:meth:`~SimBackend.set_parameter`, :meth:`~SimBackend.trigger`, :meth:`~SimBackend.crash`,
:meth:`~SimBackend.vanish`, :meth:`~SimBackend.restart`, :meth:`~SimBackend.start_late`. Armed faults
and delay overrides belong to the simulation, not to the node process: they survive a restart
(:meth:`~SimBackend.clear_faults` disarms them). Fault methods act at once (their reports to the
listener come from inside the call); only the Backend requests are deferred.

Reports to the listener come at once unless ``report_delay`` is set: then every report (appearing,
state, parameters, vanishing) comes that many seconds after it happened, in order, while answers to
requests still come at once. That is how ROS 2 can deliver them (a ``change_state`` answer before the
node's ``transition_event``, a ``set_parameters`` answer before its ``/parameter_events``), and the
engine must cope with either order.

Nodes named in ``plain`` have no lifecycle services (parameters only), as a node without
``rclcpp_lifecycle`` on ROS: they are reported ``active`` with ``lifecycle=False``, accept parameter
sets, and answer every ``change_state`` with a failure, through the clock like every answer.

The backend is single-threaded: drive it from the thread that advances the clock.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import TimerHandle, VirtualClock
from sm_bt.engine.lifecycle import REQUESTABLE, Outcome, Transition
from sm_bt.model.states import PRIMARY_STATES, State
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim.node import ParameterRejected, SimNode, TransitionEvent, TransitionRefused

_REQUESTABLE = frozenset(step.transition for step in REQUESTABLE)
#: The states a node process can start in, in lifecycle order (for messages).
_STARTABLE = tuple(s for s in State if s in PRIMARY_STATES)

#: A state to start in: a :class:`State` or its label (``"active"``).
StartState = State | str


class NodeStatus(str, enum.Enum):
    """Whether a simulated node's process runs and answers."""

    NOT_STARTED = "not started"
    RUNNING = "running"
    CRASHED = "crashed"  # stopped answering, not yet reported vanished
    VANISHED = "vanished"


class SimEventKind(str, enum.Enum):
    REQUEST = "request"  # a change_state / set_parameters call arrived at the backend
    RESPONSE = "response"  # its done() was called
    TRANSITION = "transition"  # a lifecycle TransitionEvent of the node
    PARAMETERS = "parameters"  # parameter values changed (by a set or from outside)
    FAULT = "fault"  # a fault was armed or took effect
    STARTED = "started"  # a node process started (late start, restart)
    VANISHED = "vanished"  # the backend reported the node gone


@dataclass(frozen=True)
class SimEvent:
    """Something that happened in the simulation; ``details`` is a one-line human description."""

    time: float
    node: str
    kind: SimEventKind
    details: str
    transition: TransitionEvent | None = None
    parameters: Mapping[str, ParamValue] | None = None

    def __str__(self) -> str:
        return f"{self.time:8.3f}  {self.node:<20} {self.kind.value:<10} {self.details}"


@dataclass(eq=False)  # identity: two equal-looking calls are still two calls
class _PendingCall:
    node: str
    label: str
    done: Done
    answered: bool = False


@dataclass(frozen=True)
class _Failure:
    outcome: Outcome
    on_error: Outcome


_SUCCEEDS = _Failure(Outcome.SUCCESS, Outcome.SUCCESS)


class _Callbacks:
    """A transition's callbacks running in a node: the callback returns ``outcome`` after the
    delay; on ERROR, error processing follows. The primary state reached answers ``call`` (none
    for a transition the node started by itself).

    One object per transition in flight, its steps scheduled as its bound methods: closures made
    a dozen objects per transition, and a bring-up of 10,000 nodes has them all in flight at once
    (the garbage collector's full passes grew with them)."""

    __slots__ = ("backend", "call", "node", "on_error", "outcome", "sim", "transition")

    def __init__(self, backend: SimBackend, node: str, transition: Transition, outcome: Outcome, on_error: Outcome,
                 call: _PendingCall | None) -> None:
        self.backend = backend
        self.node = node
        self.sim = backend._nodes[node]  # this process of the node (a restart cancels its timers)
        self.transition = transition
        self.outcome = outcome
        self.on_error = on_error
        self.call = call

    def start(self) -> None:
        backend = self.backend
        backend._after(self.node, backend._delay(self.node, self.transition, backend.transition_delay), self.returned)

    def returned(self) -> None:
        backend = self.backend
        event = self.sim.complete(self.outcome)
        backend._moved(self.node, event)
        if event.goal is State.ERRORPROCESSING:
            backend._after(self.node, backend._delay(self.node, None, backend.error_delay), self.error_processed)
        else:
            self._finished(event.goal)

    def error_processed(self) -> None:
        event = self.sim.complete(self.on_error)
        self.backend._moved(self.node, event)
        self._finished(event.goal)

    def _finished(self, final: State) -> None:
        if self.call is not None:
            self.backend._respond(self.call, _transition_result(self.node, self.transition, self.outcome, final))


class _NodeTimer:
    """``action``, scheduled on behalf of a node's process (its handle in ``timers`` until it runs)."""

    __slots__ = ("action", "handle", "timers")

    def __init__(self, timers: set[TimerHandle], action: Callable[[], None]) -> None:
        self.timers = timers
        self.action = action
        self.handle: TimerHandle | None = None

    def __call__(self) -> None:
        self.timers.discard(self.handle)
        self.action()


def _format(values: Mapping[str, ParamValue]) -> str:
    return "{" + ", ".join(f"{key}: {value!r}" for key, value in values.items()) + "}"


class SimBackend:
    """Simulated lifecycle nodes for every node part of ``model``.

    Nodes start running in ``initial_state`` (one state for all, or per node; unlisted nodes are
    unconfigured; a :class:`State` or its label, ``"active"``) with their default mode's parameter
    values, overridden per node by ``initial_parameters``. Nodes named in ``late`` are not running
    until that virtual time. Nodes named in ``plain`` have no lifecycle (see the module docstring):
    they always run ``active``, whatever one ``initial_state`` for all says. With ``history=False``
    nothing is kept in :attr:`events` nor in the nodes' ``transitions`` (benchmarks: at 10,000
    nodes a bring-up records 80,000 events and 40,000 transitions).
    """

    def __init__(
        self,
        model: Model,
        clock: VirtualClock | None = None,
        *,
        transition_delay: float = 0.05,
        error_delay: float = 0.05,
        parameter_delay: float = 0.01,
        vanish_after: float = 1.0,
        initial_state: StartState | Mapping[str, StartState] = State.UNCONFIGURED,
        initial_parameters: Mapping[str, Mapping[str, ParamValue]] | None = None,
        late: Mapping[str, float] | None = None,
        plain: Collection[str] = (),
        report_delay: float = 0.0,
        history: bool = True,
    ) -> None:
        for label, value in (("transition_delay", transition_delay), ("error_delay", error_delay),
                             ("parameter_delay", parameter_delay), ("vanish_after", vanish_after),
                             ("report_delay", report_delay)):
            _check_delay(label, value)
        self._clock = clock if clock is not None else VirtualClock()
        self.transition_delay = transition_delay
        self.error_delay = error_delay
        self.parameter_delay = parameter_delay
        self.vanish_after = vanish_after
        self.report_delay = report_delay
        #: Everything that happened, oldest first.
        self.events: list[SimEvent] = []
        self._history = history

        names = tuple(part.name for part in model.nodes)
        self._declared = {part.name: part.modes[part.default_mode].values() for part in model.nodes}
        per_node = initial_state if isinstance(initial_state, Mapping) else {}
        for label, mapping in (("initial_state", per_node), ("initial_parameters", initial_parameters or {}),
                               ("late", late or {}), ("plain", dict.fromkeys(plain))):
            unknown = sorted(set(mapping) - set(names))
            if unknown:
                raise ValueError(f"{label} names unknown nodes {unknown} (nodes: {', '.join(names)})")
        self._plain = frozenset(plain)
        common = State.UNCONFIGURED if isinstance(initial_state, Mapping) else \
            _start_state(initial_state, "initial_state")
        self._initial_state: dict[str, State] = {}
        for name in names:
            if name in per_node:
                state = _start_state(per_node[name], f"initial_state of node {name}")
                if name in self._plain and state is not State.ACTIVE:
                    raise ValueError(f"initial_state of node {name}: it has no lifecycle services (parameters "
                                     f"only), so it runs active, not {state}")
            else:
                state = State.ACTIVE if name in self._plain else common
            self._initial_state[name] = state
        self._initial_overrides = {name: dict((initial_parameters or {}).get(name, {})) for name in names}

        self._nodes: dict[str, SimNode] = {}
        self._status: dict[str, NodeStatus] = {}
        self._pending: dict[str, list[_PendingCall]] = {name: [] for name in names}
        self._timers: dict[str, set[TimerHandle]] = {name: set() for name in names}
        self._delays: dict[tuple[str, Transition | None], float] = {}
        self._failures: dict[tuple[str, Transition], _Failure] = {}
        self._hangs: set[tuple[str, Transition]] = set()
        self._hung: set[str] = set()  # running nodes stuck in a transition that hangs
        self._parameter_rejections: dict[str, str] = {}
        self._listener: BackendListener | None = None
        self._watched: set[str] = set()
        self._visible: set[str] = set()  # watched nodes reported appeared (and not vanished since)

        for name in names:
            self._nodes[name] = self._spawn(name, self._initial_state[name])  # validates the initial values
            self._status[name] = NodeStatus.RUNNING
        for name, at in (late or {}).items():
            self.start_late(name, at)

    # -- inspection ---------------------------------------------------------------------------------

    @property
    def clock(self) -> VirtualClock:
        return self._clock

    @property
    def nodes(self) -> tuple[str, ...]:
        """The simulated node names, in model order."""
        return tuple(self._nodes)

    def node(self, name: str) -> SimNode:
        """The current process of node ``name`` (a fresh one after a restart)."""
        self._require(name)
        return self._nodes[name]

    def status(self, name: str) -> NodeStatus:
        self._require(name)
        return self._status[name]

    def is_plain(self, name: str) -> bool:
        """True for a node without lifecycle services (parameters only)."""
        self._require(name)
        return name in self._plain

    def in_flight(self, name: str) -> tuple[str, ...]:
        """The calls ``name`` received and has not answered yet, oldest first, by label
        (``"configure"``, ``"set_parameters"``)."""
        self._require(name)
        return tuple(call.label for call in self._pending[name])

    def hung(self) -> tuple[str, ...]:
        """Running nodes stuck in a transition armed with :meth:`hang_next` (until crash or restart)."""
        return tuple(name for name in self._nodes if name in self._hung)

    # -- Backend protocol ---------------------------------------------------------------------------

    def attach(self, nodes: Sequence[str], listener: BackendListener) -> None:
        """Report to ``listener`` about ``nodes``: running ones appear now, others when they start."""
        self.detach()
        self._listener = listener
        self._watched = set(nodes)
        for name in dict.fromkeys(nodes):
            if self._status.get(name) is NodeStatus.RUNNING:
                self._appear(name)

    def detach(self) -> None:
        """Stop all listener reports. Calls in flight still get their ``done``."""
        self._listener = None
        self._watched = set()
        self._visible = set()

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        call = _PendingCall(node, transition.label, done)
        self._record(node, SimEventKind.REQUEST, f"change_state {transition.label} ({int(transition)})")
        if self._accept(call):
            self._after(node, 0.0, functools.partial(self._deliver_transition, call, transition))

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        values = dict(parameters)
        call = _PendingCall(node, "set_parameters", done)
        self._record(node, SimEventKind.REQUEST, f"set_parameters {_format(values)}", parameters=values)
        if self._accept(call):
            self._after(node, self.parameter_delay, lambda: self._deliver_parameters(call, values))

    # -- configuration and fault injection ----------------------------------------------------------

    def set_delay(self, node: str, seconds: float, transition: Transition | None = None) -> None:
        """How long ``node``'s callback for ``transition`` runs; with ``None``, every callback of the
        node (``on_error`` included) that has no per-transition delay."""
        self._require(node)
        _check_delay("delay", seconds)
        if transition is not None:
            self._require_requestable(transition)
        self._delays[(node, transition)] = seconds

    def fail_next(self, node: str, transition: Transition, outcome: Outcome = Outcome.FAILURE,
                  on_error: Outcome = Outcome.SUCCESS) -> None:
        """The next requested ``transition`` of ``node`` returns ``outcome`` (FAILURE or ERROR) from its
        callback; after ERROR, ``on_error`` returns ``on_error`` (SUCCESS -> unconfigured, else finalized).
        :meth:`trigger` does not consume it (it brings its own outcome)."""
        self._require_lifecycle(node, "fail a transition of")
        self._require_requestable(transition)
        if outcome is Outcome.SUCCESS:
            raise ValueError("fail_next needs Outcome.FAILURE or Outcome.ERROR")
        self._failures[(node, transition)] = _Failure(outcome, on_error)
        self._record(node, SimEventKind.FAULT, f"armed: next on_{transition.label} returns {outcome.name}")

    def hang_next(self, node: str, transition: Transition) -> None:
        """The next requested ``transition`` of ``node`` enters its transition state and never leaves it:
        no response comes until the node crashes (then vanishes) or restarts."""
        self._require_lifecycle(node, "hang a transition of")
        self._require_requestable(transition)
        self._hangs.add((node, transition))
        self._record(node, SimEventKind.FAULT, f"armed: next {transition.label} hangs")

    def reject_parameters(self, node: str, reason: str | None) -> None:
        """While set, every ``set_parameters`` on ``node`` fails with ``reason`` and changes nothing;
        ``None`` clears it."""
        self._require(node)
        if reason is None:
            self._parameter_rejections.pop(node, None)
            self._record(node, SimEventKind.FAULT, "cleared: parameter sets accepted again")
        else:
            self._parameter_rejections[node] = reason
            self._record(node, SimEventKind.FAULT, f"armed: parameter sets rejected ({reason})")

    def set_parameter(self, node: str, name: str, value: ParamValue) -> None:
        """Parameter ``name`` of the running ``node`` changes from outside (another client, the node
        itself); type-checked like a set (``ValueError``), reported with ``node_parameters``."""
        self._require_running(node, "set a parameter of")
        try:
            self._nodes[node].set_parameters({name: value})
        except ParameterRejected as error:
            raise ValueError(f"node {node}: {error}") from None
        self._record(node, SimEventKind.FAULT, f"parameter {name} changed from outside")
        self._parameters_changed(node, {name: value})

    def trigger(self, node: str, transition: Transition, outcome: Outcome = Outcome.SUCCESS,
                on_error: Outcome = Outcome.SUCCESS) -> None:
        """The running ``node`` starts ``transition`` by itself (no request, no response); its callback
        returns ``outcome`` after the delay, and after ERROR ``on_error`` returns ``on_error``.
        ``ValueError`` if the transition is not valid in the node's state.

        laser_resender's failure: ``trigger("laser_resender", Transition.DEACTIVATE, Outcome.ERROR)``
        gives deactivating -> errorprocessing -> unconfigured (events 4, 42, 60)."""
        self._require_running(node, "trigger a transition of")
        self._require_lifecycle(node, "trigger a transition of")
        try:
            event = self._nodes[node].start(transition)
        except TransitionRefused as error:
            raise ValueError(f"node {node} cannot {transition.label} by itself: {error}") from None
        self._record(node, SimEventKind.FAULT, f"{transition.label} by itself, on_{transition.label} will "
                                            f"return {outcome.name}")
        self._moved(node, event)
        _Callbacks(self, node, transition, outcome, on_error, None).start()

    def crash(self, node: str) -> None:
        """The running ``node`` stops answering at once: calls in flight and new calls get no response.
        After ``vanish_after`` s it is reported vanished and every pending call fails."""
        self._require_running(node, "crash")
        self._cancel_timers(node)
        self._hung.discard(node)
        self._status[node] = NodeStatus.CRASHED
        self._record(node, SimEventKind.FAULT, "crashed: no more answers")
        self._after(node, self.vanish_after, lambda: self._vanish(node))

    def vanish(self, node: str) -> None:
        """The process of the running (or crashed) ``node`` ends, as when it exits or is killed: it is
        reported vanished at once and its pending calls fail (ROS 2's graph shows such a node leave)."""
        self._require(node)
        if self._status[node] not in (NodeStatus.RUNNING, NodeStatus.CRASHED):
            raise ValueError(f"cannot make node {node} vanish: it is {self._status[node].value}")
        self._cancel_timers(node)
        self._hung.discard(node)
        self._vanish(node, "its process ended")

    def restart(self, node: str, state: StartState | None = None, *, unnoticed: bool = False) -> None:
        """A fresh process of ``node`` (running, crashed, vanished or not yet started) starts now in
        ``state`` (default: unconfigured; a plain node always starts active) with the initial
        parameter values; calls pending on the old one fail at once, once the new process is up
        (so that a client calling again from their ``done`` reaches the new one). ``unnoticed``: a
        listener that saw the old process hears of the new one as a change of its state only, as
        over ROS 2 for a process restarted faster than the graph is looked at (once a second)."""
        self._require(node)
        plain = node in self._plain
        default = State.ACTIVE if plain else State.UNCONFIGURED
        start = default if state is None else _start_state(state, f"cannot restart node {node}:")
        if plain and start is not State.ACTIVE:
            raise ValueError(f"cannot restart node {node} in {start}: it has no lifecycle services (parameters "
                             "only), so it runs active")
        stale = self._stop(node)
        if unnoticed and node in self._visible:
            self._nodes[node] = self._spawn(node, start)
            self._status[node] = NodeStatus.RUNNING
            self._record(node, SimEventKind.STARTED, f"restarted in {start}, unnoticed")
            self._report(lambda listener: listener.node_state(node, start))
        else:
            self._start(node, start, f"restarted in {start}")
        self._fail(stale, f"node {node} restarted")

    def clear_faults(self, node: str | None = None) -> None:
        """Disarm what :meth:`fail_next`, :meth:`hang_next` and :meth:`reject_parameters` armed (for
        ``node``, or every node) and not yet used; what already happened stays (a hung node stays
        hung until it restarts)."""
        nodes = self.nodes if node is None else (node,)
        for name in nodes:
            self._require(name)
            armed = [key for key in self._failures if key[0] == name] + [key for key in self._hangs if key[0] == name]
            for key in armed:
                self._failures.pop(key, None)
                self._hangs.discard(key)
            if armed or name in self._parameter_rejections:
                self._parameter_rejections.pop(name, None)
                self._record(name, SimEventKind.FAULT, "cleared: armed faults disarmed")

    def start_late(self, node: str, at: float) -> None:
        """``node`` is not running until virtual time ``at``; then it starts in its initial state and
        appears. Not for a node already reported to a listener (use :meth:`crash`/:meth:`restart`)."""
        self._require(node)
        if node in self._visible:
            raise ValueError(f"node {node} was already reported running; use crash() and restart()")
        stale = self._stop(node)
        self._status[node] = NodeStatus.NOT_STARTED
        self._record(node, SimEventKind.FAULT, f"not running until t={at:g}")
        self._fail(stale, f"node {node} is not running")
        self._after(node, at - self._clock.now(),
                    lambda: self._start(node, self._initial_state[node], f"started late in "
                                                                        f"{self._initial_state[node]}"))

    # -- request handling ---------------------------------------------------------------------------

    def _accept(self, call: _PendingCall) -> bool:
        """Queue a call on a running node (True); a crashed node keeps it unanswered until it vanishes;
        anything else fails, through the clock."""
        status = self._status.get(call.node)
        if status in (NodeStatus.RUNNING, NodeStatus.CRASHED):
            self._pending[call.node].append(call)
            return status is NodeStatus.RUNNING
        result = CallResult(False, f"node {call.node} is not running")
        self._clock.call_later(0.0, lambda: self._respond(call, result))
        return False

    def _deliver_transition(self, call: _PendingCall, transition: Transition) -> None:
        node = call.node
        if node in self._plain:
            # The ROS backend's wording (sm_bt.ros.backend), so that both backends read the same.
            self._respond(call, CallResult(False, f"node {node} has no lifecycle services (parameters only): "
                                                  f"it cannot {transition.label}"))
            return
        try:
            event = self._nodes[node].start(transition)
        except TransitionRefused as error:
            self._respond(call, CallResult(False, f"{transition.label} of {node} refused: {error}", refused=True))
            return
        self._moved(node, event)
        if (node, transition) in self._hangs:
            self._hangs.discard((node, transition))
            self._hung.add(node)
            self._record(node, SimEventKind.FAULT, f"{transition.label} hangs in {event.goal}: no response")
            return
        failure = self._failures.pop((node, transition), _SUCCEEDS)
        if failure.outcome is not Outcome.SUCCESS:
            self._record(node, SimEventKind.FAULT, f"on_{transition.label} will return {failure.outcome.name}")
        _Callbacks(self, node, transition, failure.outcome, failure.on_error, call).start()

    def _deliver_parameters(self, call: _PendingCall, values: dict[str, ParamValue]) -> None:
        node = call.node
        rejection = self._parameter_rejections.get(node)
        if rejection is not None:
            self._respond(call, CallResult(False, rejection))
            return
        try:
            self._nodes[node].set_parameters(values)
        except ParameterRejected as error:
            self._respond(call, CallResult(False, f"set_parameters on {node} rejected: {error}"))
            return
        self._parameters_changed(node, values)
        self._respond(call, CallResult(True))

    def _respond(self, call: _PendingCall, result: CallResult) -> None:
        if call.answered:
            return
        call.answered = True
        pending = self._pending.get(call.node, [])
        if call in pending:
            pending.remove(call)
        outcome = "ok" if result.ok else f"failed: {result.reason}"
        self._record(call.node, SimEventKind.RESPONSE, f"{call.label}: {outcome}")
        call.done(result)

    # -- process life -------------------------------------------------------------------------------

    def _spawn(self, node: str, state: State) -> SimNode:
        sim = SimNode(node, self._declared[node], self._clock, state=state, lifecycle=node not in self._plain,
                      history=self._history)
        try:
            sim.set_parameters(self._initial_overrides[node])
        except ParameterRejected as error:
            raise ValueError(f"initial_parameters for node {node}: {error}") from None
        return sim

    def _start(self, node: str, state: State, details: str) -> None:
        self._nodes[node] = self._spawn(node, state)
        self._status[node] = NodeStatus.RUNNING
        self._record(node, SimEventKind.STARTED, details)
        if node in self._watched:
            self._appear(node)

    def _stop(self, node: str) -> list[_PendingCall]:
        """End the current process without a vanish report; return its unanswered calls, for the
        caller to fail once the node's new status is in place (a caller's ``done`` may call again
        at once, and that call must reach the new process, not the old one)."""
        self._cancel_timers(node)
        self._hung.discard(node)
        stale, self._pending[node] = self._pending[node], []
        return stale

    def _fail(self, calls: list[_PendingCall], reason: str) -> None:
        for call in calls:
            self._respond(call, CallResult(False, reason))

    def _vanish(self, node: str, why: str | None = None) -> None:
        self._status[node] = NodeStatus.VANISHED
        reason = why if why is not None else f"no answer for {float(self.vanish_after)} s (crashed?)"
        self._record(node, SimEventKind.VANISHED, reason)
        if node in self._visible and self._listener is not None:
            self._visible.discard(node)
            self._report(lambda listener: listener.node_vanished(node, reason))
        self._fail_pending(node, f"node {node} vanished")

    def _fail_pending(self, node: str, reason: str) -> None:
        for call in list(self._pending[node]):
            self._respond(call, CallResult(False, reason))

    # -- reporting and bookkeeping ------------------------------------------------------------------

    def _appear(self, node: str) -> None:
        if self._listener is None:
            return
        sim = self._nodes[node]
        self._visible.add(node)
        report = NodeReport(sim.state, sim.parameters, lifecycle=sim.lifecycle)
        self._report(lambda listener: listener.node_appeared(node, report))

    def _moved(self, node: str, event: TransitionEvent) -> None:
        self._record(node, SimEventKind.TRANSITION, str(event), transition=event)
        if node in self._visible and self._listener is not None:
            self._report(lambda listener: listener.node_state(node, event.goal))

    def _parameters_changed(self, node: str, values: Mapping[str, ParamValue]) -> None:
        self._record(node, SimEventKind.PARAMETERS, _format(values), parameters=dict(values))
        if values and node in self._visible and self._listener is not None:
            changed = dict(values)
            self._report(lambda listener: listener.node_parameters(node, changed))

    def _report(self, deliver: Callable[[BackendListener], None]) -> None:
        """Tell the listener now, or ``report_delay`` later (in order: equal delays run FIFO); a
        report still on its way when the listener detaches is dropped."""
        listener = self._listener
        if listener is None:
            return
        if self.report_delay == 0:
            deliver(listener)
            return

        def later() -> None:
            if self._listener is listener:
                deliver(listener)

        self._clock.call_later(self.report_delay, later)

    def _record(self, node: str, kind: SimEventKind, details: str, *, transition: TransitionEvent | None = None,
                parameters: Mapping[str, ParamValue] | None = None) -> None:
        if self._history:
            self.events.append(SimEvent(self._clock.now(), node, kind, details, transition, parameters))

    def _after(self, node: str, delay: float, action: Callable[[], None]) -> None:
        """Schedule ``action`` on behalf of ``node``'s process, so that a crash or restart cancels it."""
        timers = self._timers[node]
        run = _NodeTimer(timers, action)
        run.handle = self._clock.call_later(max(0.0, delay), run)
        timers.add(run.handle)

    def _cancel_timers(self, node: str) -> None:
        for handle in self._timers[node]:
            handle.cancel()
        self._timers[node].clear()

    def _delay(self, node: str, transition: Transition | None, default: float) -> float:
        per_node = self._delays.get((node, None), default)
        return per_node if transition is None else self._delays.get((node, transition), per_node)

    def _require(self, node: str) -> None:
        if node not in self._nodes:
            raise KeyError(f"no simulated node {node!r} (nodes: {', '.join(self._nodes)})")

    def _require_lifecycle(self, node: str, action: str) -> None:
        self._require(node)
        if node in self._plain:
            raise ValueError(f"cannot {action} node {node}: it has no lifecycle services (parameters only)")

    def _require_running(self, node: str, action: str) -> None:
        self._require(node)
        if self._status[node] is not NodeStatus.RUNNING:
            raise ValueError(f"cannot {action} node {node}: it is {self._status[node].value}")

    @staticmethod
    def _require_requestable(transition: Transition) -> None:
        if transition not in _REQUESTABLE:
            raise ValueError(f"{transition.name} is not a requestable transition")


def _transition_result(node: str, transition: Transition, outcome: Outcome, final: State) -> CallResult:
    if outcome is Outcome.SUCCESS:
        return CallResult(True)
    reason = f"{transition.label} of {node} failed: on_{transition.label} returned {outcome.name}"
    if outcome is Outcome.ERROR:
        reason += f" (node went to errorprocessing, then {final})"
    return CallResult(False, reason)


def _start_state(value: StartState, what: str) -> State:
    """``value`` as a state a node process can start in; ``ValueError`` naming the valid ones."""
    valid = ", ".join(state.label for state in _STARTABLE)
    if isinstance(value, State):
        state = value
    else:
        try:
            state = State.from_label(value)
        except ValueError:
            raise ValueError(f"{what} {value!r} is not a lifecycle state: use one of {valid}") from None
    if not state.is_primary:
        raise ValueError(f"{what} {state.label!r} is not a primary state: a node starts in one of {valid}")
    return state


def _check_delay(label: str, seconds: float) -> None:
    if not (math.isfinite(seconds) and seconds >= 0):
        raise ValueError(f"{label} must be a finite number of seconds >= 0, not {seconds!r}")
