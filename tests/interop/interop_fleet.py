"""A fleet manager whose robots are served by the reference's ``mode_manager`` and by ``sm-bt manager``.

robot1 is the pilot's four simulated nodes at the root namespace under the reference's manager (built by
``tools/reference/build.sh``; ``SM_BT_REFERENCE``, as ``make interop`` sets it), on the model as the
reference reads it (:func:`reference.reference_model`): the reference names its nodes' topics absolute
and matches parameter events by node name without namespace, so it serves nodes at the root only.
robot2 is the same in ``/robot2`` under ``sm-bt manager``.
The fleet (a :class:`~sm_bt.ros.runtime.RosRuntime` in this process) drives both through their
system_modes interface (sm_bt.ros.remote_parts). The reference knows no state of its system until
a node moves, and its events come from a 1 s timer: robot1 says ``served_by: reference``,
so its changes take one to two seconds. What each robot's own manager and nodes say is checked,
not only what the fleet believes. Named ``interop_*.py``: ``make interop`` runs it, ``make test``
does not (it needs the reference's build).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from lifecycle_msgs.srv import GetState
from reference import ReferenceManager, reference_model
from ros_processes import ManagerProcess, RosContext, Starter, remove_stale_shm_files, wait_until
from system_modes_msgs.srv import GetMode

from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.ros.runtime import RosRuntime

FLEET = """\
fleet:
  ros__parameters:
    type: system
    modes:
      __DEFAULT__:
        robot1: active.f_normal_mode
        robot2: active.f_normal_mode
      FAST:
        robot1: active.f_performance_mode
        robot2: active.f_performance_mode
      REST:
        robot1: inactive
        robot2: inactive

robot1:
  ros__parameters:
    type: remote
    system: pilot                 # at the root: the reference's mode_manager serves nodes there only
    served_by: reference          # micro-ROS/system_modes' mode_manager
    modes: [__DEFAULT__, f_normal_mode, f_performance_mode]

robot2:
  ros__parameters:
    type: remote
    manager: /robot2
    system: pilot
    modes: [__DEFAULT__, f_normal_mode, f_performance_mode]
"""
#: A fleet request over the reference: its events come from a 1 s timer, one tick per stage.
REQUEST_TIMEOUT = 30.0


@pytest.fixture
def robots(node_processes: Starter, start_manager: Callable[..., ManagerProcess],
           tmp_path: Path) -> Iterator[None]:
    """robot1 under the reference (its nodes first, as on a robot: see interop_cli's fixture), robot2
    under sm-bt manager; the reference is stopped by PID at teardown (the rest by their fixtures)."""
    model = reference_model("pilot", tmp_path)
    node_processes(str(model))
    reference = ReferenceManager(model)
    try:
        reference.start()
        node_processes("pilot", "--namespace", "/robot2")
        start_manager("--namespace", "/robot2").ready()
        yield
    finally:
        reference.stop()
        print("the reference's log, last lines:", *reference.stderr.splitlines()[-60:], sep="\n")
        remove_stale_shm_files()


def _robot(ros_context: RosContext, name: str) -> tuple[State, str]:
    """What the robot's own manager says of its pilot."""
    prefix = "" if name == "robot1" else f"/{name}"
    state = ros_context.call(GetState, f"{prefix}/pilot/get_state", GetState.Request(), 5.0).current_state.id
    mode = ros_context.call(GetMode, f"{prefix}/pilot/get_mode", GetMode.Request(), 5.0).current_mode
    return State(state), str(mode)


def _done(runtime: RosRuntime, mode: str) -> None:
    started = time.monotonic()
    request = runtime.manager.change_mode("fleet", mode)
    wait_until(lambda: request.done, REQUEST_TIMEOUT + 5, f"fleet {mode} did not end")
    assert request.succeeded, request.reason
    print(f"MEASURED fleet {mode} over the reference and sm-bt manager: {time.monotonic() - started:.2f} s")


def _node_state(ros_context: RosContext, name: str) -> State:
    """What a node of robot1 itself says (not its manager)."""
    return State(ros_context.call(GetState, f"/{name}/get_state", GetState.Request(), 5.0).current_state.id)


def test_a_fleet_brings_up_switches_and_rests_a_robot_of_the_reference_beside_one_of_sm_bt(
        robots: None, ros_context: RosContext, tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text(FLEET, encoding="utf-8")
    runtime = RosRuntime(load_model(path), node_name="fleet_manager",
                         manager_options={"request_timeout": REQUEST_TIMEOUT})
    try:
        manager = runtime.manager
        # The reference answers unknown: taken for unconfigured, as its nodes are.
        wait_until(lambda: manager.actual("robot1").state is State.UNCONFIGURED
                   and manager.actual("robot2").state is State.UNCONFIGURED, 20.0,
                   f"the fleet never read its robots: {manager.actual('robot1')}, {manager.actual('robot2')}")
        assert _robot(ros_context, "robot1")[0] is State.UNKNOWN

        for mode, pilot in (("__DEFAULT__", "f_normal_mode"), ("FAST", "f_performance_mode"),
                            ("__DEFAULT__", "f_normal_mode")):
            _done(runtime, mode)
            for name in ("robot1", "robot2"):
                assert _robot(ros_context, name) == (State.ACTIVE, pilot), name
                assert manager.actual(name).state is State.ACTIVE
                assert manager.observation(name).parameters == {"__mode__": pilot}, name
        # The nodes themselves, not only the reference's word: f_normal_mode has pointcloud_to_laser inactive.
        assert _node_state(ros_context, "amcl") is State.ACTIVE
        assert _node_state(ros_context, "pointcloud_to_laser") is State.INACTIVE

        _done(runtime, "REST")
        assert _robot(ros_context, "robot1")[0] is State.INACTIVE
        assert _node_state(ros_context, "amcl") is State.INACTIVE
        # Back up from inactive: activation is its change_mode to the fleet's mode, not the
        # reference's activate (which means __DEFAULT__, every pilot part inactive).
        _done(runtime, "FAST")
        assert _robot(ros_context, "robot1") == (State.ACTIVE, "f_performance_mode")
        assert _node_state(ros_context, "amcl") is State.ACTIVE
        assert manager.actual("fleet").mode == "FAST"
    finally:
        runtime.close()
