"""The manager's topics over real rclpy, as a property: in any interleaving of subscriptions
(volatile or latched) and mode changes, a subscriber never hears of a change from before it
subscribed, a latched one's first message is the value at that moment (and only that one is
older than the subscription), and every stamp is the time of its change.

The manager runs on simulated nodes (:class:`SimulatedSystem`, virtual time: a change is done in
microseconds) and serves its topics on a real rclpy node; the subscribers are a client of their
own (another context: another DDS participant, as another process would be).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from lifecycle_msgs.msg import TransitionEvent
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_processes import RosContext, wait_until
from system_modes_msgs.msg import ModeEvent
from system_modes_msgs.srv import ChangeMode

from sm_bt.ros import removable
from sm_bt.ros.manager_node import ModeManagerServer
from sm_bt.sim import SimulatedSystem

pytestmark = pytest.mark.ros

MODES = ("__DEFAULT__", "f_normal_mode", "f_degraded_mode", "f_performance_mode")
#: (topic, message type, what its goal says): the system's mode and state, and a node's mode.
TOPICS = (("/pilot/mode_event", ModeEvent, "pilot mode"), ("/pilot/transition_event", TransitionEvent, "pilot state"),
          ("/amcl/mode_event", ModeEvent, "amcl mode"))
DURABILITY = {"volatile": DurabilityPolicy.VOLATILE, "latched": DurabilityPolicy.TRANSIENT_LOCAL}


@dataclass
class Reader:
    topic: str
    what: str
    durability: str
    since: int  # time.time_ns() just before it subscribed
    current: str | None  # what the topic's value was then (None: nothing published yet)
    received: list[Any] = field(default_factory=list)


@dataclass
class World:
    system: SimulatedSystem
    server: ModeManagerServer
    serving: RosContext
    client: RosContext


@pytest.fixture(scope="module")
def world() -> Iterator[World]:
    serving, client = RosContext("sm_bt_topics_server"), RosContext("sm_bt_topics_client")
    system = SimulatedSystem("pilot", transition_delay=0.0, parameter_delay=0.0, recovery=False)
    server = ModeManagerServer(serving.node, system.manager)
    try:
        yield World(system, server, serving, client)
    finally:
        server.close()
        system.close()
        client.close()
        serving.close()


def _value(world: World, what: str) -> str | None:
    """What the topic's latest message says now (its goal), None while it has said nothing."""
    part, kind = what.split()
    actual = world.system.manager.actual(part)
    if kind == "state":
        return actual.state.label
    return world.server._modes.get(part)  # the last mode it published


def _goal(message: Any) -> str:
    return message.goal_mode.label if isinstance(message, ModeEvent) else message.goal_state.label


actions = st.lists(st.one_of(
    st.tuples(st.just("subscribe"), st.integers(0, len(TOPICS) - 1), st.sampled_from(sorted(DURABILITY))),
    st.tuples(st.just("change"), st.sampled_from(MODES), st.just("")),
), min_size=1, max_size=6)


@pytest.mark.long
@examples(100, stress=10_000)
@given(plan=actions)
def test_subscribers_hear_only_what_is_true_when_they_hear_it(world: World, plan: list[tuple[str, Any, str]]) -> None:
    readers: list[Reader] = []
    subscriptions = []
    try:
        for kind, what, durability in plan:
            if kind == "change":
                request = world.system.finish(world.system.manager.change_mode("pilot", what))
                assert request.succeeded, request.reason
                continue
            topic, message_type, meaning = TOPICS[what]
            qos = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE, durability=DURABILITY[durability])
            reader = Reader(topic, meaning, durability, time.time_ns(), _value(world, meaning))
            # Without QoS event handlers: it is destroyed below while the context's thread spins.
            subscriptions.append(removable.subscription(world.client.node, message_type, topic,
                                                        reader.received.append, qos))
            readers.append(reader)
            wait_until(lambda: subscriptions[-1].get_publisher_count() > 0, 10.0, f"{topic} never matched")
            if durability == "latched" and reader.current is not None:
                wait_until(lambda: reader.received, 5.0, f"a latched reader of {topic} got no value")  # noqa: B023
        time.sleep(0.1)  # what is on its way arrives
        for reader in readers:
            older = [m for m in reader.received if m.timestamp < reader.since]
            name = f"{reader.durability} reader of {reader.topic}"
            if reader.durability == "volatile":
                assert older == [], f"{name} heard {[_goal(m) for m in older]} from before it subscribed"
            else:
                assert len(older) <= 1 and reader.received[:len(older)] == older, \
                    f"{name} heard {[_goal(m) for m in older]} from before it subscribed"
                if reader.current is not None:
                    assert reader.received and _goal(reader.received[0]) == reader.current, \
                        f"{name}'s first message says {_goal(reader.received[0])}, not {reader.current}"
            stamps = [m.timestamp for m in reader.received]
            assert stamps == sorted(stamps) and all(stamp <= time.time_ns() for stamp in stamps)
    finally:
        for subscription in subscriptions:
            world.client.node.destroy_subscription(subscription)


def test_a_request_taken_the_moment_its_service_exists_is_told_on_the_topics(monkeypatch: pytest.MonkeyPatch) -> None:
    """Seen in a full run: a client's ``change_mode``, answered while the manager was still making
    its interface (seconds under load), was never told on ``mode_request_info``: the services came
    before the topics and the manager's subscription. Here the request waits for the service and
    is taken the moment it exists."""
    serving, client = RosContext("sm_bt_first_request_server"), RosContext("sm_bt_first_request_client")
    system = SimulatedSystem("pilot", transition_delay=0.0, parameter_delay=0.0, recovery=False)
    heard: list[Any] = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    client.node.create_subscription(ModeEvent, "/pilot/mode_request_info", heard.append, latched)
    answers: list[bool] = []
    create_service = serving.node.create_service

    def taken_at_once(kind: Any, name: str, callback: Any, **options: Any) -> Any:
        made = create_service(kind, name, callback, **options)
        if name == "/pilot/change_mode":
            answers.append(callback(ChangeMode.Request(mode_name="f_normal_mode"), ChangeMode.Response()).success)
        return made

    monkeypatch.setattr(serving.node, "create_service", taken_at_once)
    server = ModeManagerServer(serving.node, system.manager)
    try:
        assert answers == [True]
        wait_until(lambda: any(m.goal_mode.label == "f_normal_mode" for m in heard), 10.0,
                   "the request was never told on /pilot/mode_request_info")
    finally:
        server.close()
        system.close()
        client.close()
        serving.close()
