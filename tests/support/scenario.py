"""Scenarios for the mode manager's property tests: data, a runner, and the invariants (issue 10).

A :class:`Scenario` is plain, printable data: a model (a fixed one by name, or generated YAML
text), manager options, simulated-backend options (delays, initial states, late joins, plain
nodes, slow nodes), timed :class:`Scheduled` s (requests, cancellations, faults), an optional small
py_trees tree of sm_bt behaviours, and a final user request. :func:`run` plays it on the virtual
clock, event by event (never in small fixed steps, so a scenario costs milliseconds), then
*heals* the world (faults disarmed, rejections cleared, crashed, vanished, hung and not-started
nodes restarted), lets the manager settle, makes the final request and lets it finish.

The invariants (each failure raises its own :class:`InvariantViolation` subclass, whose message
holds the scenario as Python, ready to paste into ``test_manager_regressions.py``):

* **I1** every request returned by the manager (user, tree, rule, recovery) is done by the end, at
  the latest at its creation time + its timeout; every failed one has a reason; a call that names a
  part, mode, transition or target the model does not have raises RequestError (and only such a one).
* **I2** a request that failed "preempted by request #k" was superseded by a later (k > id),
  accepted request k.
* **I3** last request wins: the final user request ends SUCCESS with the part's actual equal to its
  target when every node it needs runs, is not finalized, and (for a plain node) is only asked to
  be active; otherwise FAILURE with a reason that names the part or a node it cannot have.
* **I4** when nothing moves a node but the manager (no trigger, set_parameter, crash or restart
  step), no request fails with "cannot X while Y": a refusal caused by the manager's own call.
* **I5** at the end, the manager observed every running node's true state and parameters, and a
  reference :func:`~sm_bt.engine.inference.infer_all` (infer_node/infer_system, from scratch) infers
  the same actual for every part (incremental inference equals inference from scratch).
* **I6** recovery ends: after healing, within bounded virtual time, no request is in flight and
  none starts during a quiet period; between two user requests, recovery restores a part at most
  ``recovery_attempts`` times unless it stayed on target for ``recovery_window`` in between (or,
  with :data:`RESTART_RENEWS_BUDGET`, as docs/manager.md has it, a new process of the node appeared).
* **I7** no behaviour with a timeout is RUNNING longer than its timeout (plus one tick) after it
  was initialised; a ``hold_mode`` subtree no longer than its timeout plus its child's run.
* **I8** rules cascade (issue 10, item 2): once the manager settled after healing, no system is
  left off its target with a rule that applies (its ``if_target`` is the target, its ``if_part``
  is in the rule's state) when that part got there through a rule of its own: a sub-system's rule
  re-targeting it is a fault for the systems above, and their rules react. (A state the user
  asked for explicitly is left alone, as docs/manager.md says.)

* **I10** a request succeeds only with every part it is about (``Request.parts``: its part, or a
  continuation's nodes) at its target at that moment.

A scenario may also name a node that is expected to be *given up* by the end of its steps
(``expect_given_up``, a node hung in a transition with recovery on): then I6 also requires that
nothing is in flight on it and that its divergence is reported as an error with a reason.
"""

from __future__ import annotations

import contextlib
import logging
import re
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import py_trees
from hypothesis import strategies as st
from model_generator import FIXED_MODELS, fixed_model, generated_models, ints, model_from_text, pick, subset
from py_trees.common import Status

from sm_bt.behaviours import ChangeMode as ChangeModeBehaviour
from sm_bt.behaviours import ChangeState as ChangeStateBehaviour
from sm_bt.behaviours import HoldMode, WaitForMode, hold_mode
from sm_bt.engine.backend import BackendListener, NodeReport
from sm_bt.engine.events import Event, EventKind
from sm_bt.engine.holds import PRIORITIES
from sm_bt.engine.inference import infer_all
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, Outcome, transition_by_label
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Origin, Request
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, Model, NodePart, ParamValue
from sm_bt.sim import NodeStatus, SimBackend, SimulatedSystem

#: Period of the tree's ticks, in virtual seconds.
TICK = 0.1
#: Clock slack for comparisons of virtual times.
EPS = 1e-6
#: The final request's own timeout: long enough for any generated model's slowest plan, so that
#: I3 judges reachability, not the timeout.
FINAL_TIMEOUT = 600.0
#: A refusal caused by a transition already running on the node (the manager's own call, in I4).
BUSY_REFUSAL = re.compile(r"cannot \w+ while")
PREEMPTED = re.compile(r"preempted by request #(\d+)")
#: I6's budget is whole again after a user request, or once the part stayed on target for the
#: recovery window; docs/manager.md ("Giving up") adds: when a new process of the node appears. Issue 10
#: states I6 without that clause: set False to hold an engine to it (healing, the harness
#: repairing the world, gives the nodes it restarts a fresh budget either way).
RESTART_RENEWS_BUDGET = True


# -- scenario data ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ChangeMode:
    part: str
    mode: str
    timeout: float | None = None


@dataclass(frozen=True)
class ChangeState:
    part: str
    transition: str
    timeout: float | None = None


@dataclass(frozen=True)
class ChangeTo:
    part: str
    target: str
    timeout: float | None = None


@dataclass(frozen=True)
class Cancel:
    """Cancel the user request made ``request``-th (modulo how many were made so far)."""

    request: int


@dataclass(frozen=True)
class FailNext:
    node: str
    transition: str
    outcome: str = "failure"
    on_error: str = "success"


@dataclass(frozen=True)
class HangNext:
    node: str
    transition: str


@dataclass(frozen=True)
class RejectParameters:
    node: str
    reason: str | None


@dataclass(frozen=True)
class SetParameter:
    """A parameter changed from outside (another client)."""

    node: str
    name: str
    value: bool | int | float | str


@dataclass(frozen=True)
class Trigger:
    """The node starts one of the transitions valid in its state by itself (``choice`` picks it)."""

    node: str
    choice: int = 0
    outcome: str = "success"
    on_error: str = "success"


@dataclass(frozen=True)
class Crash:
    node: str


@dataclass(frozen=True)
class Restart:
    node: str
    state: str = "unconfigured"


RequestAction = ChangeMode | ChangeState | ChangeTo
Action = RequestAction | Cancel | FailNext | HangNext | RejectParameters | SetParameter | Trigger | Crash | Restart
#: Steps after which a node may move without the manager (I4 does not apply).
MOVERS = (Trigger, SetParameter, Crash, Restart)


@dataclass(frozen=True)
class Scheduled:
    at: float
    action: Action


@dataclass(frozen=True)
class TreeItem:
    """One behaviour of the tree: ``kind`` is change_mode, change_state, wait_for_mode or
    hold_mode (``arg`` is the mode or transition; ``ticks`` is how long hold_mode's child runs)."""

    kind: str
    part: str
    arg: str
    timeout: float
    ticks: int = 0


