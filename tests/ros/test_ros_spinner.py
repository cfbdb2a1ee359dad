"""The runtime's executor threads over an EventsExecutor: entities of the node may come and go
from other threads while it waits (never blocked, and served at once), one wait serves a burst of
messages, a stop ends the wait at once, a callback that raises is logged and the spinning goes on,
and the runtime spins the backend's node with one."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from ros_processes import wait_until

from sm_bt.ros.runtime import EVENTS_WAIT, RosRuntime, _events_executor, _Spinner

pytestmark = pytest.mark.ros


class _CountingExecutor:
    """An executor whose waits are counted (everything else is the executor's own)."""

    def __init__(self, executor: Any) -> None:
        self._executor = executor
        self.waits = 0

    def spin_until_future_complete(self, *args: Any, **kwargs: Any) -> None:
        self.waits += 1
        self._executor.spin_until_future_complete(*args, **kwargs)

    def spin_once(self, *args: Any, **kwargs: Any) -> None:
        self.waits += 1
        self._executor.spin_once(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._executor, name)


@pytest.fixture
def spun() -> Iterator[tuple[Any, _Spinner]]:
    """A node of a context of its own, spun by an EventsExecutor's spinner."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("sm_bt_spinner_test", context=context, start_parameter_services=False)
    executor = _events_executor(context)
    assert executor is not None, "the pinned rclpy has an EventsExecutor"
    executor.add_node(node)
    spinner = _Spinner(_CountingExecutor(executor), node, "test", context)
    try:
        yield node, spinner
    finally:
        spinner.stop()
        spinner.remove_waker()
        executor.shutdown(timeout_sec=2.0)
        node.destroy_node()
        context.try_shutdown()


def test_entities_come_and_go_from_another_thread_during_a_wait_and_are_served_at_once(
        spun: tuple[Any, _Spinner]) -> None:
    from std_msgs.msg import String

    node, _ = spun
    publisher = node.create_publisher(String, "/sm_bt_spinner_test/chatter", 10)
    for round_ in range(3):
        time.sleep(0.2)  # inside a wait of the spinner now
        received: list[str] = []
        began = time.monotonic()
        subscription = node.create_subscription(String, "/sm_bt_spinner_test/chatter",
                                                lambda m, received=received: received.append(m.data), 10)
        took = time.monotonic() - began
        assert took < EVENTS_WAIT / 4, f"creating a subscription took {took:.3f} s"
        wait_until(lambda subscription=subscription: subscription.get_publisher_count() > 0, 5.0, "not matched")
        sent = time.monotonic()
        publisher.publish(String(data=f"round {round_}"))
        wait_until(lambda received=received: bool(received), 2.0, "the new subscription was not served")
        assert time.monotonic() - sent < EVENTS_WAIT / 2, "served only after the wait ended"
        began = time.monotonic()
        node.destroy_subscription(subscription)
        assert time.monotonic() - began < EVENTS_WAIT / 4


def test_one_wait_serves_a_burst_of_messages(spun: tuple[Any, _Spinner]) -> None:
    # A wait per message costs a set-up and a trip through the interpreter's lock each: a burst of
    # answers (one per node of a change) then queues behind itself (docs/performance.md, P2).
    from std_msgs.msg import String

    node, spinner = spun
    received: list[str] = []
    publisher = node.create_publisher(String, "/sm_bt_spinner_test/burst", 200)
    subscription = node.create_subscription(String, "/sm_bt_spinner_test/burst",
                                            lambda m: received.append(m.data), 200)
    wait_until(lambda: subscription.get_publisher_count() > 0, 5.0, "not matched")
    time.sleep(0.1)
    before = spinner.executor.waits
    for index in range(100):
        publisher.publish(String(data=str(index)))
    wait_until(lambda: len(received) == 100, 5.0, "the burst was not served")
    assert received == [str(index) for index in range(100)]
    assert spinner.executor.waits - before <= 3, f"{spinner.executor.waits - before} waits for 100 messages"


def test_a_stop_ends_the_wait_at_once(spun: tuple[Any, _Spinner]) -> None:
    _, spinner = spun
    time.sleep(0.2)
    began = time.monotonic()
    spinner.stop()
    assert not spinner._thread.is_alive()
    assert time.monotonic() - began < EVENTS_WAIT / 4


def test_the_runtime_spins_the_backends_and_watching_nodes_with_events_executors_and_stops_at_once() -> None:
    from model_files import bundled

    ros = RosRuntime(bundled("pilot"), node_name="sm_bt_spinner_runtime", serve=False,
                     manager_options={"rules": False, "recovery": False})
    plain = RosRuntime(bundled("pilot"), node_name="sm_bt_spinner_plain", serve=False, events_executor=False,
                       manager_options={"rules": False, "recovery": False})
    try:
        assert not hasattr(ros.backend_executor, "wait_for_ready_callbacks"), "an EventsExecutor"
        assert not hasattr(ros.watch_executor, "wait_for_ready_callbacks"), "an EventsExecutor"
        assert hasattr(plain.backend_executor, "wait_for_ready_callbacks"), "rclpy's plain executor"
        time.sleep(0.2)
    finally:
        began = time.monotonic()
        ros.close()
        took = time.monotonic() - began
        plain.close()
    assert took < EVENTS_WAIT / 2, f"close() took {took:.2f} s"


def test_a_callback_that_raises_is_logged_and_the_spinning_goes_on(spun: tuple[Any, _Spinner],
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    """Out of an EventsExecutor's wait, what a timer's or a subscription's callback raised would end
    the thread: the manager deaf to its nodes and clients from then on."""
    from std_msgs.msg import String

    node, _ = spun
    heard: list[str] = []

    def hear(message: String) -> None:
        heard.append(message.data)
        if message.data == "bad":
            raise ValueError("a bug in the callback")

    node.create_subscription(String, "/spun_chatter", hear, 10)
    publisher = node.create_publisher(String, "/spun_chatter", 10)
    wait_until(lambda: publisher.get_subscription_count() == 1, 5.0, "the subscription never matched")
    with caplog.at_level("ERROR", logger="sm_bt.ros.runtime"):
        publisher.publish(String(data="bad"))
        wait_until(lambda: heard == ["bad"], 5.0, "the first message never heard")
        time.sleep(0.2)
        publisher.publish(String(data="good"))
        wait_until(lambda: heard == ["bad", "good"], 5.0, f"nothing heard after the callback raised: {heard}")
    assert any("a callback failed" in record.getMessage() and record.exc_info for record in caplog.records), \
        caplog.records


def test_spun_says_whether_a_callback_raised_and_lets_the_contexts_shutdown_through(
        caplog: pytest.LogCaptureFixture) -> None:
    from rclpy.executors import ExternalShutdownException

    from sm_bt.ros.runtime import spun

    def raising(error: BaseException) -> Any:
        def spin() -> None:
            raise error
        return spin

    assert spun(lambda: None, "quiet") is True
    with caplog.at_level("ERROR", logger="sm_bt.ros.runtime"):
        assert spun(raising(KeyError("a bug")), "sm_bt-mission-spin") is False
    assert [record.getMessage() for record in caplog.records] == ["sm_bt-mission-spin: a callback failed"]
    with pytest.raises(ExternalShutdownException):
        spun(raising(ExternalShutdownException()), "shut down")
