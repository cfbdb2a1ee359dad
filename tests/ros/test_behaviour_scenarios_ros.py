"""The shared behaviour scenarios (``behaviour_scenarios.py``), unchanged, on real ROS 2: the pilot's
nodes as rclpy lifecycle nodes in their own process, the manager embedded in the test process."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from behaviour_scenarios import SCENARIOS
from harness import Harness
from model_files import bundled
from ros_harness import RosHarness
from ros_processes import Starter
from tree_helpers import fresh_blackboard

pytestmark = pytest.mark.ros


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.mark.parametrize("scenario", SCENARIOS, ids=lambda s: s.__name__)
def test_scenario(scenario: Callable[[Harness], None], node_processes: Starter) -> None:
    process = node_processes("pilot")
    harness = RosHarness(bundled("pilot"), process)
    try:
        scenario(harness)
    finally:
        harness.close()