@dataclass(frozen=True)
class ManagerOptions:
    grace_period: float = 2.0
    request_timeout: float = 30.0
    recovery_attempts: int = 3
    recovery_window: float = 60.0
    rules: bool = True
    recovery: bool = True


@dataclass(frozen=True)
class SimOptions:
    transition_delay: float = 0.05
    error_delay: float = 0.05
    parameter_delay: float = 0.01
    vanish_after: float = 1.0
    initial_state: tuple[tuple[str, str], ...] = ()
    late: tuple[tuple[str, float], ...] = ()
    plain: tuple[str, ...] = ()
    slow: tuple[tuple[str, float], ...] = ()  # per-node callback delay
    report_delay: float = 0.0  # reports after the answers, as ROS may deliver them

    @property
    def longest_delay(self) -> float:
        return max([self.transition_delay, self.error_delay, self.parameter_delay, self.report_delay,
                    *(d for _, d in self.slow)])


@dataclass(frozen=True)
class Scenario:
    model: str  # a name of model_generator.FIXED_MODELS, or "generated" (then model_text)
    final: ChangeMode | ChangeTo
    manager: ManagerOptions = ManagerOptions()
    sim: SimOptions = SimOptions()
    steps: tuple[Scheduled, ...] = ()
    tree: tuple[tuple[TreeItem, ...], ...] = ()
    #: When the final request comes after healing: None once the manager settled, else that many
    #: seconds after the last step (0: the same instant, with everything still under way).
    final_delay: float | None = None
    #: A node hung in a transition that recovery must have given up on when the steps end (I6).
    expect_given_up: str | None = None
    model_text: str | None = field(default=None, repr=False)

    def load(self) -> Model:
        return model_from_text(self.model_text) if self.model_text is not None else fixed_model(self.model)

    def to_python(self) -> str:
        """The scenario as a Python expression (names from this module), for a regression test."""
        lines = ["Scenario("]
        if self.model_text is not None:
            lines.append(f"    model={self.model!r},\n    model_text='''\\\n{self.model_text}''',")
        else:
            lines.append(f"    model={self.model!r},")
        lines.append(f"    manager={_short_repr(self.manager)},")
        lines.append(f"    sim={_short_repr(self.sim)},")
        if self.steps:
            lines.append("    steps=(")
            lines += [f"        Scheduled({s.at!r}, {_short_repr(s.action)})," for s in self.steps]
            lines.append("    ),")
        if self.tree:
            lines.append("    tree=(")
            lines += ["        (" + " ".join(_short_repr(i) + "," for i in branch) + ")," for branch in self.tree]
            lines.append("    ),")
        lines.append(f"    final={_short_repr(self.final)},")
        if self.final_delay is not None:
            lines.append(f"    final_delay={self.final_delay!r},")
        if self.expect_given_up is not None:
            lines.append(f"    expect_given_up={self.expect_given_up!r},")
        lines.append(")")
        return "\n".join(lines)


def _short_repr(value: Any) -> str:
    """A dataclass's repr without the fields left at their defaults."""
    shown = []
    for f in fields(value):
        current = getattr(value, f.name)
        if f.default is not current and f.default != current:
            shown.append(f"{f.name}={current!r}")
    return f"{type(value).__name__}({', '.join(shown)})"


# -- results ------------------------------------------------------------------------------------------


class InvariantViolation(AssertionError):
    """An invariant failed; the message ends with the scenario as Python."""

    code = "I?"


class I1RequestEnds(InvariantViolation):
    code = "I1"


class I2Preemption(InvariantViolation):
    code = "I2"


class I3LastRequestWins(InvariantViolation):
    code = "I3"


class I4OwnCallRefusal(InvariantViolation):
    code = "I4"


class I5Inference(InvariantViolation):
    code = "I5"


class I6RecoveryEnds(InvariantViolation):
    code = "I6"


class I7BehaviourTimeout(InvariantViolation):
    code = "I7"


class I8RulesCascade(InvariantViolation):
    code = "I8"


class I9RefusalChangesNothing(InvariantViolation):
    code = "I9"


class I10SuccessIsExact(InvariantViolation):
    code = "I10"


@dataclass
class Stats:
    """What ``make stress`` sums up over every scenario run."""

    scenarios: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)
    recoveries: int = 0
    rules_fired: int = 0
    give_ups: int = 0
    max_virtual_time: float = 0.0
    violations: Counter[str] = field(default_factory=Counter)

    def summary(self) -> str:
        order = ("succeeded", "preempted", "timed out", "refused", "cancelled", "failed other", "not done")
        outcomes = ", ".join(f"{name} {self.outcomes[name]}" for name in order)
        violated = ", ".join(f"{code} {n}" for code, n in sorted(self.violations.items())) or "none"
        return (f"scenarios: {self.scenarios}\nrequests: {sum(self.outcomes.values())} ({outcomes})\n"
                f"recoveries: {self.recoveries}, rules fired: {self.rules_fired}, give-ups: {self.give_ups}\n"
                f"max virtual time per scenario: {self.max_virtual_time:.1f} s\n"
                f"invariant violations: {violated}")


#: Summed over every scenario this process ran (printed by ``make stress``).
STATS = Stats()


# -- the runner ---------------------------------------------------------------------------------------


def run(scenario: Scenario) -> list[InvariantViolation]:
    """Play ``scenario`` and return every invariant it violates (empty when all hold)."""
    # Thousands of scenarios would log every failed request: the violations say what matters,
    # and a scenario replayed by hand logs as usual.
    logger = logging.getLogger("sm_bt")
    level = logger.level
    logger.setLevel(logging.CRITICAL)
    runner = _Runner(scenario)
    try:
        runner.play()
    finally:
        logger.setLevel(level)
        runner.account()
    return runner.violations


def check(scenario: Scenario) -> None:
    """Play ``scenario`` and raise the first violation (each invariant its own exception type)."""
    violations = run(scenario)
    if violations:
        first = violations[0]
        others = "".join(f"\n  also {v.code}: {v.args[0]}" for v in violations[1:6])
        raise type(first)(f"{first.code}: {first.args[0]}{others}\n\nscenario:\n{scenario.to_python()}")


@dataclass
class _Seen:
    """A request as the runner knows it."""

    request: Request
    timeout: float
    refused_at_once: bool = False  # done (and failed) when the call returned
    announced: bool = False  # the manager told its observers it started: it was accepted
    finished_actual: StateMode | None = None  # the part's actual when it finished
    registered_running: bool = True  # its done-callback was added before it ended (I10)


@dataclass
class _Budget:
    """I6: recovery restores of one part since the last user request."""

    count: int = 0
    on_since: float | None = None


