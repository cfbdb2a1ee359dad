"""Helpers for behaviour tests (trees are built and ticked with :class:`sm_bt.sim.SimulatedSystem`):
behaviours that stand in for a mission's own work, and what the demo's story must tell."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.sim import SimEventKind, SimulatedSystem


def fresh_blackboard() -> Iterator[None]:
    """For an autouse fixture: every test starts and ends with an empty global blackboard."""
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


def backend_requests(system: SimulatedSystem, node: str | None = None) -> list[str]:
    """The calls (change_state / set_parameters) that reached the simulated nodes so far."""
    return [f"{e.node}: {e.details}" for e in system.backend.events
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
