"""Every ordered pair of requests, at four offsets: the last request wins (issue 10, item 1).

On the pilot and the Nav2-like model, from all nodes unconfigured and from a settled active mode,
each pair (r1, r2) of requests drawn from: change_mode of every system to each of its modes,
change_state of every system (configure, activate, deactivate, cleanup), and a few node-level
change_modes; r2 comes at the same instant as r1, one tick (0.01 s) later, in the middle of r1's
first transition, or once r1 has settled. Expected, for every pair:

* r2 is refused at once (a transition invalid for the state its part is in or heading to: done
  immediately, with a reason), or ends SUCCESS with its part's actual equal to its target;
* r1 ends SUCCESS (it finished first, or the scopes do not overlap), or FAILURE "preempted by
  request #<r2>" (or it was refused at once, being invalid from the initial state);
* no request fails with "cannot X while Y" (a refusal caused by the manager's own call).

One test per model, initial state and offset; each reports every failing pair.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import pytest
from model_generator import fixed_model
from scenario import BUSY_REFUSAL, ChangeMode, ChangeState, RequestAction, needed_nodes

from sm_bt.engine.lifecycle import PlanError, edge_for, transition_by_label
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, ParamValue
from sm_bt.sim import NotReached, SimEventKind, SimulatedSystem

TRANSITIONS = ("configure", "activate", "deactivate", "cleanup")
#: Node-level requests mixed in with the systems' (a mode other than the default where there is one).
NODE_REQUESTS = {
    "pilot": (ChangeMode("amcl", "DEGRADED"), ChangeMode("controller_server", "FAST"),
              ChangeMode("laser_resender", "__DEFAULT__")),
    "nav2_like": (ChangeMode("amcl", "DEGRADED"), ChangeMode("controller_server", "SLOW"),
                  ChangeMode("bt_navigator", "SIMPLE")),
}
#: The settled active mode of the second starting point.
ACTIVE_MODE = {"pilot": ("pilot", "f_normal_mode"), "nav2_like": ("navigation", "f_normal_mode")}
OFFSETS = ("same instant", "one tick", "mid-transition", "after settling")
TRANSITION_DELAY = 0.05
#: Virtual time allowed for one pair to finish: far beyond what any of these plans needs.
LIMIT = 120.0


@cache
def pair_requests(name: str) -> tuple[RequestAction, ...]:
    model = fixed_model(name)
    requests: list[RequestAction] = []
    for system in model.systems:
        requests += [ChangeMode(system.name, mode) for mode in system.modes]
        requests += [ChangeState(system.name, transition) for transition in TRANSITIONS]
    return (*requests, *NODE_REQUESTS[name])


def make(manager: ModeManager, action: RequestAction) -> Request:
    if isinstance(action, ChangeMode):
        return manager.change_mode(action.part, action.mode)
    assert isinstance(action, ChangeState)
    return manager.change_state(action.part, action.transition)


def run_until(system: SimulatedSystem, stop: Callable[[], bool], limit: float = LIMIT) -> bool:
    """Advance event by event until ``stop()`` holds (True) or ``limit`` seconds passed (False)."""
    try:
        system.run_until(stop, limit, step=None)
    except NotReached:
        return False
    return True


def invalid_from(model: Model, action: RequestAction, state: State | None) -> bool:
    """True when ``action`` is a transition that cannot be asked of a part in ``state``."""
    if not isinstance(action, ChangeState):
        return False
    if state is None or not state.is_primary:
        return True
    transition = transition_by_label(action.transition, state)
    goal = {"configure": State.INACTIVE, "activate": State.ACTIVE, "deactivate": State.INACTIVE,
            "cleanup": State.UNCONFIGURED}[action.transition]
    if state is goal:
        return False
    try:
        edge_for(state, transition)
    except PlanError:
        return True
    return False


@dataclass
class PairResult:
    r1: RequestAction
    r2: RequestAction
    problems: list[str]

    def __str__(self) -> str:
        return f"{_show(self.r1)} then {_show(self.r2)}: {'; '.join(self.problems)}"


def _show(action: RequestAction) -> str:
    arg = action.mode if isinstance(action, ChangeMode) else action.transition  # type: ignore[union-attr]
    kind = "change_mode" if isinstance(action, ChangeMode) else "change_state"
    return f"{kind}({action.part}, {arg})"


def start(name: str, settled: bool) -> SimulatedSystem:
    """A manager over nodes all unconfigured, or settled in the active mode (the nodes start in
    it, and the manager is asked for it: the request succeeds at once and sets the targets)."""
    model = fixed_model(name)
    states: dict[str, str] = {}
    parameters: dict[str, dict[str, ParamValue]] = {}
    if settled:
        part, mode = ACTIVE_MODE[name]
        for node, target in needed_nodes(model, part, StateMode(State.ACTIVE, mode)).items():
            states[node] = target.state.label
            spec = model.parts[node]
            if target.mode is not None and isinstance(spec, NodePart):
                parameters[node] = spec.modes[target.mode].values()
    system = SimulatedSystem(model, transition_delay=TRANSITION_DELAY, initial_state=states,
                             initial_parameters=parameters, record=False)
    manager = system.manager
    if settled:
        request = manager.change_mode(*ACTIVE_MODE[name])
        assert request.done and request.succeeded and not manager.requests(), request
    return system


def run_pair(name: str, settled: bool, offset: str, r1: RequestAction, r2: RequestAction) -> PairResult:
    model = fixed_model(name)
    system = start(name, settled)
    backend, manager = system.backend, system.manager
    before = manager.actual(r1.part).state
    first = make(manager, r1)
    if offset == "one tick":
        backend.clock.advance(0.01)
    elif offset == "mid-transition":
        # Half way through the first transition r1 starts (or a tick later when it starts none).
        seen = len(backend.events)
        run_until(system, lambda: any(e.kind is SimEventKind.TRANSITION for e in backend.events[seen:]), 1.0)
        backend.clock.advance(TRANSITION_DELAY / 2)
    elif offset == "after settling":
        run_until(system, lambda: first.done and not manager.requests())
    actual, target = manager.actual(r2.part).state, manager.target(r2.part)
    second = make(manager, r2)
    refused = second.done and not second.succeeded
    reached: list[str] = []
    second.add_done_callback(lambda r: reached.append(str(manager.actual(r.part))))
    finished = run_until(system, lambda: first.done and second.done and not manager.requests())

    problems = []
    if not finished:
        problems.append(f"not done after {LIMIT:g} s: {manager.requests()}")
    if refused:
        if not (invalid_from(model, r2, actual) or invalid_from(model, r2, target.state if target else None)):
            problems.append(f"r2 refused although valid from {actual} (heading to {target}): {second.reason}")
        if not second.reason:
            problems.append("r2 refused without a reason")
    elif not second.succeeded:
        problems.append(f"r2 failed: {second.reason}")
    elif reached and reached[0] != str(second.target):
        problems.append(f"r2 succeeded with {r2.part} {reached[0]}, not {second.target}")
    first_refused = first.done and first.created == first.finished and not first.succeeded \
        and invalid_from(model, r1, before)
    if not (first.succeeded or first_refused
            or re.fullmatch(rf"preempted by request #{second.id}\b.*", first.reason or "")):
        problems.append(f"r1 ended {'SUCCESS' if first.succeeded else 'FAILURE: ' + first.reason}")
    if refused and not (first.succeeded or first_refused):
        problems.append("r2 was refused, yet r1 did not succeed")
    for request in (first, second):
        if BUSY_REFUSAL.search(request.reason):
            problems.append(f"#{request.id} {request.description}: {request.reason}")
    return PairResult(r1, r2, problems)


def failing_pairs(name: str, settled: bool, offset: str) -> list[PairResult]:
    requests = pair_requests(name)
    results = (run_pair(name, settled, offset, r1, r2) for r1 in requests for r2 in requests)
    return [result for result in results if result.problems]


@pytest.mark.parametrize("offset", OFFSETS)
@pytest.mark.parametrize("settled", [False, True], ids=["from unconfigured", "from active"])
@pytest.mark.parametrize("name", ["pilot", "nav2_like"])
def test_the_last_of_two_requests_wins(name: str, settled: bool, offset: str) -> None:
    failures = failing_pairs(name, settled, offset)
    total = len(pair_requests(name)) ** 2
    shown = "\n".join(str(failure) for failure in failures[:25])
    assert not failures, f"{len(failures)} of {total} pairs fail:\n{shown}"
