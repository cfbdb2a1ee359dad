"""A robot in a namespace (``--namespace /robot1``), as robots of a fleet share a ROS domain: its
nodes are found under it, its parts served under it, and nothing of it is at the root, where
another robot's manager may serve the same model."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest
from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.srv import GetState
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import ManagerProcess, RosContext, Starter, wait_until
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
CALL_TIMEOUT = 5.0


def _mode(ros: RosContext, name: str) -> str:
    try:
        return str(ros.call(GetMode, name, GetMode.Request(), CALL_TIMEOUT).current_mode)
    except TimeoutError:
        return ""


def _state(ros: RosContext, name: str) -> int:
    try:
        return int(ros.call(GetState, name, GetState.Request(), CALL_TIMEOUT).current_state.id)
    except TimeoutError:
        return -1


def test_two_robots_in_their_namespaces_are_served_apart(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext,
        capsys: pytest.CaptureFixture[str]) -> None:
    robot1 = start_manager("--namespace", "/robot1")
    robot2 = start_manager("--namespace", "/robot2")
    node_processes("pilot", "--namespace", "/robot1", "--state", "inactive")
    node_processes("pilot", "--namespace", "/robot2", "--state", "inactive")
    robot1.ready()
    robot2.ready()
    # Its stderr is read by a thread of its own: the start-up lines may follow "serving" by a moment.
    wait_until(lambda: "  - /robot1/pilot/change_mode" in robot1.stderr, 5.0, "no start-up line")
    assert "  - /pilot/change_mode" not in robot1.stderr
    ros = ros_context
    events: list[Any] = []
    ros.node.create_subscription(ModeEvent, "/robot1/pilot/mode_event", events.append, LATCHED)
    for robot in ("robot1", "robot2"):
        wait_until(lambda: _state(ros, f"/{robot}/pilot/get_state") == StateMsg.PRIMARY_STATE_INACTIVE,  # noqa: B023
                   20.0, f"{robot}'s pilot never found")
    answer = ros.call(ChangeMode, "/robot1/pilot/change_mode", ChangeMode.Request(mode_name="f_degraded_mode"),
                      CALL_TIMEOUT)
    assert answer.success
    wait_until(lambda: bool(events) and events[-1].goal_mode.label == "f_degraded_mode", 10.0, "no mode_event")
    # Robot1's own nodes moved; robot2's, the same names in another namespace, did not.
    assert _state(ros, "/robot1/amcl/get_state") == StateMsg.PRIMARY_STATE_ACTIVE
    assert _mode(ros, "/robot1/pilot/get_mode") == "f_degraded_mode"
    assert _state(ros, "/robot2/pilot/get_state") == StateMsg.PRIMARY_STATE_INACTIVE
    assert _state(ros, "/robot2/amcl/get_state") == StateMsg.PRIMARY_STATE_INACTIVE
    # The CLI reaches a namespaced part by its full name, as ROS 2's own tools do.
    from sm_bt.cli import main

    assert main(["mode", "set", "/robot1/pilot", "f_normal_mode", "--wait"]) == 0
    assert main(["mode", "get", "/robot1/pilot"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "robot1/pilot: f_normal_mode"
    # Nothing at the root: a third robot's manager could serve the pilot there.
    time.sleep(0.5)
    names = {name for name, _ in ros.node.get_service_names_and_types()}
    assert "/robot1/pilot/change_mode" in names and "/robot2/pilot/change_mode" in names
    assert not {name for name in names if name.startswith(("/pilot/", "/amcl/"))}, sorted(names)


def test_a_namespace_that_ros_refuses_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    from sm_bt.cli import main

    for command in (["manager", "pilot", "--namespace", "robot1"], ["sim-nodes", "pilot", "--namespace", "/1a"]):
        assert main(command) == 2
        assert "is not a ROS 2 namespace: write it absolute, with letters, digits and underscores, e.g. /robot1" \
            in capsys.readouterr().err
