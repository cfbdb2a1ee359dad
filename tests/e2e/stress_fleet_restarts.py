"""``make stress``: a fleet's robot whose manager is killed during a change and started again (the
fleet over real ROS 2 of tests/ros/test_ros_fleet.py). The fleet's view of a robot whose new manager
knows no mode of nodes left between modes is in ``make test`` against a scripted manager
(tests/ros/test_ros_remote_reference_like.py)."""

from __future__ import annotations

import time
from collections.abc import Callable

import pytest
from fleet_robots import fleet_fixture, robots  # noqa: F401 (the fixture)
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from ros_processes import ManagerProcess, RosContext, Starter, wait_until

from sm_bt.model.states import State
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

#: The fleet's liveness window (RemoteBackend's default), and what the verdict may take beyond it on a
#: loaded machine.
WINDOW, LATENCY = 0.9, 0.3
#: lifecycle_msgs/msg/State's id.
ACTIVE = 3


def test_a_robot_manager_killed_mid_change_fails_the_fleets_at_once_and_a_new_one_is_taken_on(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext,
        fleet: RosRuntime) -> None:
    """robot1's manager is killed while its slow nodes take their steps for the fleet: the fleet's
    request fails within the liveness window, not at its timeout. Its nodes are left between modes
    (amcl, asked directly, deactivates: no mode of the pilot has it inactive beside an active
    laser). The operator starts a new manager (its request numbers start again at 1), which knows no
    mode of its system and has no target, while its nodes answer: the fleet tells that from nodes
    out of its reach, and restores robot1's target through it."""
    managers = robots(start_manager, node_processes, fleet, robot1=("--transition-delay", "0.5"))
    fleet_manager = fleet.manager
    night = fleet_manager.change_mode("fleet", "NIGHT")
    robot1 = managers["robot1"]
    wait_until(lambda: robot1.lines("change_mode pilot f_energy_saving_mode started [fleet]"), 10.0,
               "robot1's manager never started the fleet's request")
    assert robot1.process is not None
    robot1.process.kill()
    killed = time.monotonic()
    wait_until(lambda: night.done, 10.0, "the fleet's request did not end")
    took = time.monotonic() - killed
    assert not night.succeeded and "no answer from the manager of robot1" in night.reason, night.reason
    assert took <= WINDOW + 2 * LATENCY, f"the fleet's request failed {took:.2f} s after robot1's manager was killed"
    assert fleet_manager.actual("robot1").state is State.UNKNOWN

    def amcl() -> int:
        return int(ros_context.call(GetState, "/robot1/amcl/get_state", GetState.Request(), 5.0).current_state.id)

    wait_until(lambda: amcl() == ACTIVE, 10.0, "robot1's amcl never active")
    deactivate = ChangeState.Request(transition=Transition(id=Transition.TRANSITION_DEACTIVATE))
    assert ros_context.call(ChangeState, "/robot1/amcl/change_state", deactivate, 10.0).success

    again = start_manager("--namespace", "/robot1").ready()
    wait_until(lambda: str(fleet_manager.actual("robot1")) == "active.f_energy_saving_mode", 20.0,
               "robot1 never restored through its new manager")
    assert again.lines("change_mode pilot f_energy_saving_mode started [fleet]"), again.stderr[-3000:]
    wait_until(lambda: str(fleet_manager.actual("fleet")) == "active.NIGHT", 5.0, "the fleet never NIGHT")
