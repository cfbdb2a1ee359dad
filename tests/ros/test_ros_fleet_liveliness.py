"""A fleet told by DDS liveliness that a robot's manager stopped (sm_bt.ros.remote_parts).

sm-bt manager's ``mode_event`` offers a liveliness lease (sm_bt.ros.manager_node.MODE_EVENT_LEASE),
read here from the ROS graph as any client sees it; readers that ask for no lease, volatile or
transient local (the reference's and most clients'), still match and receive. A fleet asks for a
lease of its liveness window: with its probes slowed to minutes, a robot's manager frozen with
SIGSTOP (its DDS threads stop too) is unknown at the fleet within a second, and once it goes on it
is read afresh at once: only the liveliness can have told either.
"""

from __future__ import annotations

import inspect
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from lifecycle_msgs.srv import GetState
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import ManagerProcess, RosContext, Starter, Starved, wait_until
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode, GetMode

from sm_bt.engine.events import EventKind
from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.ros.manager_node import MODE_EVENT_LEASE
from sm_bt.ros.remote_parts import RemoteBackend
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

#: Two robots (/robot1/pilot, /robot2/pilot) under a fleet of __DEFAULT__ and NIGHT (robot1 in
#: f_energy_saving_mode, robot2 inactive).
FLEET = Path(__file__).resolve().parents[2] / "models" / "fleet.yaml"
#: The fleet's liveness window (RemoteBackend's default): the lease it asks for.
WINDOW = 0.9
#: The issue's goal: unknown within 1 s of the manager's last word (its last assertion came at most
#: 1/3 s before the freeze: within 1 s of the freeze is the stricter test).
TOLD = 1.0
#: Probes slowed so much that, within these tests, only the liveliness can tell a robot gone or back.
SLOWED = {"probe_interval": 10.0, "slow_probe_interval": 120.0}
#: Read again after SIGCONT within this, long before a slowed probe was due. Not the issue's 2 s
#: (the fleet bench's figure, with probes at their real pace): here no request of the fleet is left
#: in flight when the manager goes on, and the first one asked of a process that stood still for a
#: couple of seconds went unanswered for its window about every other run (then the next, asked at
#: once, within 0.7 s), though a fresh client's was answered in 10 ms.
HEALED = 3.0
#: As the reference's subscribers (rclcpp's default QoS) and most clients: volatile; and a latched reader.
VOLATILE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
LATE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
CALL_TIMEOUT = 3.0
#: Over shared memory (Fast DDS's default between local processes), a request written to a process
#: frozen for more than about a second is dropped, and the client's later requests are held back
#: behind it until its writer repairs it, 2-3 s later (seen: the first get_state after SIGCONT took
#: 2.6 s on that client, 2 ms on a fresh one). Over UDP, what comes meanwhile waits in the frozen
#: process's socket, and a cut link loses it at once: no frozen port.
UDP_ONLY = {"FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}


def test_the_fleets_window_is_the_one_these_tests_time_and_the_lease_fits_in_it() -> None:
    defaults = inspect.signature(RemoteBackend).parameters
    assert defaults["liveness_timeout"].default == WINDOW
    assert MODE_EVENT_LEASE <= WINDOW  # an offered lease longer than the requested one does not match


def _publishers(ros: RosContext, topic: str) -> list[Any]:
    wait_until(lambda: bool(ros.node.get_publishers_info_by_topic(topic)), 20.0, f"no writer of {topic}")
    return list(ros.node.get_publishers_info_by_topic(topic))


def test_sm_bt_managers_mode_event_offers_a_liveliness_lease_and_its_other_topics_none(
        start_manager: Callable[..., ManagerProcess], ros_context: RosContext) -> None:
    start_manager("--namespace", "/robot1", "--log-level", "warning").ready()
    for topic in ("/robot1/pilot/mode_event", "/robot1/amcl/mode_event"):  # a system's and a node's
        [writer] = _publishers(ros_context, topic)
        qos = writer.qos_profile
        assert qos.liveliness == LivelinessPolicy.AUTOMATIC, (topic, qos.liveliness)
        assert qos.liveliness_lease_duration.nanoseconds == round(MODE_EVENT_LEASE * 1e9), (
            topic, qos.liveliness_lease_duration)
        assert qos.durability == DurabilityPolicy.TRANSIENT_LOCAL and qos.reliability == ReliabilityPolicy.RELIABLE
    for topic in ("/robot1/pilot/transition_event", "/robot1/pilot/mode_request_info",
                  "/robot1/pilot/transition_request_info"):
        [writer] = _publishers(ros_context, topic)
        assert writer.qos_profile.liveliness_lease_duration.nanoseconds > 10 ** 18, (  # infinite
            topic, writer.qos_profile.liveliness_lease_duration)


def test_readers_that_ask_for_no_lease_volatile_and_transient_local_still_receive_mode_event(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    manager = start_manager("--log-level", "warning")
    node_processes("pilot")
    manager.ready()
    ros = ros_context
    volatile: list[Any] = []
    late: list[Any] = []
    readers = [ros.node.create_subscription(ModeEvent, "/pilot/mode_event", volatile.append, VOLATILE)]
    wait_until(lambda: readers[0].get_publisher_count() > 0, 20.0, "the volatile reader never matched")
    assert ros.call(ChangeMode, "/pilot/change_mode", ChangeMode.Request(mode_name="__DEFAULT__"), CALL_TIMEOUT).success
    wait_until(lambda: [m.goal_mode.label for m in volatile] == ["__DEFAULT__"], 20.0,
               f"the volatile reader heard no __DEFAULT__: {[m.goal_mode.label for m in volatile]}")
    # A transient-local reader that comes now gets the current mode first.
    readers.append(ros.node.create_subscription(ModeEvent, "/pilot/mode_event", late.append, LATE))
    wait_until(lambda: [m.goal_mode.label for m in late] == ["__DEFAULT__"], 20.0,
               f"the late latched reader did not get the current mode: {[m.goal_mode.label for m in late]}")
    assert ros.call(ChangeMode, "/pilot/change_mode", ChangeMode.Request(mode_name="f_degraded_mode"),
                    CALL_TIMEOUT).success
    for heard in (volatile, late):
        wait_until(lambda heard=heard: [m.goal_mode.label for m in heard][-1:] == ["f_degraded_mode"], 10.0,
                   "a reader heard no f_degraded_mode")


def _robot_view(ros: RosContext, robot: str) -> tuple[State, str] | None:
    """``robot``'s state and mode as its own manager answers them (None: no answer in time)."""
    try:
        state = State(int(ros.call(GetState, f"/{robot}/pilot/get_state", GetState.Request(), 1.0).current_state.id))
        mode = str(ros.call(GetMode, f"/{robot}/pilot/get_mode", GetMode.Request(), 1.0).current_mode)
    except (AssertionError, ValueError):
        return None
    return state, mode


def test_a_frozen_robot_manager_is_told_by_its_liveliness_within_a_second_and_read_afresh_when_it_goes_on(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext,
        monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in UDP_ONLY.items():  # the processes started here, and the fleet's participant
        monkeypatch.setenv(name, value)
    managers = {name: start_manager("--namespace", f"/{name}", "--log-level", "warning")
                for name in ("robot1", "robot2")}
    for name in managers:
        node_processes("pilot", "--namespace", f"/{name}", "--state", "inactive")
    for process in managers.values():
        process.ready()
    runtime = RosRuntime(load_model(FLEET), node_name="fleet_manager", manager_options={"request_timeout": 20.0},
                         backend_options=SLOWED)
    robot1 = managers["robot1"].process
    assert robot1 is not None
    try:
        fleet = runtime.manager
        wait_until(lambda: all(fleet.actual(r).state is State.INACTIVE for r in managers), 30.0,
                   "the fleet never read its robots")
        night = fleet.change_mode("fleet", "NIGHT")
        wait_until(lambda: night.done, 20.0, "the fleet's switch did not end")
        assert night.succeeded, night.reason
        views: list[tuple[float, str]] = []
        with fleet.lock:
            watch = fleet.subscribe(lambda event: views.append((time.monotonic(), str(event.actual))),
                                    part="robot1", kinds=[EventKind.ACTUAL])
        try:
            # Its probes are minutes apart now: were it judged by their silence, it would flap here.
            time.sleep(2 * WINDOW + 0.5)
            assert str(fleet.actual("robot1")) == "active.f_energy_saving_mode", views
            assert not any(view.startswith("unknown") for _, view in views), views

            with Starved() as starved:
                os.kill(robot1.pid, signal.SIGSTOP)
                stopped = time.monotonic()
                try:
                    wait_until(lambda: fleet.actual("robot1").state is State.UNKNOWN, 5.0, "robot1 never unknown")
                    told = min(when for when, view in views if view.startswith("unknown")) - stopped
                    assert fleet.observation("robot1").gone == (
                        "no answer from the manager of robot1 (/robot1/pilot) for 0.9 s (it exited, or the network is "
                        "cut)")
                    assert fleet.actual("robot2").state is State.INACTIVE  # NIGHT: robot2 inactive
                    # Frozen past the timeout of the probe sent at the verdict: nothing the fleet asked is
                    # left for it to answer when it goes on, and the next probe is seconds away.
                    time.sleep(WINDOW + 0.6)
                finally:
                    os.kill(robot1.pid, signal.SIGCONT)
                    resumed = time.monotonic()
            assert told <= TOLD + starved.worst, (
                f"robot1 unknown {told:.2f} s after its manager froze (this process stood still for "
                f"{starved.worst:.2f} s)")
            # Read afresh: its state and mode as its own manager answers them, long before a probe was due.
            wait_until(lambda: fleet.actual("robot1").known and _robot_view(ros_context, "robot1") == (
                fleet.actual("robot1").state, fleet.actual("robot1").mode), 10.0, "robot1 never read again")
            healed = min(when for when, view in views if when > resumed and not view.startswith("unknown")) - resumed
            assert healed <= HEALED, f"robot1 read again {healed:.2f} s after its manager went on"
            assert str(fleet.actual("robot1")) == "active.f_energy_saving_mode"
            assert str(fleet.actual("fleet")) == "active.NIGHT"
            print(f"MEASURED liveliness: robot1 unknown {told:.3f} s after SIGSTOP, read again {healed:.3f} s after "
                  "SIGCONT")
        finally:
            watch.cancel()
    finally:
        os.kill(robot1.pid, signal.SIGCONT)
        runtime.close()
