"""The snapshot-stream protocol of py_trees_ros, as its tree watcher and viewer speak it, against a
hosted sm_bt mission: the client side here uses rclpy and the interface types only (no sm_bt
code), finds the services by type, opens a stream and reads the snapshots while the mission
changes mode."""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import py_trees
import pytest
from py_trees_ros_interfaces.msg import Behaviour, BehaviourTree
from py_trees_ros_interfaces.srv import CloseSnapshotStream, OpenSnapshotStream, ReconfigureSnapshotStream
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import RosContext, Starter, call, wait_until

pytestmark = pytest.mark.ros

MISSION = """<root main_tree_to_execute="Mission">
  <BehaviorTree ID="Mission">
    <ReactiveSequence name="Mission">
      <ModesToBlackboard name="Modes" parts="{parts}"/>
      <Sequence name="Work">
        <WaitForState name="Nodes up?" part="amcl" state="unconfigured" timeout="60"/>
        <ChangeMode name="f_slow_mode" part="pilot" mode="f_slow_mode" timeout="15"/>
        <Running name="Hold on"/>
      </Sequence>
    </ReactiveSequence>
  </BehaviorTree>
</root>
"""
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
OPEN_TYPE = "py_trees_ros_interfaces/srv/OpenSnapshotStream"


@pytest.fixture
def client() -> Iterator[RosContext]:
    ros = RosContext("plain_tree_watcher")
    yield ros
    ros.close()


@pytest.fixture
def mission(tmp_path: Path) -> Iterator[subprocess.Popen[str]]:
    """The hosted mission, started before the nodes: it waits for them in the tree."""
    (tmp_path / "mission.xml").write_text(MISSION.replace(' parts="{parts}"', ""))
    host = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "mission", "--ros-args", "-p", "model:=pilot",
                             "-p", "tree:=mission.xml", "-p", "rate:=20.0", "-p", "wait_for_nodes:=0.0",
                             "-r", "__node:=mission_tree"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    yield host
    if host.poll() is None:
        host.send_signal(signal.SIGINT)
    try:
        host.wait(8.0)
    except subprocess.TimeoutExpired:
        host.kill()
        host.wait(3.0)


def _find_by_type(node: Any, service_type: str) -> list[str]:
    return [name for name, types in node.get_service_names_and_types() if service_type in types]


def test_a_plain_client_watches_the_mission_change_mode(client: RosContext, mission: subprocess.Popen[str],
                                                       node_processes: Starter) -> None:
    node = client.node
    wait_until(lambda: mission.poll() is not None or bool(_find_by_type(node, OPEN_TYPE)), 20.0,
               "an OpenSnapshotStream service on the graph")
    assert mission.poll() is None, mission.stderr.read() if mission.stderr else ""
    assert _find_by_type(node, OPEN_TYPE) == ["/mission_tree/snapshot_streams/open"]

    opener = node.create_client(OpenSnapshotStream, "/mission_tree/snapshot_streams/open")
    client.wait_for([opener])
    request = OpenSnapshotStream.Request()
    request.parameters.snapshot_period = math.inf  # on change only, as the watcher asks by default
    request.parameters.blackboard_data = True
    request.parameters.blackboard_activity = True
    topic = call(opener, request, timeout=2.0).topic_name
    assert topic == "/mission_tree/snapshot_streams/_snapshots_0"

    snapshots: list[BehaviourTree] = []
    lock = threading.Lock()

    def received(message: BehaviourTree) -> None:
        with lock:
            snapshots.append(message)

    node.create_subscription(BehaviourTree, topic, received, LATCHED)
    wait_until(lambda: bool(snapshots), 10.0, "the current snapshot, at once")
    # Now the mission can change mode, watched from the start; each transition takes 1.2 s, longer
    # than the pace of snapshots sent for feedback alone, so the stream shows each step.
    node_processes("pilot", "--transition-delay", "1.2")

    def change_mode() -> list[Behaviour]:
        with lock:
            return [b for s in snapshots for b in s.behaviours if b.name == "f_slow_mode"]

    wait_until(lambda: any(b.status == Behaviour.SUCCESS for b in change_mode()), 40.0, "f_slow_mode succeeded")
    time.sleep(0.3)
    with lock:
        seen = list(snapshots)
    names = {b.name for b in seen[-1].behaviours}
    assert {"Mission", "Modes", "Work", "f_slow_mode", "Hold on"} <= names
    ours = next(b for b in seen[-1].behaviours if b.name == "f_slow_mode")
    assert ours.class_name == "sm_bt.behaviours.change.ChangeMode"
    assert ours.additional_detail == "pilot f_slow_mode"
    assert ours.type == Behaviour.BEHAVIOUR and ours.status == Behaviour.SUCCESS
    holding = next(b for b in seen[-1].behaviours if b.name == "Hold on")
    assert holding.is_active and holding.status == Behaviour.RUNNING  # the path ticked last
    # Each step of the change reached the stream although the status stayed RUNNING.
    running = [b.message for b in change_mode() if b.status == Behaviour.RUNNING]
    assert len(set(running)) >= 2, running
    assert all(s.changed for s in seen), "period inf: only changed snapshots are sent"
    # Blackboard data on the visited path, as str(value): the whole story of the part.
    values = {kv.key: kv.value for kv in seen[-1].blackboard_on_visited_path}
    assert values["/system_modes/pilot"] == "active.f_slow_mode (target active.f_slow_mode)"
    assert any(item.key == "/system_modes/pilot" and item.activity_type == "WRITE"
               for s in seen for item in s.blackboard_activity)
    assert seen[-1].statistics.count > 0

    reconfigure = node.create_client(ReconfigureSnapshotStream, "/mission_tree/snapshot_streams/reconfigure")
    closer = node.create_client(CloseSnapshotStream, "/mission_tree/snapshot_streams/close")
    client.wait_for([reconfigure, closer])
    again = ReconfigureSnapshotStream.Request(topic_name=topic)
    again.parameters.snapshot_period = 0.2
    assert call(reconfigure, again, timeout=2.0).result
    with lock:
        before = len(snapshots)
    time.sleep(1.0)
    with lock:
        periodic = snapshots[before:]
    assert len(periodic) >= 2 and not all(s.changed for s in periodic), "a period sends unchanged snapshots too"
    assert call(closer, CloseSnapshotStream.Request(topic_name=topic), timeout=2.0).result
    assert not call(closer, CloseSnapshotStream.Request(topic_name=topic), timeout=2.0).result
    assert mission.poll() is None