class _AppearanceWatch:
    """A backend listener that tells ``seen`` of each appearance before passing every report on."""

    def __init__(self, listener: BackendListener, seen: Callable[[str], None]) -> None:
        self._listener, self._seen = listener, seen

    def node_appeared(self, node: str, report: NodeReport) -> None:
        self._seen(node)
        self._listener.node_appeared(node, report)

    def node_state(self, node: str, state: State) -> None:
        self._listener.node_state(node, state)

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        self._listener.node_parameters(node, changed)

    def node_vanished(self, node: str, reason: str) -> None:
        self._listener.node_vanished(node, reason)

    def batch(self) -> contextlib.AbstractContextManager[None]:
        return self._listener.batch()


def _watch_appearances(backend: SimBackend, seen: Callable[[str], None]) -> None:
    """Have ``seen(node)`` called on every appearance ``backend`` reports to whoever attaches."""
    attach = backend.attach
    backend.attach = lambda nodes, listener: attach(nodes, _AppearanceWatch(listener, seen))  # type: ignore[method-assign]


class _Runner:
    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.model = scenario.load()
        sim = scenario.sim
        self.backend = SimBackend(
            self.model, transition_delay=sim.transition_delay, error_delay=sim.error_delay,
            parameter_delay=sim.parameter_delay, vanish_after=sim.vanish_after,
            initial_state=dict(sim.initial_state), late=dict(sim.late), plain=sim.plain,
            report_delay=sim.report_delay)
        for node, delay in sim.slow:
            self.backend.set_delay(node, delay)
        self.clock = self.backend.clock
        options = scenario.manager
        self.options = options
        self.violations: list[InvariantViolation] = []
        self.seen: dict[int, _Seen] = {}
        self.user: list[Request] = []
        self.rules_fired = 0
        self.give_ups = 0
        self.budgets: dict[str, _Budget] = {name: _Budget() for name in self.model.parts}
        self.set_by: dict[str, Origin] = {}  # who made the last request for each part (I8)
        self.targets: dict[str, StateMode | None] = {name: None for name in self.model.parts}
        self.tree: _Tree | None = None
        # Restarts whose new process the manager has not heard of yet, by node: each appearance renews
        # the node's budget (I6), so two restarts at one instant renew it twice.
        self.renewing: dict[str, int] = {}
        _watch_appearances(self.backend, self._appeared)
        self.system = SimulatedSystem(self.model, backend=self.backend, record=False,
                                      request_timeout=options.request_timeout, grace_period=options.grace_period,
                                      recovery_attempts=options.recovery_attempts,
                                      recovery_window=options.recovery_window, rules=options.rules,
                                      recovery=options.recovery)
        self.manager = self.system.manager
        self.actuals = {name: self.manager.actual(name) for name in self.model.parts}
        self.manager.subscribe(self._on_event)

    # -- recording -------------------------------------------------------------------------------

    def _on_event(self, event: Event) -> None:
        if event.request is not None and event.request.refused:
            return  # told, but never accepted: nothing started, no target set (I9 checks it)
        if event.request is not None and event.request.id in self.seen:
            self.seen[event.request.id].announced = True
        elif event.request is not None:
            request = event.request
            self.seen[request.id] = _Seen(request, self.options.request_timeout, announced=True,
                                          registered_running=not request.done)
            request.add_done_callback(self._finished)
            self.set_by[request.part] = request.origin
            if request.origin is Origin.USER:
                for budget in self.budgets.values():
                    budget.count = 0
            elif request.origin is Origin.RECOVERY:
                self._restored(request.part, event.time)
        request = event.request
        if event.kind is EventKind.REQUEST and request is not None and request.succeeded \
                and not event.message.endswith("started") and request.parts == (request.part,) \
                and event.actual is not None and not event.actual.is_(request.target):
            # I10: the event announcing the success tells the part's actual at that moment.
            self._violate(I10SuccessIsExact, f"t={event.time:.3f}: request #{request.id} {request.description} "
                                             f"[{request.origin.value}] succeeded while {request.part} was "
                                             f"{event.actual}, not {request.target}")
        if event.kind is EventKind.RULE:
            self.rules_fired += 1
        elif event.kind is EventKind.FAILED:
            self.give_ups += 1
        elif event.kind is EventKind.TARGET:
            self.targets[event.part] = event.target
            self._track(event.part, event.time)
        elif event.kind is EventKind.ACTUAL and event.actual is not None:
            self.actuals[event.part] = event.actual
            self._track(event.part, event.time)

    def _finished(self, request: Request) -> None:
        seen = self.seen.get(request.id)
        if seen is not None and request.part in self.model.parts:
            seen.finished_actual = self.manager.actual(request.part).state_mode
        # I10 for a continuation's nodes, when the runner heard of it before it ended (its own part is
        # judged from the event that announces the success, see _on_event).
        if request.succeeded and seen is not None and seen.registered_running:
            for part in request.parts:
                wanted, actual = self.manager.target(part), self.manager.actual(part)
                if request.parts != (request.part,) and wanted is not None and not actual.is_(wanted):
                    self._violate(I10SuccessIsExact, f"t={self.clock.now():.3f}: request #{request.id} "
                                                     f"{request.description} [{request.origin.value}] succeeded "
                                                     f"while {part} was {actual}, not {wanted}")

    def _track(self, part: str, now: float) -> None:
        actual, target = self.actuals[part], self.targets[part]
        on = target is not None and actual.known and actual.state_mode == target
        budget = self.budgets[part]
        if on and budget.on_since is None:
            budget.on_since = now
        elif not on and budget.on_since is not None:
            if now - budget.on_since >= self.options.recovery_window - EPS:
                budget.count = 0
            budget.on_since = None

    def _restored(self, part: str, now: float) -> None:
        budget = self.budgets[part]
        if budget.on_since is not None and now - budget.on_since >= self.options.recovery_window - EPS:
            budget.count = 0
        budget.count += 1
        if budget.count > self.options.recovery_attempts:
            self._violate(I6RecoveryEnds, f"t={now:.3f}: recovery restored {part} {budget.count} times since the "
                                          f"last user request (recovery_attempts={self.options.recovery_attempts}, "
                                          "not on target for recovery_window in between)")

    def _restart(self, node: str, state: str | None = None, *, renew: bool = RESTART_RENEWS_BUDGET) -> None:
        """Restart ``node``; with ``renew``, its budget is whole again when the manager hears of the
        new process (its appearance report, maybe ``report_delay`` later)."""
        if renew:
            self.renewing[node] = self.renewing.get(node, 0) + 1
        self.backend.restart(node, state)

    def _appeared(self, node: str) -> None:
        """The manager is about to hear that ``node`` appeared: a restarted one's budget is whole
        again from this instant, before the manager can react (it may restore from the report)."""
        pending = self.renewing.get(node, 0)
        if pending:
            if pending == 1:
                del self.renewing[node]
            else:
                self.renewing[node] = pending - 1
            self.budgets[node].count = 0

    def _violate(self, kind: type[InvariantViolation], message: str) -> None:
        if not any(type(v) is kind and v.args[0] == message for v in self.violations):
            self.violations.append(kind(message))

    # -- time --------------------------------------------------------------------------------------

    def advance(self, until: float, stop: Callable[[], bool] | None = None) -> bool:
        """Run the clock event by event (and the tree every tick) up to ``until``, or until
        ``stop()`` holds after an event; True if it stopped early."""
        spins, last = 0, self.clock.now()
        while not (stop is not None and stop()):
            due = self.clock.next_due()
            tick = self.tree.next_tick if self.tree is not None and self.tree.running else None
            pending = [t for t in (due, tick) if t is not None and t <= until]
            if not pending:
                self.clock.run_until(until)
                return False
            when = min(pending)
            self.clock.run_until(when)
            if tick is not None and when >= tick - EPS:
                self._tick()
            spins = spins + 1 if self.clock.now() <= last else 0
            last = self.clock.now()
            if spins > 10_000:  # callbacks that keep scheduling themselves at the same instant
                self._violate(I6RecoveryEnds, f"t={last:.3f}: the clock does not advance (a livelock)")
                return False
        return True

    def _tick(self) -> None:
        assert self.tree is not None
        self.tree.tick(self.clock.now(), self._violate)
        for request_id, timeout in self.tree.timeouts.items():
            if request_id in self.seen:
                self.seen[request_id].timeout = timeout

    # -- playing -----------------------------------------------------------------------------------

    def play(self) -> None:
        scenario = self.scenario
        if scenario.tree:
            self.tree = _Tree(scenario.tree, self.manager)
            self._tick()
        for step in scenario.steps:
            if step.at > self.clock.now():
                self.advance(step.at)
            self.perform(step.action)
        if self.tree is not None:
            tree = self.tree
            self.advance(max(self.clock.now(), tree.horizon), stop=lambda: not tree.running)
            tree.stop()
        if scenario.expect_given_up is not None:
            self.check_given_up(scenario.expect_given_up)
        self.heal()
        delay = scenario.final_delay
        if delay is None:
            if self.settle("after healing"):
                self.check_cascade()
        elif delay > 0:
            self.advance(self.clock.now() + delay)
        self.finish()

    def perform(self, action: Action) -> None:
        backend = self.backend
        if isinstance(action, (ChangeMode, ChangeState, ChangeTo)):
            self.request(action)
        elif isinstance(action, Cancel):
            if self.user:
                self.user[action.request % len(self.user)].cancel()
        elif isinstance(action, Crash):
            if backend.status(action.node) is NodeStatus.RUNNING:
                backend.crash(action.node)
        elif isinstance(action, Restart):
            self._restart(action.node, None if backend.is_plain(action.node) else action.state)
        elif isinstance(action, RejectParameters):
            backend.reject_parameters(action.node, action.reason)
        elif backend.is_plain(action.node):
            return  # lifecycle faults have no meaning for a node without a lifecycle
        elif isinstance(action, FailNext):
            backend.fail_next(action.node, transition_by_label(action.transition, State.UNCONFIGURED),
                              Outcome(action.outcome), Outcome(action.on_error))
        elif isinstance(action, HangNext):
            backend.hang_next(action.node, transition_by_label(action.transition, State.UNCONFIGURED))
        elif backend.status(action.node) is not NodeStatus.RUNNING:
            return
        elif isinstance(action, SetParameter):
            with contextlib.suppress(ValueError):  # a value of the wrong type: refused, nothing happens
                backend.set_parameter(action.node, action.name, action.value)
        elif isinstance(action, Trigger):
            valid = backend.node(action.node).valid_transitions()
            if valid:
                backend.trigger(action.node, valid[action.choice % len(valid)], Outcome(action.outcome),
                                Outcome(action.on_error))

    def request(self, action: RequestAction, timeout: float | None = None,
                priority: int | None = None) -> Request | None:
        """Make the request (at ``priority``: default the user's); ``None`` when the manager raised
        (a name the model does not have: I1)."""
        manager = self.manager
        timeout = action.timeout if timeout is None else timeout
        targets = {part: manager.target(part) for part in self.model.parts}
        running = {r.id for r in manager.requests()}
        invalid = invalid_by_name(self.model, action)
        try:
            if isinstance(action, ChangeMode):
                request = manager.change_mode(action.part, action.mode, timeout=timeout, priority=priority)
            elif isinstance(action, ChangeState):
                request = manager.change_state(action.part, action.transition, timeout=timeout, priority=priority)
            else:
                request = manager.change_to(action.part, action.target, timeout=timeout, priority=priority)
        except RequestError as error:
            if not invalid:
                self._violate(I1RequestEnds, f"{action} raised although the model has every name it uses: {error}")
            return None
        if invalid:
            self._violate(I1RequestEnds, f"request #{request.id} {request.description} names a part, mode, "
                                         f"transition or target the model does not have, but did not raise "
                                         f"({request.reason or request.feedback})")
        seen = self.seen.get(request.id)
        if seen is None:
            seen = self.seen[request.id] = _Seen(request, 0.0)
            request.add_done_callback(self._finished)
        seen.timeout = self.options.request_timeout if timeout is None else timeout
        seen.refused_at_once = request.done and not request.succeeded
        if request.refused:  # I9: no target, no request in flight survives a refusal
            changed = sorted(part for part, target in targets.items() if manager.target(part) != target)
            started = {r.id for r in manager.requests()} - running
            if changed or started or not (request.done and not request.succeeded):
                self._violate(I9RefusalChangesNothing, f"request #{request.id} {request.description} was refused "
                                                       f"({request.reason}) but changed the targets of {changed} "
                                                       f"and started {sorted(started)}")
        self.user.append(request)
        return request

    def heal(self) -> None:
        """Stop the faults (disarm, clear rejections) and bring every node process back (crashed,
        vanished, hung, finalized or not started yet), at once: what is under way goes on. Then no
        node is out of reach, and I3 holds the final request to reaching its target: no state of
        the model and the nodes may lock a user out (a finalized node that comes back is a new life)."""
        backend = self.backend
        backend.clear_faults()
        for node in backend.nodes:
            if backend.status(node) is not NodeStatus.RUNNING or node in backend.hung() \
                    or backend.node(node).state is State.FINALIZED:
                self._restart(node, renew=True)

    def settle(self, when: str) -> bool:
        """Run until no request is in flight and none starts for a quiet period; a violation of I6
        if that takes longer than the manager's own bounds allow."""
        options, sim = self.options, self.scenario.sim
        quiet = options.grace_period + sim.vanish_after + 4 * sim.longest_delay + 1.0
        limit = self.clock.now() + (options.recovery_attempts + 2) * (options.request_timeout + quiet) + 30.0
        while self.clock.now() < limit:
            self.advance(limit, stop=lambda: not self.manager.requests())
            if self.manager.requests():
                break
            started = len(self.seen)
            self.advance(min(limit, self.clock.now() + quiet), stop=lambda: bool(self.manager.requests()))
            if not self.manager.requests() and len(self.seen) == started:
                return True
        busy = "; ".join(f"#{r.id} {r.description} [{r.origin.value}]: {r.feedback}" for r in self.manager.requests())
        self._violate(I6RecoveryEnds, f"{when}: the manager did not settle within {limit:.1f} s of virtual "
                                      f"time (in flight: {busy or 'nothing, but requests kept starting'})")
        return False

    def finish(self) -> None:
        final = self.scenario.final
        needed = needed_nodes(self.model, final.part, final_target(self.model, final))
        # A transition under way (or asked for: a shutdown in flight) cannot be cancelled: a node
        # in one may still end finalized, and then the target is out of reach.
        doomed = {node for node in needed if not self.backend.node(node).state.is_primary
                  or self.backend.node(node).state is State.FINALIZED or "shutdown" in self.backend.in_flight(node)}
        # A node restarted by the healing whose report is still on its way (report_delay) is gone
        # as far as the manager can know: a request made now may be refused for it.
        # Likewise a node the manager still sees finalized.
        # And a node whose first report is still on its way: the manager may yet hear of the process
        # the healing replaced (finalized, say) before it hears of the new one.
        unseen = {node for node in needed if self.manager.observation(node).gone
                  or not self.manager.observation(node).seen
                  or self.manager.observation(node).state is State.FINALIZED}
        # And a node the manager knows in another state than it is (its reports are late): the
        # manager may confirm the target from what it knows before the news comes.
        stale = {node for node in needed if self.backend.status(node) is NodeStatus.RUNNING
                 and self.manager.observation(node).state is not self.backend.node(node).state}
        # And a node the healing restarted whose new process the manager has not heard of yet: the
        # news of the old one's end may still be on its way too, and fail a request made now (the
        # manager cannot tell that its calls reached the new process).
        stale |= {node for node in needed if node in self.renewing}
        # At the rules' priority: a rule's hold lasts while its condition does, which a request of
        # its priority ends (holds.py); below it, a refusal naming the rule is the right answer.
        request = self.request(final, FINAL_TIMEOUT, priority=PRIORITIES["rule"])
        assert request is not None, f"the final request {final} is not a valid one"
        self.advance(self.clock.now() + FINAL_TIMEOUT + 1.0, stop=lambda: request.done)
        missing = [node for node, wanted in needed.items()
                   if (self.backend.is_plain(node) and wanted.state is not State.ACTIVE)
                   or (node in doomed and node not in stale and self.backend.node(node).state is State.FINALIZED)]
        self.check_final(request, not missing, missing, sorted((unseen | stale) - set(missing)))
        self.settle("after the final request")
        self.check_requests()
        self.check_observations()

    # -- invariants --------------------------------------------------------------------------------

    def check_final(self, request: Request, reachable: bool, missing: list[str], doubtful: list[str]) -> None:
        """I3. ``missing``: the needed nodes the target cannot have (every node runs after healing):
        finalized, or on the way there, when the request was made; plain ones asked for a state.
        ``doubtful``: nodes whose news was still on its way to the manager then (it may refuse or
        fail the request for them, naming them, or reach the target once it hears)."""
        actual = self.manager.actual(request.part) if request.part in self.model.parts else None
        where = f"final request #{request.id} {request.description}"
        if not request.done:
            self._violate(I3LastRequestWins, f"{where} is not done after {FINAL_TIMEOUT:g} s")
        elif reachable and doubtful and not request.succeeded:
            if not any(name in request.reason for name in (request.part, *doubtful)):
                self._violate(I3LastRequestWins, f"{where} failed with a reason that names neither the part nor "
                                                 f"{', '.join(doubtful)}: {request.reason!r}")
        elif reachable and not request.succeeded:
            self._violate(I3LastRequestWins, f"{where} failed although its target is reachable: {request.reason}")
        elif reachable and self.seen[request.id].finished_actual != request.target:
            self._violate(I3LastRequestWins, f"{where} succeeded but {request.part} was "
                                             f"{self.seen[request.id].finished_actual} then, not {request.target}")
        elif not reachable and request.succeeded:
            self._violate(I3LastRequestWins, f"{where} succeeded although {', '.join(missing)} cannot be had")
        elif not reachable and not any(name in request.reason for name in (request.part, *missing, *doubtful)):
            self._violate(I3LastRequestWins, f"{where} failed with a reason that names neither the part nor "
                                             f"{', '.join([*missing, *doubtful])}: {request.reason!r}")
        if request.succeeded and actual is not None:
            later = self.manager.actual(request.part)
            if later.state_mode != request.target and self.manager.target(request.part) != request.target:
                self._violate(I3LastRequestWins, f"{where} succeeded, but afterwards (nothing failed since "
                                                 f"healing) {request.part} was re-targeted to "
                                                 f"{self.manager.target(request.part)} (actual {later})")

    def check_given_up(self, node: str) -> None:
        """I6 for a node hung in a transition: recovery stopped, and says so."""
        if node not in self.backend.hung() or self.clock.now() < give_up_bound(self.options):
            return
        busy = [r for r in self.manager.requests() if r.part == node or node in r.description]
        divergence = self.manager.divergence(node)
        now = self.clock.now()
        if busy:
            self._violate(I6RecoveryEnds, f"t={now:.3f}: {node} hangs in a transition, yet requests are still "
                                          f"in flight on it: {busy}")
        elif divergence is None or not divergence.is_error:
            self._violate(I6RecoveryEnds, f"t={now:.3f}: recovery stopped on the hung {node}, but its divergence "
                                          f"is not reported as an error: {divergence}")

    def check_cascade(self) -> None:
        """I8, once the manager settled after healing (nothing in flight, nothing starting)."""
        if not self.options.rules:
            return
        manager = self.manager
        given_up = set(manager.failed())
        for system in self.model.systems:
            target = manager.target(system.name)
            actual = manager.actual(system.name)
            if target is None or system.name in given_up or (actual.known and actual.state_mode == target):
                continue
            for rule in system.rules:
                condition = manager.actual(rule.if_part)
                if rule.if_target == target and rule.new_target != target and condition.known \
                        and condition.state_mode == rule.if_part_state and self.set_by.get(rule.if_part) is Origin.RULE:
                    self._violate(I8RulesCascade, f"t={self.clock.now():.3f}: {system.name} stays {actual} with "
                                                  f"target {target}, although its rule {rule.name} applies: "
                                                  f"{rule.if_part} is {condition} (through a rule of its own)")

    def check_requests(self) -> None:
        now = self.clock.now()
        movers = any(isinstance(step.action, MOVERS) for step in self.scenario.steps)
        for seen in self.seen.values():
            request = seen.request
            name = f"request #{request.id} {request.description} [{request.origin.value}]"
            if not request.done:
                self._violate(I1RequestEnds, f"{name} is not done at t={now:.3f} (created t={request.created:.3f}, "
                                             f"timeout {seen.timeout:g} s): {request.feedback}")
                continue
            assert request.finished is not None
            if request.finished > request.created + seen.timeout + EPS:
                self._violate(I1RequestEnds, f"{name} finished at t={request.finished:.3f}, after its timeout "
                                             f"({seen.timeout:g} s from t={request.created:.3f})")
            if not request.succeeded and not request.reason:
                self._violate(I1RequestEnds, f"{name} failed without a reason")
            match = PREEMPTED.search(request.reason)
            if match:
                by = int(match.group(1))
                other = self.seen.get(by)
                if by <= request.id or other is None or not other.announced:
                    self._violate(I2Preemption, f"{name} failed {request.reason!r}, but #{by} is not a later, "
                                                "accepted request")
            if not movers and BUSY_REFUSAL.search(request.reason):
                self._violate(I4OwnCallRefusal, f"{name} failed: {request.reason}")

    def check_observations(self) -> None:
        manager, backend = self.manager, self.backend
        for node in backend.nodes:
            observation = manager.observation(node)
            if backend.status(node) is NodeStatus.RUNNING:
                sim = backend.node(node)
                truth = (True, sim.state, sim.parameters, not backend.is_plain(node))
                seen = (observation.reachable, observation.state, observation.parameters, observation.lifecycle)
                if seen != truth:
                    self._violate(I5Inference, f"{node}: the manager observed (reachable, state, parameters, "
                                               f"lifecycle) {seen}, the node is {truth}")
        # From scratch with the reference functions (infer_node/infer_system, no tallies).
        observations = {node: manager.observation(node) for node in backend.nodes}
        targets = {part: t for part in self.model.parts if (t := manager.target(part)) is not None}
        fresh = infer_all(self.model, observations, targets)
        for part in self.model.parts:
            if fresh[part] != manager.actual(part):
                self._violate(I5Inference, f"{part}: the manager infers {manager.actual(part)!r}, inference "
                                           f"from scratch {fresh[part]!r}")

    # -- statistics --------------------------------------------------------------------------------

    def account(self) -> None:
        STATS.scenarios += 1
        for seen in self.seen.values():
            STATS.outcomes[outcome(seen.request, seen.refused_at_once and not seen.announced)] += 1
        STATS.recoveries += sum(1 for s in self.seen.values() if s.request.origin is Origin.RECOVERY)
        STATS.rules_fired += self.rules_fired
        STATS.give_ups += self.give_ups
        STATS.max_virtual_time = max(STATS.max_virtual_time, self.clock.now())
        for violation in self.violations:
            STATS.violations[violation.code] += 1


