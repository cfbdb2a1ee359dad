"""pytest fixtures for testing your own model and mission trees on simulated nodes.

Installing sm_bt registers this module as a pytest plugin (entry point ``pytest11``), so the
fixtures are there in every test without an import::

    def test_the_robot_goes_fast(simulated_system):
        robot = simulated_system("models/robot.yaml")
        assert robot.finish(robot.manager.change_mode("robot", "FAST")).succeeded

``pytest -p no:sm_bt`` leaves it out.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from typing import Any

import py_trees
import pytest

from sm_bt.model.types import Model
from sm_bt.sim.system import SimulatedSystem

#: What the ``simulated_system`` fixture is: ``make(model, **options)`` as :class:`SimulatedSystem` takes them.
MakeSystem = Callable[..., SimulatedSystem]


@pytest.fixture
def simulated_system() -> Iterator[MakeSystem]:
    """``make(model, **options) -> SimulatedSystem`` (a model, its file or a bundled model's name;
    options as :class:`~sm_bt.sim.system.SimulatedSystem` takes them). Every system made is closed
    after the test, and py_trees' global blackboard is empty before and after it (behaviours keep
    what they share there)."""
    made: list[SimulatedSystem] = []

    def make(model: Model | str | os.PathLike[str], **options: Any) -> SimulatedSystem:
        system = SimulatedSystem(model, **options)
        made.append(system)
        return system

    py_trees.blackboard.Blackboard.clear()
    try:
        yield make
    finally:
        for system in made:
            system.close()
        py_trees.blackboard.Blackboard.clear()


__all__ = ["MakeSystem", "simulated_system"]
