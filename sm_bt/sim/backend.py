"""SimBackend: the :class:`~sm_bt.engine.backend.Backend` protocol served by simulated lifecycle nodes.

Every node of the model runs as a :class:`~sm_bt.sim.node.SimNode`. Time is a
:class:`~sm_bt.engine.clock.VirtualClock`: nothing happens until its owner advances it, so runs are
deterministic. Requests reach a node through the clock (delay 0) and never answer from inside the
call; callbacks take ``transition_delay`` (``error_delay`` for ``on_error``), parameter sets take
``parameter_delay``.

Faults are injected from outside (tests, demos: the methods of "configuration and fault
injection") and each one is recorded in :attr:`SimBackend.events`. Armed faults and delays belong
to the simulation, not to the node process (:mod:`sm_bt.sim.faults`). Fault methods act at once
(their reports to the listener come from inside the call); only the Backend requests are deferred.
Reports may come ``report_delay`` s late, after the answers (:mod:`sm_bt.sim.reports`), as ROS 2
can deliver them.

Nodes named in ``plain`` have no lifecycle services (parameters only), as a node without
``rclcpp_lifecycle`` on ROS: they are reported ``active`` with ``lifecycle=False``, accept parameter
sets, and answer every ``change_state`` with a failure, through the clock like every answer.

The backend is single-threaded: drive it from the thread that advances the clock.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Collection, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass

from sm_bt.engine.backend import BackendListener, CallResult, Done, NodeReport
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.lifecycle import REQUESTABLE, Outcome, Transition
from sm_bt.model.states import State
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim.events import NodeStatus, SimEvent, SimEventKind, format_values
from sm_bt.sim.faults import ArmedFaults, Failure
from sm_bt.sim.node import ParameterRejected, SimNode, TransitionEvent, TransitionRefused
from sm_bt.sim.reports import Reports
from sm_bt.sim.start import StartState, check_delay, check_names, initial_states, start_state
from sm_bt.sim.timers import ProcessTimers

__all__ = ["NodeStatus", "SimBackend", "SimEvent", "SimEventKind", "StartState"]

_REQUESTABLE = frozenset(edge.transition for edge in REQUESTABLE)


@dataclass(eq=False)  # identity: two equal-looking calls are still two calls
class _PendingCall:
    node: str
    label: str
    done: Done
    answered: bool = False


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
            check_delay(label, value)
        self._clock = clock if clock is not None else VirtualClock()
        self.transition_delay = transition_delay
        self.error_delay = error_delay
        self.parameter_delay = parameter_delay
        self.vanish_after = vanish_after
        #: Everything that happened, oldest first.
        self.events: list[SimEvent] = []
        self._history = history

        names = tuple(part.name for part in model.nodes)
        self._declared = {part.name: part.modes[part.default_mode].values() for part in model.nodes}
        check_names(names, initial_state=initial_state if isinstance(initial_state, Mapping) else {},
                    initial_parameters=initial_parameters or {}, late=late or {}, plain=plain)
        self._plain = frozenset(plain)
        self._initial_state = initial_states(names, initial_state, self._plain)
        self._initial_overrides = {name: dict((initial_parameters or {}).get(name, {})) for name in names}

        self._nodes: dict[str, SimNode] = {}
        self._status: dict[str, NodeStatus] = {}
        self._pending: dict[str, list[_PendingCall]] = {name: [] for name in names}
        self._timers = ProcessTimers(self._clock)
        self._armed = ArmedFaults()
        self._hung: set[str] = set()  # running nodes stuck in a transition that hangs
        self._reports = Reports(self._clock, report_delay)

        for name in names:
            self._nodes[name] = self._spawn(name, self._initial_state[name])  # validates the initial values
            self._status[name] = NodeStatus.RUNNING
        for name, at in (late or {}).items():
            self.start_late(name, at)

    # -- inspection ---------------------------------------------------------------------------------

    @property
    def report_delay(self) -> float:
        """Seconds between something happening and the listener hearing of it (see the module)."""
        return self._reports.delay

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
        self._reports.attach(nodes, listener)
        self._clock.batch = listener.batch
        for name in dict.fromkeys(nodes):
            if self._status.get(name) is NodeStatus.RUNNING:
                self._appear(name)

    def detach(self) -> None:
        """Stop all listener reports. Calls in flight still get their ``done``."""
        self._reports.detach()
        self._clock.batch = nullcontext

    def change_state(self, node: str, transition: Transition, done: Done) -> None:
        call = _PendingCall(node, transition.label, done)
        self._record(node, SimEventKind.REQUEST, lambda: f"change_state {transition.label} ({int(transition)})")
        if self._accept(call):
            self._after(node, 0.0, functools.partial(self._deliver_transition, call, transition))

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None:
        values = dict(parameters)
        call = _PendingCall(node, "set_parameters", done)
        self._record(node, SimEventKind.REQUEST, lambda: f"set_parameters {format_values(values)}", parameters=values)
        if self._accept(call):
            self._after(node, self.parameter_delay, lambda: self._deliver_parameters(call, values))

    # -- configuration and fault injection ----------------------------------------------------------

    def set_delay(self, node: str, seconds: float, transition: Transition | None = None) -> None:
        """How long ``node``'s callback for ``transition`` runs; with ``None``, every callback of the
        node (``on_error`` included) that has no per-transition delay."""
        self._require(node)
        check_delay("delay", seconds)
        if transition is not None:
            self._require_requestable(transition)
        self._armed.set_delay(node, seconds, transition)

    def fail_next(self, node: str, transition: Transition, outcome: Outcome = Outcome.FAILURE,
                  on_error: Outcome = Outcome.SUCCESS) -> None:
        """The next requested ``transition`` of ``node`` returns ``outcome`` (FAILURE or ERROR) from its
        callback; after ERROR, ``on_error`` returns ``on_error`` (SUCCESS -> unconfigured, else finalized).
        :meth:`trigger` does not consume it (it brings its own outcome)."""
        self._require_lifecycle(node, "fail a transition of")
        self._require_requestable(transition)
        if outcome is Outcome.SUCCESS:
            raise ValueError("fail_next needs Outcome.FAILURE or Outcome.ERROR")
        self._armed.fail_next(node, transition, Failure(outcome, on_error))
        self._record(node, SimEventKind.FAULT, f"armed: next on_{transition.label} returns {outcome.name}")

    def hang_next(self, node: str, transition: Transition) -> None:
        """The next requested ``transition`` of ``node`` enters its transition state and never leaves it:
        no response comes until the node crashes (then vanishes) or restarts."""
        self._require_lifecycle(node, "hang a transition of")
        self._require_requestable(transition)
        self._armed.hang_next(node, transition)
        self._record(node, SimEventKind.FAULT, f"armed: next {transition.label} hangs")

    def reject_parameters(self, node: str, reason: str | None) -> None:
        """While set, every ``set_parameters`` on ``node`` fails with ``reason`` and changes nothing;
        ``None`` clears it."""
        self._require(node)
        self._armed.reject_parameters(node, reason)
        if reason is None:
            self._record(node, SimEventKind.FAULT, "cleared: parameter sets accepted again")
        else:
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
        start = default if state is None else start_state(state, f"cannot restart node {node}:")
        if plain and start is not State.ACTIVE:
            raise ValueError(f"cannot restart node {node} in {start}: it has no lifecycle services (parameters "
                             "only), so it runs active")
        stale = self._stop(node)
        if unnoticed and self._reports.visible(node):
            self._nodes[node] = self._spawn(node, start)
            self._status[node] = NodeStatus.RUNNING
            self._record(node, SimEventKind.STARTED, f"restarted in {start}, unnoticed")
            self._reports.state(node, start)
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
            if self._armed.clear(name):
                self._record(name, SimEventKind.FAULT, "cleared: armed faults disarmed")

    def start_late(self, node: str, at: float) -> None:
        """``node`` is not running until virtual time ``at``; then it starts in its initial state and
        appears. Not for a node already reported to a listener (use :meth:`crash`/:meth:`restart`)."""
        self._require(node)
        if self._reports.visible(node):
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
        if self._armed.take_hang(node, transition):
            self._hung.add(node)
            self._record(node, SimEventKind.FAULT, f"{transition.label} hangs in {event.goal}: no response")
            return
        failure = self._armed.take_failure(node, transition)
        if failure.outcome is not Outcome.SUCCESS:
            self._record(node, SimEventKind.FAULT, f"on_{transition.label} will return {failure.outcome.name}")
        _Callbacks(self, node, transition, failure.outcome, failure.on_error, call).start()

    def _deliver_parameters(self, call: _PendingCall, values: dict[str, ParamValue]) -> None:
        node = call.node
        rejection = self._armed.rejection(node)
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
        self._record(call.node, SimEventKind.RESPONSE,
                     lambda: f"{call.label}: {'ok' if result.ok else f'failed: {result.reason}'}")
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
        if self._reports.watched(node):
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
        self._reports.vanished(node, reason)
        self._fail_pending(node, f"node {node} vanished")

    def _fail_pending(self, node: str, reason: str) -> None:
        for call in list(self._pending[node]):
            self._respond(call, CallResult(False, reason))

    # -- reporting and bookkeeping ------------------------------------------------------------------

    def _appear(self, node: str) -> None:
        sim = self._nodes[node]
        self._reports.appeared(node, NodeReport(sim.state, sim.parameters, lifecycle=sim.lifecycle))

    def _moved(self, node: str, event: TransitionEvent) -> None:
        self._record(node, SimEventKind.TRANSITION, event.__str__, transition=event)
        self._reports.state(node, event.goal)

    def _parameters_changed(self, node: str, values: Mapping[str, ParamValue]) -> None:
        self._record(node, SimEventKind.PARAMETERS, lambda: format_values(values), parameters=values)
        self._reports.parameters(node, values)

    def _record(self, node: str, kind: SimEventKind, details: str | Callable[[], str], *,
                transition: TransitionEvent | None = None, parameters: Mapping[str, ParamValue] | None = None) -> None:
        """Keep an event in the history, if one is kept. ``details`` may be a function that makes the
        text: a big bring-up makes several events per node, and no text is needed without a history."""
        if self._history:
            text = details if isinstance(details, str) else details()
            self.events.append(SimEvent(self._clock.now(), node, kind, text, transition,
                                        None if parameters is None else dict(parameters)))

    def _after(self, node: str, delay: float, action: Callable[[], None]) -> None:
        """Schedule ``action`` on behalf of ``node``'s process, so that a crash or restart cancels it."""
        self._timers.after(node, delay, action)

    def _cancel_timers(self, node: str) -> None:
        self._timers.cancel(node)

    def _delay(self, node: str, transition: Transition | None, default: float) -> float:
        return self._armed.delay(node, transition, default)

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