def outcome(request: Request, refused_at_once: bool = False) -> str:
    if not request.done:
        return "not done"
    if request.succeeded:
        return "succeeded"
    if refused_at_once:
        return "refused"
    if PREEMPTED.search(request.reason):
        return "preempted"
    if "timed out" in request.reason:
        return "timed out"
    if request.reason == "cancelled":
        return "cancelled"
    return "failed other"


# -- the model, as the invariants need it ---------------------------------------------------------------


def give_up_bound(options: ManagerOptions) -> float:
    """Time enough for recovery to spend every attempt on a hung node (each one times out after
    its grace period) and for the recovery window to pass: by then it must have given up."""
    return (options.recovery_attempts + 2) * (options.request_timeout + options.grace_period + 1) \
        + options.recovery_window


def invalid_by_name(model: Model, action: RequestAction) -> bool:
    """True when the request names a part, mode, transition or target the model (or the lifecycle)
    does not have: the manager must raise RequestError, whatever the state."""
    spec = model.parts.get(action.part)
    if spec is None:
        return True
    if isinstance(action, ChangeMode):
        return action.mode not in spec.modes and action.mode != DEFAULT_MODE
    if isinstance(action, ChangeState):
        return action.transition not in REQUESTABLE_LABELS
    try:
        wanted = StateMode.parse(action.target)
    except ValueError:
        return True
    if wanted.state not in (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE):
        return True
    return wanted.mode is not None and wanted.mode not in spec.modes and wanted.mode != DEFAULT_MODE


