"""py_trees_ros's blackboard-stream protocol (what ``py-trees-blackboard-watcher`` speaks), served by
:class:`~sm_bt.ros.blackboard_streams.BlackboardStreams` for a tree that keeps the parts' modes on
the blackboard; the client side uses rclpy and the interface types only."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import py_trees
import pytest
from model_files import bundled
from py_trees_ros_interfaces.srv import CloseBlackboardStream, GetBlackboardVariables, OpenBlackboardStream
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import RosContext, wait_until
from std_msgs.msg import String
from tree_helpers import fresh_blackboard

from sm_bt.behaviours import ModesToBlackboard
from sm_bt.ros.blackboard_streams import BlackboardStreams
from sm_bt.sim import SimulatedSystem

pytestmark = pytest.mark.ros

#: What py-trees-blackboard-watcher subscribes with: what went out before it matched never reaches it.
VOLATILE = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def test_a_watcher_lists_opens_reads_and_closes_streams_of_the_modes() -> None:
    rig = SimulatedSystem(bundled("pilot"), recovery=False)
    tree = rig.tree(py_trees.composites.Sequence("Root", memory=False, children=[ModesToBlackboard()]))
    server, client = RosContext("bb_tree"), RosContext("bb_watcher")
    streams = BlackboardStreams(server.node, tree)
    try:
        tree.tick()
        variables = client.call(GetBlackboardVariables, "/bb_tree/blackboard_streams/get_variables",
                                GetBlackboardVariables.Request()).variables
        assert "/system_modes/pilot" in variables and "/system_modes/pilot.mode" in variables
        assert "/system_modes/pilot.state_mode" in variables  # a property is a variable too

        request = OpenBlackboardStream.Request(variables=["/system_modes/pilot", "/system_modes/amcl.state"],
                                               filter_on_visited_path=False, with_activity_stream=True)
        topic = client.call(OpenBlackboardStream, "/bb_tree/blackboard_streams/open", request).topic
        assert topic == "/bb_tree/blackboard_streams/_watcher_0"
        received: list[str] = []
        lock = threading.Lock()

        def got(message: String) -> None:
            with lock:
                received.append(message.data)

        client.node.create_subscription(String, topic, got, VOLATILE)

        def ticked_and_received() -> bool:
            tree.tick()
            return bool(received)

        wait_until(ticked_and_received, 10.0, "the blackboard as it is, once the reader matched", poll=0.05)
        assert received[0].splitlines()[:2] == ["/system_modes/amcl.state: unconfigured",
                                                "/system_modes/pilot: unconfigured (no target)"]

        for _ in range(3):  # nothing changes: nothing is sent
            tree.tick()
        rig.manager.change_state("pilot", "configure")
        rig.run(2.0)
        tree.tick()
        wait_until(lambda: len(received) >= 2, 5.0, "the change")
        with lock:
            assert len(received) == 2, received
            latest = received[-1].splitlines()
        assert latest[:2] == ["/system_modes/amcl.state: inactive",
                              "/system_modes/pilot: inactive (target inactive)"]
        assert any(line.startswith("  WRITE: /system_modes/pilot by ") for line in latest)  # the tick's activity

        close = CloseBlackboardStream.Request(topic_name=topic)
        assert client.call(CloseBlackboardStream, "/bb_tree/blackboard_streams/close", close).result
        assert not client.call(CloseBlackboardStream, "/bb_tree/blackboard_streams/close", close).result
        assert py_trees.blackboard.Blackboard.activity_stream is None  # off again once nobody wants it
    finally:
        streams.close()
        client.close()
        server.close()
