"""A fleet over real ROS 2 for the tests: robots, each the pilot's four simulated nodes with its own
``sm-bt manager`` in a namespace of its own (``/robot1``, ``/robot2``), and a fleet's manager embedded
in the test's process over them (the ``fleet`` fixture: import ``fleet_fixture`` in a test module)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from ros_processes import ManagerProcess, Starter, wait_until

from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.ros.runtime import RosRuntime

#: Two robots (/robot1/pilot, /robot2/pilot) under a fleet of __DEFAULT__ and NIGHT: the model
#: of docs/model-format.md, "Remote parts".
FLEET = Path(__file__).resolve().parents[2] / "models" / "fleet.yaml"


@pytest.fixture(name="fleet")
def fleet_fixture() -> Iterator[RosRuntime]:
    runtime = RosRuntime(load_model(FLEET), node_name="fleet_manager", manager_options={"request_timeout": 20.0})
    yield runtime
    runtime.close()


def robots(start_manager: Callable[..., ManagerProcess], node_processes: Starter, fleet: RosRuntime,
           robot1: tuple[str, ...] = ()) -> dict[str, ManagerProcess]:
    """robot1 and robot2, each the pilot's nodes (inactive; ``robot1``: more options of its nodes) and
    its own manager, read by the fleet."""
    managers = {name: start_manager("--namespace", f"/{name}") for name in ("robot1", "robot2")}
    for name in managers:
        node_processes("pilot", "--namespace", f"/{name}", "--state", "inactive", *(robot1 if name == "robot1" else ()))
    for manager in managers.values():
        manager.ready()
    wait_until(lambda: all(fleet.manager.actual(r).state is State.INACTIVE for r in managers), 20.0,
               "the fleet never read its robots")
    return managers
