"""The shared behaviour scenarios on simulated nodes (``test_behaviour_scenarios_ros.py`` runs the
same ones on real rclpy nodes)."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from behaviour_scenarios import SCENARIOS
from harness import Harness, sim_harness
from model_files import bundled
from tree_helpers import fresh_blackboard


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.__name__)
def test_scenario(scenario: Callable[[Harness], None]) -> None:
    harness = sim_harness(bundled("pilot"))
    try:
        scenario(harness)
    finally:
        harness.close()
