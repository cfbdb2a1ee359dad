"""Clean stops: the manager and the monitor end promptly on SIGINT, with no traceback, also while
calls are in flight (rclpy's Executor.shutdown() under a spinning thread once made the manager's
executor thread raise ``'NoneType' object has no attribute 'trigger'`` in about 1 stop in 12)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable

import pytest
from ros_processes import DUMPABLE, ManagerProcess, RosContext, Starter, communicate_or_dump, line_within, wait_until
from system_modes_msgs.srv import ChangeMode

pytestmark = pytest.mark.ros

STOPS = 4
#: SIGINT to exit.
PROMPT = 2.0


@pytest.mark.long
def test_the_manager_stops_cleanly_with_requests_in_flight(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter, ros_context: RosContext) -> None:
    node_processes("pilot")
    modes = ("f_normal_mode", "f_degraded_mode", "f_performance_mode")
    for attempt in range(STOPS):
        manager = start_manager().ready()
        # Its first line says who it can see: the settings these runs chose (never forced by it).
        wait_until(lambda: manager.lines("discovery:"), 2.0, "no discovery line")  # noqa: B023 (used at once)
        assert manager.lines("discovery:") == [
            f"discovery: ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, ROS_AUTOMATIC_DISCOVERY_RANGE="
            f"{os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}"], manager.stderr[:2000]
        client = ros_context.node.create_client(ChangeMode, "/pilot/change_mode")
        try:
            ros_context.wait_for([client])
            time.sleep(0.3 + 0.2 * attempt)  # the nodes found, or still being found
            future = client.call_async(ChangeMode.Request(mode_name=modes[attempt % len(modes)]))
            time.sleep(0.01 * attempt)  # stop while the change is under way
            assert manager.process is not None
            manager.process.send_signal(signal.SIGINT)
            sent = time.monotonic()
            code = manager.process.wait(PROMPT + 3.0)
            took = time.monotonic() - sent
            assert (code, "Traceback" in manager.stderr) == (0, False), manager.stderr[-3000:]
            assert took < PROMPT, f"stopped {took:.2f} s after SIGINT"
            future.cancel()
        finally:
            ros_context.node.destroy_client(client)


def test_the_monitor_stops_within_two_seconds_of_sigint(node_processes: Starter) -> None:
    node_processes("pilot")
    for args in (["--duration", "60"], ["--change", "pilot=configure", "--duration", "60"]):
        monitor = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "monitor", "pilot", "--ros", *args],
                                   stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   env={**os.environ, **DUMPABLE})
        try:
            # Its first line says it runs (the commands loaded, ROS up: a second or more on a busy
            # machine; a Ctrl-C before is told apart, tests/cli): then discovering, or watching.
            assert line_within(monitor.stdout, 30.0, "the monitor's first line"), monitor.communicate()
            time.sleep(0.5)
            assert monitor.poll() is None, monitor.communicate()
            monitor.send_signal(signal.SIGINT)
            sent = time.monotonic()
            _, err = communicate_or_dump(monitor, PROMPT + 3.0)
            took = time.monotonic() - sent
            assert took < PROMPT, f"stopped {took:.2f} s after SIGINT"
            assert "Traceback" not in err, err
            assert monitor.returncode == 130 and err.endswith("sm-bt: interrupted\n"), (monitor.returncode, err)
        finally:
            if monitor.poll() is None:
                monitor.kill()
                monitor.wait(5.0)