def final_target(model: Model, final: ChangeMode | ChangeTo) -> StateMode:
    """The target a valid request stands for (``active`` and ``__DEFAULT__`` name the default mode)."""
    spec = model.parts[final.part]
    wanted = StateMode(State.ACTIVE, final.mode) if isinstance(final, ChangeMode) else StateMode.parse(final.target)
    if wanted.state is not State.ACTIVE or wanted.mode in spec.modes:
        return wanted
    return StateMode(State.ACTIVE, spec.default_mode)


def needed_nodes(model: Model, part: str, target: StateMode) -> dict[str, StateMode]:
    """Every node ``target`` of ``part`` asks something of (don't-care entries ask nothing)."""
    spec = model.parts[part]
    if isinstance(spec, NodePart):
        return {part: target}
    found: dict[str, StateMode] = {}
    if target.state is State.ACTIVE:
        for entry in spec.modes[target.mode or spec.default_mode].entries.values():
            if entry.target is not None:
                found.update(needed_nodes(model, entry.part, entry.target))
    else:
        for child in spec.parts:
            found.update(needed_nodes(model, child, StateMode(target.state)))
    return found


# -- the tree -----------------------------------------------------------------------------------------


class _Tree:
    """A small tree of sm_bt behaviours, ticked every :data:`TICK`; checks I7 after each tick."""

    def __init__(self, branches: tuple[tuple[TreeItem, ...], ...], manager: ModeManager) -> None:
        self.manager = manager
        self.bounds: dict[py_trees.behaviour.Behaviour, float] = {}
        self.started: dict[py_trees.behaviour.Behaviour, float] = {}
        self.overdue: set[py_trees.behaviour.Behaviour] = set()  # reported once each
        self.timeouts: dict[int, float] = {}  # request id -> the timeout a behaviour gave it
        children = []
        for index, branch in enumerate(branches):
            items = [py_trees.decorators.FailureIsSuccess(f"ok {index}.{i}", self._build(item, f"{index}.{i}"))
                     for i, item in enumerate(branch)]
            children.append(py_trees.composites.Sequence(f"branch {index}", memory=True, children=items))
        self.root = py_trees.composites.Parallel(
            "scenario", policy=py_trees.common.ParallelPolicy.SuccessOnAll(synchronise=False), children=children)
        self.tree = py_trees.trees.BehaviourTree(self.root)
        self.tree.setup(manager=manager)
        self.ticks = 0
        self.stopped = False
        # Every branch has run to its end by then, if each behaviour keeps to its bound.
        self.horizon = max(sum(i.timeout + (i.ticks + 2) * TICK for i in b) for b in branches) + 1.0

    def _build(self, item: TreeItem, label: str) -> py_trees.behaviour.Behaviour:
        name = f"{item.kind} {item.part} {item.arg} ({label})"
        behaviour: py_trees.behaviour.Behaviour
        if item.kind == "change_mode":
            behaviour = ChangeModeBehaviour(name, item.part, item.arg, timeout=item.timeout)
        elif item.kind == "change_state":
            behaviour = ChangeStateBehaviour(name, item.part, item.arg, timeout=item.timeout)
        elif item.kind == "wait_for_mode":
            behaviour = WaitForMode(name, item.part, item.arg, timeout=item.timeout)
        else:
            child = py_trees.behaviours.TickCounter(f"work ({label})", item.ticks, Status.SUCCESS)
            behaviour = hold_mode(name, item.part, item.arg, child, timeout=item.timeout)
            # The whole subtree: the change (its timeout), then the child's run.
            self.bounds[behaviour] = item.timeout + (item.ticks + 2) * TICK
            for inner in behaviour.iterate():
                if isinstance(inner, HoldMode):
                    self.bounds[inner] = self.bounds[behaviour]
            return behaviour
        self.bounds[behaviour] = item.timeout
        return behaviour

    @property
    def running(self) -> bool:
        return not self.stopped and self.root.status in (Status.INVALID, Status.RUNNING)

    @property
    def next_tick(self) -> float:
        return self.ticks * TICK

    def tick(self, now: float, violate: Callable[[type[InvariantViolation], str], None]) -> None:
        self.ticks = max(self.ticks, round(now / TICK)) + 1
        self.tree.tick()
        for behaviour, bound in self.bounds.items():
            if behaviour.status is Status.RUNNING:
                started = self.started.setdefault(behaviour, now)
                if now - started > bound + TICK + EPS and behaviour not in self.overdue:
                    self.overdue.add(behaviour)
                    violate(I7BehaviourTimeout, f"{behaviour.name} is RUNNING at t={now:.2f}, initialised at "
                                                f"t={started:.2f}, bound {bound:g} s: {behaviour.feedback_message}")
            else:
                self.started.pop(behaviour, None)
        for behaviour in self._request_behaviours():
            request = behaviour.request
            if request is not None and request.id not in self.timeouts:
                timeout = behaviour.timeout
                self.timeouts[request.id] = self.manager.request_timeout if timeout is None else timeout

    def _request_behaviours(self) -> Iterator[Any]:
        for behaviour in self.root.iterate():
            if isinstance(behaviour, (ChangeModeBehaviour, ChangeStateBehaviour, HoldMode)):
                yield behaviour

    def stop(self) -> None:
        """Interrupt what still runs (its requests are withdrawn) and tick no more."""
        self.stopped = True
        if self.root.status is Status.RUNNING:
            self.root.stop(Status.INVALID)



