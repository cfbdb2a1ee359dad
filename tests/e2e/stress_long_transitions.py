"""``make stress``: nodes whose every transition takes 30 s, in one executor thread (as in a component
container: nothing of the process answers meanwhile), brought up and switched over ROS 2 with no
node declared gone. ``make test`` does the same with 3 s (tests/ros/test_ros_liveness.py). And a fleet
over robots whose nodes take 10 s a transition: each fleet change takes what the robots' own take."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from model_files import bundled
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from ros_processes import ManagerProcess, RosContext, Starter, wait_until

from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros


def test_nodes_whose_transitions_take_30_s_are_brought_up_and_switched(node_processes: Starter) -> None:
    # The request needs four transitions of 30 s each, one after the other: its timeout says so, and
    # the calls may take as long (the runtime's default).
    ros = RosRuntime(bundled("actuation"), node_name="sm_bt_long_transitions",
                     manager_options={"request_timeout": 150.0, "rules": False, "recovery": False})
    try:
        node_processes("actuation", "--transition-delay", "30", "--single-threaded")
        wait_until(lambda: all(ros.manager.observation(n).reachable for n in ("manipulator", "drive_base")),
                   15.0, "nodes not discovered")
        vanished: list[str] = []
        ros.manager.subscribe(lambda event: vanished.append(event.message) if "vanished" in event.message else None)
        started = time.monotonic()
        request = ros.manager.change_mode("actuation", "PERFORMANCE")
        wait_until(lambda: request.done, 150.0, "the request did not end")
        took = time.monotonic() - started
        assert request.succeeded, request.reason
        assert 120.0 <= took < 130.0, took  # four transitions of 30 s, one after the other
        assert vanished == []
        assert not ros.backend.link("drive_base").slow
    finally:
        ros.close()


#: Two robots (/robot1/pilot, /robot2/pilot) under a fleet of __DEFAULT__ and NIGHT.
FLEET = Path(__file__).resolve().parents[2] / "models" / "fleet.yaml"
#: Seconds each transition of the robots' nodes takes.
SLOW = 10.0
NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")


def test_a_fleet_over_robots_whose_nodes_take_seconds_takes_what_the_robots_own_changes_take(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    managers = {name: start_manager("--namespace", f"/{name}") for name in ("robot1", "robot2")}
    for name in managers:
        node_processes("pilot", "--namespace", f"/{name}", "--state", "inactive")
    for manager in managers.values():
        manager.ready()
    slow = Parameter(name="sim.transition_delay", value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                                       double_value=SLOW))
    for name in managers:  # from now on (brought inactive at once)
        for node in NODES:
            answer = ros_context.call(SetParameters, f"/{name}/{node}/set_parameters",
                                      SetParameters.Request(parameters=[slow]), 5.0)
            assert answer.results[0].successful, answer.results[0].reason
    fleet = RosRuntime(load_model(FLEET), node_name="fleet_manager", manager_options={"request_timeout": 120.0})
    try:
        wait_until(lambda: all(fleet.manager.actual(r).state is State.INACTIVE for r in managers), 20.0,
                   "the fleet never read its robots")
        for mode in ("NIGHT", "__DEFAULT__", "NIGHT"):
            before = {name: len(manager.lines("succeeded in")) for name, manager in managers.items()}
            started = time.monotonic()
            request = fleet.manager.change_mode("fleet", mode)
            wait_until(lambda: request.done, 120.0, f"the fleet's {mode} did not end")  # noqa: B023 (used at once)
            took = time.monotonic() - started
            assert request.succeeded, request.reason
            # What each robot's own manager took for the fleet's request (a robot already there: none).
            own = max(float(re.findall(r"succeeded in ([\d.]+) s", line)[0]) for name, manager in managers.items()
                      for line in manager.lines("succeeded in")[before[name]:])
            print(f"MEASURED fleet {mode} over nodes of {SLOW:g} s transitions: {took:.2f} s, the slowest robot's "
                  f"own {own:.2f} s")
            assert took <= own + 1.0, (took, own)
        for manager in managers.values():
            assert manager.lines("vanished") == [], manager.lines("vanished")
    finally:
        fleet.close()
