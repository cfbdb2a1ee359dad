"""A fleet manager over real ROS 2: its remote parts are robots, each the pilot's four nodes with its
own ``sm-bt manager`` in a namespace of its own; the fleet asks them through their system_modes
interface and follows their events (sm_bt.ros.remote_parts)."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable

import pytest
from fleet_robots import FLEET, fleet_fixture, robots  # noqa: F401 (the fixture)
from lifecycle_msgs.srv import GetState
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from ros_processes import ManagerProcess, RosContext, Starter, wait_until
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.engine.events import EventKind
from sm_bt.model.states import State
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

#: The fleet's liveness window (RemoteBackend's default), and what the verdict
#: may take beyond them on a loaded machine.
WINDOW, LATENCY = 0.9, 0.3
#: RemoteBackend's default pace of the probes of a robot whose liveliness DDS vouches for.
SLOW_PROBES = 3.0
#: lifecycle_msgs/msg/State's id.
INACTIVE = 2


def test_a_fleet_drives_robots_through_their_managers_and_tells_one_cut_off(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext,
        fleet: RosRuntime) -> None:
    managers = robots(start_manager, node_processes, fleet)
    fleet_manager = fleet.manager
    up = fleet_manager.change_mode("fleet", "__DEFAULT__")
    wait_until(lambda: up.done, 20.0, "the fleet's bring-up did not end")
    assert up.succeeded, up.reason
    night = fleet_manager.change_mode("fleet", "NIGHT")
    wait_until(lambda: night.done, 20.0, "the fleet's switch did not end")
    assert night.succeeded, night.reason
    # Each robot's own manager did it: its interface says so.
    mode = ros_context.call(GetMode, "/robot1/pilot/get_mode", GetMode.Request(), 5.0).current_mode
    assert mode == "f_energy_saving_mode"
    assert str(fleet_manager.actual("robot1")) == "active.f_energy_saving_mode"
    assert fleet_manager.actual("robot2").state is State.INACTIVE
    assert str(fleet_manager.actual("fleet")) == "active.NIGHT"

    # DDS vouches for the robots' managers: their probes are seconds apart, and their silence between
    # them is no verdict.
    views: list[str] = []
    with fleet_manager.lock:
        watch = fleet_manager.subscribe(lambda event: views.append(str(event.actual)), part="robot1",
                                        kinds=[EventKind.ACTUAL])
    time.sleep(SLOW_PROBES + 2 * WINDOW)
    watch.cancel()
    assert views == [] and str(fleet_manager.actual("robot1")) == "active.f_energy_saving_mode", views

    # Robot1's manager stops answering (frozen, its DDS threads too): unknown at the fleet within the window.
    robot1 = managers["robot1"].process
    assert robot1 is not None
    os.kill(robot1.pid, signal.SIGSTOP)
    try:
        stopped = time.monotonic()
        wait_until(lambda: fleet_manager.actual("robot1").state is State.UNKNOWN, 5.0, "robot1 never unknown")
        took = time.monotonic() - stopped
        # One window after its last word: its liveliness, asserted by DDS every 1/3 s, tells it.
        assert took <= WINDOW + LATENCY, f"robot1 unknown {took:.2f} s after its manager froze"
        assert "no answer from the manager of robot1 (/robot1/pilot)" in fleet_manager.observation("robot1").gone
        assert fleet_manager.actual("robot2").state is State.INACTIVE
    finally:
        os.kill(robot1.pid, signal.SIGCONT)
    # Healed: read afresh, and the fleet is consistent with the robot again.
    wait_until(lambda: str(fleet_manager.actual("robot1")) == "active.f_energy_saving_mode", 10.0,
               "robot1 never read again")
    assert str(fleet_manager.actual("fleet")) == "active.NIGHT"


def test_sm_bt_manager_of_a_fleet_model_serves_the_fleet_over_the_robots_managers(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    for name in ("robot1", "robot2"):
        start_manager("--namespace", f"/{name}").ready()
        node_processes("pilot", "--namespace", f"/{name}", "--state", "inactive")
    fleet = start_manager("--node-name", "fleet_manager", model=str(FLEET)).ready()
    # Its stderr is read by a thread of its own: the start-up lines may follow "serving" by a moment.
    wait_until(lambda: "- remote part 'robot1': /robot1/pilot, served by its own manager" in fleet.stderr, 5.0,
               "no start-up line for the remote part")
    ros = ros_context

    def state_of(part: str) -> int:
        try:
            return int(ros.call(GetState, f"/{part}/get_state", GetState.Request(), 5.0).current_state.id)
        except TimeoutError:
            return -1

    def mode_of(part: str) -> str:
        try:
            return str(ros.call(GetMode, f"/{part}/get_mode", GetMode.Request(), 5.0).current_mode)
        except TimeoutError:
            return ""

    wait_until(lambda: len(fleet.lines("appeared: inactive")) == 2, 20.0, "the fleet never read its robots")
    wait_until(lambda: state_of("fleet") == INACTIVE, 5.0, "the fleet never inferred its state")
    answer = ros.call(ChangeMode, "/fleet/change_mode", ChangeMode.Request(mode_name="NIGHT"), 5.0)
    assert answer.success
    wait_until(lambda: mode_of("fleet") == "NIGHT", 20.0, "the fleet never reached NIGHT")
    assert mode_of("robot1/pilot") == "f_energy_saving_mode"
    assert state_of("robot2/pilot") == INACTIVE


def test_a_robots_failed_request_fails_the_fleets_at_once_with_the_robots_reason(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext,
        fleet: RosRuntime) -> None:
    """robot1's amcl fails its activation: robot1's own request fails, and the fleet's with it, its
    reason the robot's, long before the fleet's request timeout (20 s). The robot's log names the
    fleet as the requester."""
    managers = robots(start_manager, node_processes, fleet)
    fleet_manager = fleet.manager
    parameter = Parameter(name="sim.fail_next", value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                                      string_value="activate"))
    answer = ros_context.call(SetParameters, "/robot1/amcl/set_parameters", SetParameters.Request(
        parameters=[parameter]), 5.0)
    assert answer.results[0].successful, answer.results[0].reason
    start = time.monotonic()
    night = fleet_manager.change_mode("fleet", "NIGHT")
    wait_until(lambda: night.done, 20.0, "the fleet's switch did not end")
    took = time.monotonic() - start
    assert not night.succeeded
    assert "robot1: activate failed: its manager's request #" in night.reason, night.reason
    assert "amcl: activate failed" in night.reason, night.reason
    assert took < 10.0, f"the fleet's request failed {took:.1f} s after it was made"
    assert "change_mode pilot f_energy_saving_mode started [fleet]" in managers["robot1"].stderr