# -- strategies -----------------------------------------------------------------------------------------

#: Where the next step comes: the same instant, one tick, mid-transition, a while, long after.
_DELAYS = st.one_of(st.just(0.0), st.sampled_from([0.01, 0.02, 0.025, 0.05, 0.1]),
                    st.integers(1, 300).map(lambda i: i / 100), st.integers(5, 40).map(float))
_TIMEOUTS = st.one_of(st.none(), st.integers(5, 200).map(lambda i: i / 10))
_TENTHS = {(low, high): st.integers(low, high).map(lambda i: i / 10) for low, high in ((1, 100), (5, 50), (5, 100))}
_FOREIGN = st.integers(101, 200)
_FAULT_TRANSITIONS = ("configure", "activate", "deactivate", "cleanup")


def fixed_models() -> st.SearchStrategy[tuple[str, str | None]]:
    return st.sampled_from(sorted(FIXED_MODELS)).map(lambda name: (name, None))


def random_models() -> st.SearchStrategy[tuple[str, str | None]]:
    return generated_models().map(lambda generated: ("generated", generated.text))


@st.composite
def cascade_scenarios(draw: st.DrawFn) -> Scenario:
    """Issue 10, item 2 (checked by I8): a generated model with the cascade; the user puts the
    parent in the mode its cascade rule watches, then the node the sub-system's rule watches
    fails by itself (and maybe more nodes do)."""
    generated = draw(generated_models(cascade=True))
    model = generated.load()
    rules = {rule.name: rule for system in model.systems for rule in system.rules}
    parent, sub = rules["cascade_parent"], rules["cascade_sub"]
    nodes = [n.name for n in model.nodes]
    steps = [Scheduled(0.0, ChangeMode(parent.system, parent.if_target.mode or DEFAULT_MODE))]
    at = draw(_TENTHS[5, 50])
    for node in [sub.if_part, *subset(draw, nodes, max_size=2)]:
        steps.append(Scheduled(at, Trigger(node, draw(ints(0, 2)), pick(draw, ["success", "error", "failure"]))))
        at = round(at + draw(_DELAYS), 3)
    manager = ManagerOptions(grace_period=pick(draw, [0.0, 0.1, 0.5, 1.0]), request_timeout=float(draw(ints(2, 20))),
                             recovery_attempts=draw(ints(1, 3)), recovery=draw(st.booleans()))
    final = draw(_request(model, valid=True))
    assert isinstance(final, (ChangeMode, ChangeTo))
    return Scenario("generated", final, manager, SimOptions(), tuple(steps), model_text=generated.text)