class _Counting(py_trees.behaviour.Behaviour):
    """RUNNING with a feedback that changes on every tick (as one counting time does) until told
    to succeed."""

    def __init__(self) -> None:
        super().__init__("Counting")
        self.ticks = 0
        self.done = False

    def update(self) -> py_trees.common.Status:
        self.ticks += 1
        self.feedback_message = f"tick {self.ticks}"
        return py_trees.common.Status.SUCCESS if self.done else py_trees.common.Status.RUNNING


def test_feedback_alone_is_paced_and_a_status_change_goes_out_at_once(client: RosContext) -> None:
    from sm_bt.ros.snapshot_streams import FEEDBACK_INTERVAL, SnapshotStreams

    server = RosContext("paced_tree")
    counting = _Counting()
    tree = py_trees.trees.BehaviourTree(counting)
    streams = SnapshotStreams(server.node, tree)
    try:
        request = OpenSnapshotStream.Request()
        request.parameters.snapshot_period = math.inf
        topic = client.call(OpenSnapshotStream, "/paced_tree/snapshot_streams/open", request).topic_name
        snapshots: list[tuple[float, BehaviourTree]] = []
        client.node.create_subscription(BehaviourTree, topic, lambda m: snapshots.append((time.monotonic(), m)),
                                        LATCHED)
        wait_until(lambda: bool(snapshots), 10.0, "the current snapshot, at once")
        began, ticks = time.monotonic(), 0
        while time.monotonic() - began < 4 * FEEDBACK_INTERVAL:  # 50 Hz, a new feedback on every tick
            tree.tick()
            ticks += 1
            time.sleep(0.02)
        time.sleep(0.3)
        paced = [m for _, m in snapshots[1:]]
        assert ticks > 50 and 2 <= len(paced) <= 6, (ticks, len(paced))  # not one per tick
        assert all(m.changed for m in paced)
        shown = [b.message for b in paced[-1].behaviours if b.name == "Counting"]
        assert shown and shown[0] != "tick 1"  # the latest feedback, not the first held back
        counting.done = True
        tree.tick()  # RUNNING -> SUCCESS: sent although the last one went out just now
        finished = time.monotonic()
        wait_until(lambda: any(b.status == Behaviour.SUCCESS for _, m in snapshots for b in m.behaviours), 2.0,
                   "the status change")
        arrived = next(at for at, m in snapshots if any(b.status == Behaviour.SUCCESS for b in m.behaviours))
        assert arrived - finished < FEEDBACK_INTERVAL
    finally:
        streams.close()
        server.close()
