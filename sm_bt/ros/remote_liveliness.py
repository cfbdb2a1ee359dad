"""The liveliness of a fleet's robots: DDS's word that a robot's manager still runs and is reachable.

sm-bt manager's ``mode_event`` writers offer a liveliness lease (:data:`sm_bt.ros.manager_node.MODE_EVENT_LEASE`);
a fleet's :class:`~sm_bt.ros.remote_parts.RemoteBackend` subscribes to them asking for its liveness
window (:func:`liveliness_qos`) and hears from DDS itself, with no call answered by Python, when a
robot's manager stops or is cut off (:class:`Liveliness`).
"""

from __future__ import annotations

import contextlib
import logging
import threading
from typing import Any

from rclpy.duration import Duration
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from system_modes_msgs.msg import ModeEvent

log = logging.getLogger("sm_bt.ros.remote_liveliness")


def liveliness_qos(lease: float) -> QoSProfile:
    """What the fleet's liveliness subscription of a robot's ``mode_event`` asks for: a lease of
    ``lease`` s (a writer that offers a longer one, or none, does not match: it is told as a
    warning). Best effort and volatile: it matches any writer of the topic, and its messages are
    not the point (the events subscription reads them)."""
    return QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE,
                      liveliness=LivelinessPolicy.AUTOMATIC,
                      liveliness_lease_duration=Duration(nanoseconds=int(lease * 1e9)))


class Liveliness:
    """A node of the backend's own (in ``node``'s context and namespace) for the liveliness
    subscriptions, spun by a plain executor in a thread of its own: rclpy's EventsExecutor, which
    spins the backend's node, never calls their liveliness callbacks (rclpy 7.1.5 with
    rmw_fastrtps: it calls a subscription's matched callback, not its liveliness or incompatible
    QoS ones). Idle, the thread waits in the middleware and costs nothing; it wakes for a liveliness
    change, and for each message of the topics, taken raw and dropped (a robot's mode events: one a
    change; each wake costs about a millisecond of Python). A subscription kept out of the executor's
    wait with only its event handlers in would not do: Fast DDS's wait for an event also wakes while
    a message lies untaken, and the thread would spin. Subscribed before :meth:`start`;
    :meth:`close` stops the thread before anything is destroyed (an entity destroyed under a
    spinning executor ends its thread)."""

    def __init__(self, node: Node) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.node = rclpy.create_node(f"{node.get_name()}_liveliness", context=node.context,
                                      namespace=node.get_namespace(), start_parameter_services=False,
                                      use_global_arguments=False, enable_rosout=False)
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self.node)
        self._waker = self.node.create_guard_condition(lambda: None)
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="sm_bt-remote-liveliness", daemon=True)

    def subscribe(self, topic: str, qos: QoSProfile, callbacks: SubscriptionEventCallbacks) -> Any:
        """A subscription of ``topic`` (ModeEvent) for its liveliness only."""
        return self.node.create_subscription(ModeEvent, topic, _ignore, qos, event_callbacks=callbacks, raw=True)

    def start(self) -> None:
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):  # the context shut down under us
            while not self._stopping.is_set() and self.node.context.ok():
                try:
                    self._executor.spin_once()  # until something is ready: the waker ends the wait
                except ExternalShutdownException:
                    raise
                except Exception:  # a callback's error must not end the liveliness of every robot
                    log.exception("the liveliness thread's callback failed")

    def close(self) -> None:
        self._stopping.set()
        with contextlib.suppress(Exception):  # the context may be shut down already
            self._waker.trigger()
        if self._thread.is_alive():
            self._thread.join(3.0)
        for step in (lambda: self._executor.shutdown(timeout_sec=2.0),
                     lambda: self.node.destroy_guard_condition(self._waker), self.node.destroy_node):
            try:
                step()
            except Exception as error:  # the application may have shut the context down first
                log.debug("closing the liveliness node: %s", error)


def _ignore(message: Any) -> None:
    """The liveliness subscription's messages: read by the events subscription."""
