"""Publishers and subscriptions made by sm_bt.ros.removable may go while their node is spun.

The executor here plays the other thread: it destroys the entity at the worst moment, right after
listing it for its wait set. A publisher or subscription with rclpy's default event handlers ends
the spinning thread there (``InvalidHandle``); these must not.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from sm_bt.ros import removable

pytestmark = pytest.mark.ros


@pytest.fixture(name="node")
def node_fixture() -> Iterator[Any]:
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("sm_bt_removable_test", context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        context.try_shutdown()


def spin_destroying(node: Any, entity: Any, destroy: Callable[[Any], None]) -> bool:
    """One spin of ``node``'s executor that destroys ``entity`` just after it (or one of its event
    handlers) was listed; whether it was listed at all."""
    from rclpy.executors import SingleThreadedExecutor

    destroyed: list[Any] = []

    class DestroyingWhileListing(SingleThreadedExecutor):
        def can_execute(self, listed: Any) -> bool:
            # The last moment of its listing: its event handlers come after the entity itself.
            last = entity.event_handlers[0] if entity.event_handlers else entity
            if not destroyed and listed is last:
                destroyed.append(listed)
                destroy(entity)
            return bool(super().can_execute(listed))

    executor = DestroyingWhileListing(context=node.context)
    executor.add_node(node)
    try:
        executor.spin_once(timeout_sec=0.0)
    finally:
        executor.shutdown(timeout_sec=1.0)
    return bool(destroyed)


def test_a_publisher_destroyed_while_its_node_spins_does_not_end_the_spinning(node: Any) -> None:
    from std_msgs.msg import String

    publisher = removable.publisher(node, String, "/sm_bt_removable", 10)
    # Nothing of it is in an executor's wait set: there is no moment when destroying it is unsafe.
    assert not spin_destroying(node, publisher, node.destroy_publisher)
    node.destroy_publisher(publisher)
    assert not spin_destroying(node, publisher, node.destroy_publisher)
    assert publisher not in node.publishers


def test_a_subscription_destroyed_while_listed_does_not_end_the_spinning(node: Any) -> None:
    from std_msgs.msg import String

    subscription = removable.subscription(node, String, "/sm_bt_removable", lambda message: None, 10)
    assert spin_destroying(node, subscription, node.destroy_subscription)
    assert subscription not in node.subscriptions
