"""Helpers for behaviour tests: real py_trees trees, ticked against a simulated backend, with the
virtual clock advanced between ticks (so timeouts and grace periods cost no wall time)."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import py_trees
from engine_helpers import Rig
from py_trees.common import Status

from sm_bt.engine.requests import Request
from sm_bt.sim.backend import EventKind as SimEventKind


def fresh_blackboard() -> Iterator[None]:
    """For an autouse fixture: every test starts and ends with an empty global blackboard."""
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


def build(root: py_trees.behaviour.Behaviour, rig: Rig) -> py_trees.trees.BehaviourTree:
    """A tree around ``root``, set up with the rig's manager."""
    tree = py_trees.trees.BehaviourTree(root)
    tree.setup(manager=rig.manager)
    return tree


@dataclass(frozen=True)
class Tick:
    """What one behaviour showed after one tick."""

    time: float
    status: Status
    feedback: str


def tick_until(tree: py_trees.trees.BehaviourTree, rig: Rig, condition: Callable[[], bool], *,
               watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05,
               limit: float = 10.0) -> list[Tick]:
    """Tick, and advance the clock by ``step`` after every tick, until ``condition()`` holds right
    after a tick. Returns what ``watch`` (default: the root) showed at every tick; fails once
    ``limit`` seconds of virtual time passed without the condition."""
    watched = watch if watch is not None else tree.root
    start = rig.clock.now()
    trace: list[Tick] = []
    while True:
        tree.tick()
        trace.append(Tick(rig.clock.now(), watched.status, watched.feedback_message))
        if condition():
            return trace
        if rig.clock.now() - start >= limit:
            raise AssertionError(f"condition not met within {limit} s of virtual time; last tick of "
                                 f"{watched.name}: {trace[-1]}")
        rig.clock.advance(step)


def tick_until_done(tree: py_trees.trees.BehaviourTree, rig: Rig, *,
                    watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05,
                    limit: float = 10.0) -> list[Tick]:
    """Tick until ``watch`` (default: the root) is no longer RUNNING."""
    watched = watch if watch is not None else tree.root
    return tick_until(tree, rig, lambda: watched.status is not Status.RUNNING, watch=watched, step=step,
                      limit=limit)


def tick_for(tree: py_trees.trees.BehaviourTree, rig: Rig, seconds: float, *,
             watch: py_trees.behaviour.Behaviour | None = None, step: float = 0.05) -> list[Tick]:
    """Tick every ``step`` for ``seconds`` of virtual time (both ends included)."""
    end = rig.clock.now() + seconds - 1e-9
    return tick_until(tree, rig, lambda: rig.clock.now() >= end, watch=watch, step=step, limit=seconds + 1.0)


def settle(rig: Rig, request: Request, limit: float = 10.0) -> Request:
    """Let a request made directly on the manager finish; it must succeed."""
    rig.finish(request, limit)
    assert request.succeeded, request.reason
    return request


def backend_requests(rig: Rig, node: str | None = None) -> list[str]:
    """The calls (change_state / set_parameters) that reached the simulated nodes so far."""
    return [f"{e.node}: {e.details}" for e in rig.backend.events
            if e.kind is SimEventKind.REQUEST and (node is None or e.node == node)]


class Flag(py_trees.behaviour.Behaviour):
    """A condition the test flips: SUCCESS while ``on``, FAILURE otherwise."""

    def __init__(self, name: str, on: bool = False) -> None:
        super().__init__(name)
        self.on = on

    def update(self) -> Status:
        return Status.SUCCESS if self.on else Status.FAILURE


class Probe(py_trees.behaviour.Behaviour):
    """Work under test: returns ``results`` one per tick (the last one repeats) and records, for
    every tick, what ``look()`` returned (for instance the manager's view of a part)."""

    def __init__(self, name: str, results: Sequence[Status], look: Callable[[], Any] = lambda: None) -> None:
        super().__init__(name)
        self.results = list(results)
        self.look = look
        self.seen: list[Any] = []
        self.terminated: list[Status] = []

    def update(self) -> Status:
        self.seen.append(self.look())
        return self.results[min(len(self.seen), len(self.results)) - 1]

    def terminate(self, new_status: Status) -> None:
        self.terminated.append(new_status)


def assert_in_order(text: str, lines: Sequence[str]) -> None:
    """Each of ``lines`` occurs in ``text``, in this order (a narrative's story)."""
    position = 0
    for line in lines:
        found = text.find(line, position)
        assert found >= 0, f"{line!r} missing after position {position}:\n{text}"
        position = found + len(line)


#: What the pilot demo tells, in order, on either backend: start-up, then each contingency with
#: its confirmations.
PILOT_DEMO_STORY = (
    "change_state pilot configure succeeded",
    "== pilot is now active.f_normal_mode ==",
    "laser failure: the scans are all zero",
    "restore laser_resender to active.__DEFAULT__ started [recovery]",
    "gave up restoring laser_resender",
    "change_mode pilot f_degraded_mode succeeded",
    "== pilot is now active.f_degraded_mode ==",
    "laser repaired",
    "== pilot is now active.f_normal_mode ==",
    "battery low",
    "== pilot is now active.f_energy_saving_mode ==",
    "recharged: battery 1.00",
    "mission SUCCESS",
    "pilot ends in active.f_normal_mode; as expected",
)
