"""Rollback over ROS 2: twenty rclpy lifecycle nodes in a child process, one made to fail its
activation (the change's third transition); the manager (``on_failure="rollback"``) puts every
node back, and the nodes themselves say so (their lifecycle services and parameters)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from lifecycle_msgs.srv import GetState
from model_generator import flat_system_text
from rcl_interfaces.srv import GetParameters, SetParametersAtomically
from ros_processes import RosContext, Starter, wait_until

from sm_bt.model.loader import load_model
from sm_bt.ros.parameters import from_parameter_value, to_parameters
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

NAMES = [f"n{i:02d}" for i in range(20)]


def write_model(path: Path) -> Path:
    path.write_text(flat_system_text(len(NAMES)))
    return path


def on_the_nodes(ros: RosContext) -> dict[str, tuple[str, float, str]]:
    """Each node's state and values, as its own services answer."""
    found = {}
    for name in NAMES:
        state = ros.call(GetState, f"/{name}/get_state", GetState.Request()).current_state.label
        values = ros.call(GetParameters, f"/{name}/get_parameters", GetParameters.Request(names=["speed", "label"]))
        speed, label = (from_parameter_value(value) for value in values.values)
        found[name] = (str(state), float(speed), str(label))  # type: ignore[arg-type]
    return found


@pytest.mark.long
def test_a_failed_twenty_node_change_is_rolled_back_on_the_nodes_themselves(
        node_processes: Starter, ros_context: RosContext, tmp_path: Path) -> None:
    path = write_model(tmp_path / "twenty.yaml")
    node_processes(str(path), "--state", "inactive")
    runtime = RosRuntime(load_model(path), serve=False, manager_options={"rules": False, "recovery": False,
                                                                         "on_failure": "rollback"})
    try:
        runtime.wait_for_nodes(20.0)
        manager = runtime.manager
        before = on_the_nodes(ros_context)
        assert set(before.values()) == {("inactive", 1.0, "slow")}
        # n02's activate fails: the third transition of the change (n00, n01, n02 activate together).
        response = ros_context.call(SetParametersAtomically, "/n02/set_parameters_atomically",
                                    SetParametersAtomically.Request(parameters=to_parameters(
                                        {"sim.fail_next": "activate"})))
        assert response.result.successful
        began = time.monotonic()
        failed = manager.change_mode("robot", "FAST")
        wait_until(lambda: failed.done, 30.0, "the failed change never ended")
        rolled_took = time.monotonic() - began
        assert failed.reason.startswith("rolled back: n02: activate failed"), failed.reason
        assert on_the_nodes(ros_context) == before  # every state and both values, as the nodes answer
        # The same change, working this time: the yardstick of the rollback's time.
        began = time.monotonic()
        request = manager.change_mode("robot", "FAST")
        wait_until(lambda: request.done, 20.0, "the change never ended")
        change_took = time.monotonic() - began
        assert request.succeeded, request.reason
        assert set(on_the_nodes(ros_context).values()) == {("active", 2.0, "fast")}
        print(f"\nthe change took {change_took:.3f} s; failing and rolling back took {rolled_took:.3f} s")
    finally:
        runtime.close()