@st.composite
def hung_scenarios(draw: st.DrawFn, models: st.SearchStrategy[tuple[str, str | None]]) -> Scenario:
    """Issue 10, item 3 (checked by I6): a node whose transition callback never returns, asked
    for by the user, recovery on; nothing else happens for long enough that any budget runs out."""
    name, text = draw(models)
    model = model_from_text(text) if text is not None else fixed_model(name)
    node = pick(draw, [n.name for n in model.nodes])
    transition = pick(draw, ["configure", "activate"])
    manager = ManagerOptions(grace_period=pick(draw, [0.0, 0.5, 2.0]), request_timeout=float(draw(ints(2, 30))),
                             recovery_attempts=draw(ints(1, 3)), recovery_window=pick(draw, [60.0, 5.0, 30.0]),
                             rules=False, recovery=True)
    steps = (Scheduled(0.0, HangNext(node, transition)), Scheduled(0.0, ChangeTo(node, "active")),
             Scheduled(round(give_up_bound(manager), 3), RejectParameters(node, None)))
    final = draw(_request(model, valid=True))
    assert isinstance(final, (ChangeMode, ChangeTo))
    return Scenario(name, final, manager, SimOptions(), steps, expect_given_up=node, model_text=text)


def _modes(model: Model, part: str) -> list[str]:
    return list(model.parts[part].modes) if part in model.parts else []


