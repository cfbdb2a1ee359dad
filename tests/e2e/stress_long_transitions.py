"""``make stress``: nodes whose every transition takes 30 s, in one executor thread (as in a component
container: nothing of the process answers meanwhile), brought up and switched over ROS 2 with no
node declared gone. ``make test`` does the same with 3 s (tests/ros/test_ros_liveness.py)."""

from __future__ import annotations

import time

import pytest
from model_files import bundled
from ros_processes import Starter, wait_until

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
