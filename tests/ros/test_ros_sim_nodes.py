"""The simulated nodes as real ROS 2 processes (``sm-bt sim-nodes``), driven over ROS.

Each test starts its own process (a few nodes each) and talks to it with plain rclpy clients from a
fresh context, as the ROS backend will: lifecycle services, parameter services, transition events.
The test-side context is created before the process so that discovery usually completes while the
process starts.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetState
from rcl_interfaces.srv import GetParameters, SetParametersAtomically
from ros_processes import (
    RosContext,
    Starter,
    call,
    node_processes_fixture,  # noqa: F401  (the node_processes fixture)
    ros_context_fixture,  # noqa: F401  (the ros_context fixture)
    wait_until,
)

from sm_bt.model.types import ParamValue
from sm_bt.ros.parameters import from_parameter_value, to_parameters

pytestmark = pytest.mark.ros

MODELS = Path(__file__).parents[1] / "models"
PILOT_NODES = ["/amcl", "/controller_server", "/pointcloud_to_laser", "/laser_resender"]


# -- small clients ------------------------------------------------------------------------------------


def state(ros: RosContext, node: str) -> str:
    return str(ros.call(GetState, f"{node}/get_state", GetState.Request()).current_state.label)


def change(ros: RosContext, node: str, *, label: str = "", transition_id: int = 0) -> bool:
    request = ChangeState.Request()
    request.transition.label = label
    request.transition.id = transition_id
    return bool(ros.call(ChangeState, f"{node}/change_state", request).success)


def set_parameters(ros: RosContext, node: str, values: dict[str, ParamValue]) -> Any:
    request = SetParametersAtomically.Request(parameters=to_parameters(values))
    return ros.call(SetParametersAtomically, f"{node}/set_parameters_atomically", request).result


def parameters(ros: RosContext, node: str, *names: str) -> dict[str, ParamValue | None]:
    response = ros.call(GetParameters, f"{node}/get_parameters", GetParameters.Request(names=list(names)))
    return {name: from_parameter_value(value) for name, value in zip(names, response.values, strict=True)}


def services_of(ros: RosContext, node: str) -> set[str]:
    """The services the graph lists for ``node`` (``"/name"``), once it lists its get_parameters.

    Node names reach the graph on their own topic, a little after the services do.
    """
    namespace, _, name = node.rpartition("/")
    found: set[str] = set()

    def listed() -> bool:
        nonlocal found
        try:
            found = {service for service, _ in ros.node.get_service_names_and_types_by_node(name, namespace or "/")}
        except Exception:  # NodeNameNonExistentError (rclpy's C extension) until the name is known
            return False
        return f"{node}/get_parameters" in found

    wait_until(listed, 5.0, f"{node} never listed its services")
    return found


def transitions(events: list[Any]) -> list[tuple[str, str]]:
    return [(event.start_state.label, event.goal_state.label) for event in list(events)]


def watch(ros: RosContext, node: str) -> list[Any]:
    """The list the node's transition events will be appended to.

    Call it before starting the process: the node then matches the reader as it creates its
    publisher, whereas a reader created later might miss the first events (volatile topic).
    """
    return ros.subscribe(TransitionEvent, f"{node}/transition_event")


def await_publisher(ros: RosContext, node: str) -> None:
    topic = f"{node}/transition_event"
    wait_until(lambda: ros.node.count_publishers(topic) > 0, 10.0, f"no publisher on {topic}")


# -- tests ----------------------------------------------------------------------------------------------


def test_ready_lists_the_nodes_which_start_unconfigured_with_the_model_parameters(
    ros_context: RosContext, node_processes: Starter
) -> None:
    process = node_processes("pilot")
    assert process.names == PILOT_NODES
    assert [state(ros_context, node) for node in PILOT_NODES] == ["unconfigured"] * 4
    assert parameters(ros_context, "/controller_server", "FollowPath.max_vel_x", "FollowPath.max_vel_theta") == {
        "FollowPath.max_vel_x": 0.3, "FollowPath.max_vel_theta": 1.25}
    assert parameters(ros_context, "/laser_resender", "node_name", "sim.transition_delay", "sim.fail_next",
                      "sim.reject_parameters", "sim.broken") == {
        "node_name": "laser_resender", "sim.transition_delay": 0.0, "sim.fail_next": "",
        "sim.reject_parameters": "", "sim.broken": False}


def test_change_state_by_label_and_by_id_with_transition_events(
    ros_context: RosContext, node_processes: Starter
) -> None:
    events = watch(ros_context, "/amcl")
    node_processes("pilot", "--only", "amcl")
    await_publisher(ros_context, "/amcl")
    assert change(ros_context, "/amcl", label="configure")
    assert state(ros_context, "/amcl") == "inactive"
    assert change(ros_context, "/amcl", transition_id=Transition.TRANSITION_ACTIVATE)
    assert state(ros_context, "/amcl") == "active"
    wait_until(lambda: len(events) >= 4, 2.0, f"4 transition events expected, got {transitions(events)}")
    assert transitions(events) == [("unconfigured", "configuring"), ("configuring", "inactive"),
                                   ("inactive", "activating"), ("activating", "active")]


def test_an_invalid_transition_is_answered_false_and_the_process_keeps_serving(
    ros_context: RosContext, node_processes: Starter
) -> None:
    node_processes("pilot", "--only", "amcl,controller_server", "--state", "active")
    # By id: rclpy would raise out of the executor and stop the whole process without the guard.
    assert not change(ros_context, "/amcl", transition_id=Transition.TRANSITION_CONFIGURE)
    assert not change(ros_context, "/amcl", transition_id=99)
    assert not change(ros_context, "/amcl", label="cleanup")
    assert state(ros_context, "/amcl") == "active"
    assert state(ros_context, "/controller_server") == "active"
    assert change(ros_context, "/amcl", label="deactivate")
    assert state(ros_context, "/amcl") == "inactive"


def test_parameters_are_statically_typed(ros_context: RosContext, node_processes: Starter) -> None:
    node_processes("pilot", "--only", "controller_server")
    result = set_parameters(ros_context, "/controller_server", {"FollowPath.max_vel_x": 1})
    assert not result.successful
    assert "type" in result.reason.lower()
    assert not set_parameters(ros_context, "/controller_server", {"FollowPath.undeclared": 1.0}).successful
    assert parameters(ros_context, "/controller_server", "FollowPath.max_vel_x") == {"FollowPath.max_vel_x": 0.3}
    assert set_parameters(ros_context, "/controller_server",
                          {"FollowPath.max_vel_x": 0.5, "FollowPath.max_speed_xy": 0.5}).successful
    assert parameters(ros_context, "/controller_server", "FollowPath.max_vel_x") == {"FollowPath.max_vel_x": 0.5}


def test_fail_next_fails_one_requested_transition_with_failure_or_error(
    ros_context: RosContext, node_processes: Starter
) -> None:
    node = "/pointcloud_to_laser"
    events = watch(ros_context, node)
    node_processes("pilot", "--only", "pointcloud_to_laser", "--state", "inactive")
    await_publisher(ros_context, node)
    assert set_parameters(ros_context, node, {"sim.fail_next": "activate"}).successful
    assert not change(ros_context, node, label="activate")
    assert state(ros_context, node) == "inactive"  # FAILURE: back to the start state
    assert parameters(ros_context, node, "sim.fail_next") == {"sim.fail_next": ""}  # used once

    assert set_parameters(ros_context, node, {"sim.fail_next": "activate:error"}).successful
    assert not change(ros_context, node, label="activate")
    assert state(ros_context, node) == "unconfigured"  # ERROR: errorprocessing, on_error SUCCESS
    assert parameters(ros_context, node, "sim.fail_next") == {"sim.fail_next": ""}
    # The process's own configure (--state inactive) may come first: the reader existed already.
    wait_until(lambda: transitions(events)[-1:] == [("errorprocessing", "unconfigured")], 2.0,
               f"transition events: {transitions(events)}")
    assert transitions(events)[-5:] == [
        ("inactive", "activating"), ("activating", "inactive"),
        ("inactive", "activating"), ("activating", "errorprocessing"), ("errorprocessing", "unconfigured")]

    rejected = set_parameters(ros_context, node, {"sim.fail_next": "explode"})
    assert not rejected.successful
    assert "configure" in rejected.reason
    assert change(ros_context, node, label="configure")  # nothing pending any more
    assert change(ros_context, node, label="activate")
    assert state(ros_context, node) == "active"


def test_hang_next_leaves_one_transition_unanswered_until_the_process_stops(
    ros_context: RosContext, node_processes: Starter
) -> None:
    node = "/amcl"
    process = node_processes("pilot", "--only", "amcl")
    rejected = set_parameters(ros_context, node, {"sim.hang_next": "explode"})
    assert not rejected.successful and "configure" in rejected.reason
    assert set_parameters(ros_context, node, {"sim.hang_next": "configure"}).successful
    time.sleep(0.3)  # the answer's path to this client (see RosContext.call): the request goes once
    request = ChangeState.Request()
    request.transition.label = "configure"
    with pytest.raises(AssertionError, match=r"no response within 1\.5 s"):
        call(ros_context.client(ChangeState, f"{node}/change_state"), request, timeout=1.5)
    # Hung, not dead: the process ends at once when asked to (its stop releases the callback).
    assert process.stop() == 0


def test_transition_delay_makes_transitions_take_time_without_holding_up_other_nodes(
    ros_context: RosContext, node_processes: Starter
) -> None:
    node_processes("pilot", "--only", "amcl,controller_server")
    for node in ("/amcl", "/controller_server"):
        assert set_parameters(ros_context, node, {"sim.transition_delay": 0.6}).successful
    start = time.monotonic()
    assert change(ros_context, "/amcl", label="configure")
    assert 0.6 <= time.monotonic() - start < 1.5
    # Two nodes at once: one executor thread per node, so both callbacks sleep in parallel.
    clients = [ros_context.client(ChangeState, f"{node}/change_state") for node in ("/amcl", "/controller_server")]
    ros_context.wait_for(clients)
    futures = []
    start = time.monotonic()
    for client, label in zip(clients, ("activate", "configure"), strict=True):
        request = ChangeState.Request()
        request.transition.label = label
        futures.append(client.call_async(request))
    wait_until(lambda: all(future.done() for future in futures), 3.0, "the two transitions did not finish")
    assert time.monotonic() - start < 1.1  # one after the other would take 1.2 s
    assert [future.result().success for future in futures] == [True, True]
    assert not set_parameters(ros_context, "/amcl", {"sim.transition_delay": -1.0}).successful


def test_reject_parameters_refuses_model_parameters_but_not_sim_ones(
    ros_context: RosContext, node_processes: Starter
) -> None:
    node = "/controller_server"
    node_processes("pilot", "--only", "controller_server")
    assert set_parameters(ros_context, node, {"sim.reject_parameters": "controller busy"}).successful
    result = set_parameters(ros_context, node, {"FollowPath.max_vel_x": 0.1})
    assert (result.successful, result.reason) == (False, "controller busy")
    mixed = set_parameters(ros_context, node, {"FollowPath.max_vel_x": 0.1, "sim.transition_delay": 0.1})
    assert not mixed.successful
    assert parameters(ros_context, node, "FollowPath.max_vel_x", "sim.transition_delay") == {
        "FollowPath.max_vel_x": 0.3, "sim.transition_delay": 0.0}
    assert set_parameters(ros_context, node, {"sim.transition_delay": 0.0, "sim.reject_parameters": ""}).successful
    assert set_parameters(ros_context, node, {"FollowPath.max_vel_x": 0.1}).successful


def test_a_broken_node_fails_by_itself_whenever_active(ros_context: RosContext, node_processes: Starter) -> None:
    node = "/laser_resender"
    events = watch(ros_context, node)
    node_processes("pilot", "--only", "laser_resender", "--state", "inactive")
    await_publisher(ros_context, node)
    assert change(ros_context, node, label="activate")
    wait_until(lambda: transitions(events)[-1:] == [("activating", "active")], 2.0,
               f"the activate's events never arrived: {transitions(events)}")
    del events[:]

    broken_at = time.monotonic()
    assert set_parameters(ros_context, node, {"sim.broken": True}).successful
    took = wait_until(lambda: len(events) >= 3, 1.0, f"no self-failure; events: {transitions(events)}")
    assert transitions(events) == [("active", "deactivating"), ("deactivating", "errorprocessing"),
                                   ("errorprocessing", "unconfigured")]
    assert time.monotonic() - broken_at < 1.0, took
    assert state(ros_context, node) == "unconfigured"

    # Still broken: activation succeeds, then the node fails again.
    del events[:]
    assert change(ros_context, node, label="configure")
    assert change(ros_context, node, label="activate")
    wait_until(lambda: len(events) >= 7, 1.0, f"no second self-failure; events: {transitions(events)}")
    assert transitions(events)[-1] == ("errorprocessing", "unconfigured")

    # Repaired: it stays active.
    assert set_parameters(ros_context, node, {"sim.broken": False}).successful
    assert change(ros_context, node, label="configure")
    assert change(ros_context, node, label="activate")
    time.sleep(0.3)
    assert state(ros_context, node) == "active"


def test_state_active_and_parameters_only_nodes(ros_context: RosContext, node_processes: Starter) -> None:
    process = node_processes("pilot", "--only", "amcl", "--state", "active",
                             "--parameters-only", "controller_server")
    assert process.names == ["/amcl", "/controller_server"]
    assert state(ros_context, "/amcl") == "active"
    # A plain node: parameters, but no lifecycle services.
    assert parameters(ros_context, "/controller_server", "FollowPath.max_vel_x") == {"FollowPath.max_vel_x": 0.3}
    assert "/amcl/get_state" in services_of(ros_context, "/amcl")  # the same process: discovered together
    services = services_of(ros_context, "/controller_server")
    assert not {name for name in services if name.endswith(("/get_state", "/change_state"))}, services
    get_state = ros_context.client(GetState, "/controller_server/get_state")
    time.sleep(0.3)
    assert not get_state.service_is_ready()


def test_namespaced_parts_become_namespaced_nodes(ros_context: RosContext, node_processes: Starter) -> None:
    process = node_processes(str(MODELS / "loader_namespaced.yaml"), "--state", "inactive")
    assert process.names == ["/left/gripper", "/right/gripper", "/wrist"]
    assert state(ros_context, "/left/gripper") == "inactive"
    assert parameters(ros_context, "/right/gripper", "force") == {"force": 2.0}
    assert parameters(ros_context, "/wrist", "angle") == {"angle": 0}


def test_sigint_ends_the_process_quickly_with_exit_code_0(node_processes: Starter) -> None:
    process = node_processes("pilot")
    start = time.monotonic()
    assert process.stop() == 0, process.stderr  # a hang would have needed SIGKILL after 3 s
    assert time.monotonic() - start < 2.5  # typically 0.3 s
    process.restart()
    assert process.names == PILOT_NODES
    assert process.stop() == 0, process.stderr


@pytest.mark.parametrize(("args", "code", "message"), [
    # as every sm-bt command: a model that does not load is exit 1, a name that is not a node exit 2
    ([str(MODELS / "cli_bad.yaml")], 1, "cli_bad.yaml: failed ("),
    (["no_such_model"], 1, "sm-bt: error: no_such_model: no such file, and no bundled model of that name"),
    (["pilot", "--only", "amcl,pilot,nobody"], 2, "pilot, nobody (nodes: amcl, controller_server,"),
])
def test_bad_arguments_are_said_as_by_every_command(args: list[str], code: int, message: str) -> None:
    result = subprocess.run([sys.executable, "-m", "sm_bt.cli", "sim-nodes", *args],
                            capture_output=True, text=True, timeout=20)
    assert result.returncode == code
    assert message in result.stderr.strip().splitlines()[-1]
    assert "Traceback" not in result.stderr and not result.stdout