@st.composite
def _request(draw: st.DrawFn, model: Model, valid: bool = False) -> RequestAction:
    parts = list(model.parts)
    part = pick(draw, parts if valid else [*parts, "ghost"])
    modes = _modes(model, part)
    timeout = None if valid else draw(_TIMEOUTS)
    kind = pick(draw, ["mode", "to"] if valid else ["mode", "state", "to", "mode", "state"])
    if kind == "mode":
        return ChangeMode(part, pick(draw, [*modes, DEFAULT_MODE] if valid else [*modes, DEFAULT_MODE, "TYPO"]),
                          timeout)
    if kind == "state":
        labels = ["configure", "activate", "deactivate", "cleanup"] * 3 + ["shutdown", "bogus"]
        return ChangeState(part, pick(draw, labels), timeout)
    targets = ["active", *(f"active.{m}" for m in modes), "inactive", "unconfigured"]
    return ChangeTo(part, pick(draw, targets if valid else [*targets, "finalized", "active.TYPO"]), timeout)


@st.composite
def _fault(draw: st.DrawFn, model: Model, movers: bool) -> Action:
    nodes = [n.name for n in model.nodes]
    node = pick(draw, nodes)
    kinds = ["fail", "hang", "reject", "unreject"]
    if movers:
        kinds += ["set", "trigger", "trigger", "crash", "restart"]
    kind = pick(draw, kinds)
    if kind == "fail":
        return FailNext(node, pick(draw, _FAULT_TRANSITIONS), pick(draw, ["failure", "error"]),
                        pick(draw, ["success", "success", "failure"]))
    if kind == "hang":
        return HangNext(node, pick(draw, _FAULT_TRANSITIONS))
    if kind in ("reject", "unreject"):
        return RejectParameters(node, "rejected by the test" if kind == "reject" else None)
    if kind == "set":
        part = model.parts[node]
        assert isinstance(part, NodePart)
        mode = part.modes[pick(draw, list(part.modes))]
        name = pick(draw, list(mode.parameters))
        # A value of one of the node's modes (it may move the node to that mode), or a foreign one.
        value = mode.parameters[name].value if draw(st.booleans()) else draw(_FOREIGN)
        return SetParameter(node, name, value)
    if kind == "trigger":
        return Trigger(node, draw(ints(0, 2)), pick(draw, ["success", "failure", "error"]),
                       pick(draw, ["success", "success", "failure"]))
    if kind == "crash":
        return Crash(node)
    return Restart(node, pick(draw, ["unconfigured", "inactive", "active"]))


@st.composite
def _tree(draw: st.DrawFn, model: Model) -> tuple[tuple[TreeItem, ...], ...]:
    parts = list(model.parts)
    branches = []
    for _ in range(draw(ints(1, 3))):
        items = []
        for _ in range(draw(ints(1, 3))):
            kind = pick(draw, ["change_mode", "change_state", "wait_for_mode", "hold_mode"])
            part = pick(draw, parts)
            if kind == "change_state":
                arg = pick(draw, ["configure", "activate", "deactivate", "cleanup"])
            else:
                arg = pick(draw, [*_modes(model, part), DEFAULT_MODE])
            timeout = draw(_TENTHS[5, 100])
            items.append(TreeItem(kind, part, arg, timeout, draw(ints(0, 20)) if kind == "hold_mode" else 0))
        branches.append(tuple(items))
    return tuple(branches)


@st.composite
def scenarios(draw: st.DrawFn, models: st.SearchStrategy[tuple[str, str | None]], *, movers: bool = True,
              tree: bool = False, max_steps: int = 12) -> Scenario:
    """Random scenarios over the models ``models`` draws. ``movers=False`` leaves out every step that
    moves a node without the manager (I4 then applies); ``tree`` adds a tree of behaviours."""
    name, text = draw(models)
    model = model_from_text(text) if text is not None else fixed_model(name)
    nodes = [n.name for n in model.nodes]
    manager = ManagerOptions(
        grace_period=pick(draw, [0.0, 0.1, 0.5, 1.0]),
        request_timeout=float(draw(ints(2, 20))),
        recovery_attempts=draw(ints(1, 3)),
        recovery_window=pick(draw, [60.0, 5.0, 10.0, 30.0]),
        rules=draw(st.booleans()), recovery=draw(st.booleans()))
    plain = tuple(subset(draw, nodes, max_size=min(2, len(nodes)))) if draw(ints(0, 3)) == 0 else ()
    states = ["unconfigured", "inactive", "active"] * 2 + ["finalized"]
    lifecycle_nodes = [n for n in nodes if n not in plain]
    initial = [(node, pick(draw, states)) for node in subset(draw, lifecycle_nodes)]
    late = [(node, draw(_TENTHS[1, 100])) for node in subset(draw, nodes, max_size=min(2, len(nodes)))]
    slow = [(node, draw(_TENTHS[5, 50])) for node in subset(draw, nodes, max_size=min(2, len(nodes)))]
    delays = [0.0, 0.01, 0.05, 0.05, 0.2, 1.0]
    sim = SimOptions(
        transition_delay=pick(draw, delays), error_delay=pick(draw, delays),
        parameter_delay=pick(draw, [0.0, 0.01, 0.01, 0.05]),
        vanish_after=pick(draw, [1.0, 0.5, 3.0]),
        initial_state=tuple(initial), late=tuple(late), plain=plain, slow=tuple(slow),
        report_delay=pick(draw, [0.0, 0.0, 0.005, 0.03]))
    steps = []
    at = 0.0
    for _ in range(draw(ints(0, max_steps))):
        at = round(at + draw(_DELAYS), 3)
        kind = pick(draw, ["request", "request", "request", "fault", "fault", "cancel"])
        if kind == "request":
            action: Action = draw(_request(model))
        elif kind == "fault":
            action = draw(_fault(model, movers))
        else:
            action = Cancel(draw(ints(0, 5)))
        steps.append(Scheduled(at, action))
    final = draw(_request(model, valid=True))
    assert isinstance(final, (ChangeMode, ChangeTo))
    final_delay = pick(draw, [None, 0.0, 0.01, 0.025, 0.1, 1.0])
    return Scenario(name, final, manager, sim, tuple(steps), draw(_tree(model)) if tree else (), final_delay,
                    model_text=text)
