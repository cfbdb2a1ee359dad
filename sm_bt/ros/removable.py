"""Publishers and subscriptions that may be destroyed while another thread spins their node.

rclpy (Jazzy) gives every publisher and subscription QoS event handlers by default, and an executor
thread that lists an event handler just before another thread destroys it still adds it to its
wait set: ``InvalidHandle`` ends that thread. Its publishers and subscriptions themselves are
guarded. Created without the handlers, an entity can go at any moment (a stream closed by a viewer,
the manager's interface removed, a backend detached); the other side of a QoS mismatch still warns
(its handlers are its own).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def subscription(node: Any, kind: Any, topic: str, callback: Callable[[Any], None], qos: Any, *,
                 raw: bool = False) -> Any:
    """``node.create_subscription`` without event handlers (``raw``: the callback gets the
    serialised bytes)."""
    from rclpy.event_handler import SubscriptionEventCallbacks

    return node.create_subscription(kind, topic, callback, qos, raw=raw,
                                     event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))


def publisher(node: Any, kind: Any, topic: str, qos: Any) -> Any:
    """``node.create_publisher`` without event handlers."""
    from rclpy.event_handler import PublisherEventCallbacks

    return node.create_publisher(kind, topic, qos, event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))
