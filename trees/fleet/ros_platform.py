"""The ROS 2 side of ``sm-bt demo --fleet --ros``: two robots as real processes, the fleet's manager on ROS.

Each robot is the pilot's four simulated lifecycle nodes (``sm-bt sim-nodes pilot --namespace /robotK
--state inactive``) and its own ``sm-bt manager pilot --namespace /robotK``, two child processes; the
fleet's manager is an embedded :class:`~sm_bt.ros.runtime.RosRuntime` over the bundled ``fleet`` model
(its remote parts name ``/robot1`` and ``/robot2``), serving ``/fleet``'s system_modes interface while
the demo runs. On one machine nothing can cut a robot's network, so the cut freezes the robot's
manager process (SIGSTOP: the fleet hears nothing from it, as from a robot behind a partition,
while its nodes go on) and the heal lets it go on (SIGCONT). ``make stress`` cuts real links
(tests/e2e/stress_fleet_hosts.py).
"""

from __future__ import annotations

import functools
import os
import signal
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from typing import Any

from sm_bt.bundled import path as bundled_model
from sm_bt.engine.manager import ModeManager
from sm_bt.model.errors import Error
from sm_bt.model.loader import load_model
from sm_bt.ros.client import ModeClient, Outcome, follow_outcomes
from sm_bt.ros.environment import prepare, require_ros
from sm_bt.ros.node_process import ManagerProcess, NodesError, NodesProcess, sigterm_as_interrupt
from sm_bt.ros.runtime import RosRuntime
from sm_bt.trees.fleet.platforms import ROBOT_MODEL, ROBOTS, RobotTeller

#: Seconds until the fleet has read both robots (their processes start at once, on a loaded machine).
DISCOVERY_TIMEOUT = 30.0
#: Seconds one question to a robot's own manager may take.
CALL_TIMEOUT = 2.0
#: The fleet's node.
FLEET_NODE = "fleet_manager"


class RosFleet:
    """The fleet's platform on ROS 2 (see :class:`~sm_bt.trees.fleet.platforms.FleetPlatform`); ``say`` tells
    what it starts. Anything that fails on the way stops what was started."""

    description = "real ROS 2 processes (each robot: its pilot nodes and its own sm-bt manager)"
    time_unit = "wall"

    def __init__(self, say: Callable[[str], None] | None = None) -> None:
        say = say or (lambda text: None)
        self.robots = list(ROBOTS)
        self._closed = False
        self._began = time.monotonic()
        with ExitStack() as stack:
            stack.enter_context(sigterm_as_interrupt())  # kept until close(): the robots stop then too
            # The children inherit the environment: local discovery, a domain id of this run's own unless
            # the user chose one.
            prepare(own_domain=True)
            require_ros()
            self._nodes = {robot: NodesProcess(ROBOT_MODEL, "--namespace", f"/{robot}", "--state", "inactive")
                           for robot in self.robots}
            self._managers = {robot: ManagerProcess(ROBOT_MODEL, "--namespace", f"/{robot}", "--log-level",
                                                    "warning") for robot in self.robots}
            processes = self.processes
            stack.callback(self._stop_processes)
            with ThreadPoolExecutor(len(processes)) as pool:  # all at once: each takes seconds
                list(pool.map(lambda process: process.start(), processes))
            started = [f"{robot} (nodes pid {self._nodes[robot].pid}, manager pid {self._managers[robot].pid})"
                       for robot in self.robots]
            say(f"robots started: {', '.join(started)}")
            self.runtime = RosRuntime(load_model(bundled_model("fleet")), node_name=FLEET_NODE, own_domain=True)
            stack.callback(self.runtime.close)
            self.manager: ModeManager = self.runtime.manager
            self._wait_for_robots()
            say(f"the fleet's manager {FLEET_NODE} has read {', '.join(self.robots)} "
                f"({time.monotonic() - self._began:.1f} s)")
            # The robots' own managers are asked by a node of its own in the runtime's context (spun in its calls).
            self._asking = ModeClient(timeout=CALL_TIMEOUT, node_name="fleet_demo_robots", context=self.runtime.context)
            stack.callback(self._asking.close)
            self._subscriptions: list[Any] = []
            self._began = time.monotonic()
            self._stop = stack.pop_all()  # kept running; close() unwinds it

    def _wait_for_robots(self) -> None:
        deadline = time.monotonic() + DISCOVERY_TIMEOUT
        while not all(self.manager.actual(robot).known for robot in self.robots):
            for process in self.processes:
                process.check()
            if time.monotonic() > deadline:
                unread = [f"{robot} ({self.manager.observation(robot).gone or 'never read'})"
                          for robot in self.robots if not self.manager.actual(robot).known]
                raise NodesError(f"the fleet did not read {', '.join(unread)} within {DISCOVERY_TIMEOUT:.0f} s")
            time.sleep(0.05)

    @property
    def processes(self) -> list[NodesProcess]:
        """The robots' processes: each robot's nodes and its manager."""
        return [*self._nodes.values(), *self._managers.values()]

    # -- the FleetPlatform protocol --------------------------------------------------------------------

    def now(self) -> float:
        return time.monotonic() - self._began

    def advance(self, seconds: float) -> None:
        for process in self.processes:
            process.check()
        time.sleep(seconds)

    def follow_robots(self, tell: RobotTeller) -> None:
        """Each robot's requests as they end (its manager's ``request_outcome``)."""

        def told(robot: str, ended: Outcome) -> None:
            reason = f": {ended.reason}" if ended.reason else ""
            tell(robot, f"request #{ended.request} {ended.description} [{ended.requester}] {ended.outcome}{reason}",
                 ended.outcome == "succeeded")

        for robot in self.robots:
            self._subscriptions.append(follow_outcomes(self.runtime.node, f"{robot}/{ROBOT_MODEL}",
                                                       functools.partial(told, robot)))

    def cut(self, robot: str) -> str:
        os.kill(self._pid(robot), signal.SIGSTOP)
        return (f"{robot}'s manager is frozen (SIGSTOP): the fleet hears nothing from it, as from a robot cut off "
                "(its nodes go on)")

    def heal(self, robot: str) -> str:
        os.kill(self._pid(robot), signal.SIGCONT)
        return f"{robot}'s manager goes on (SIGCONT)"

    def robot_view(self, robot: str) -> str:
        part = f"{robot}/{ROBOT_MODEL}"
        try:
            state = self._asking.get_state(part)
            return f"active.{self._asking.get_mode(part)}" if state == "active" else state
        except Error as error:  # out of reach: said, not raised (the summary tells it)
            return f"not known ({error})"

    def close(self) -> None:
        """Close the fleet's runtime, then stop the robots' processes (SIGCONT, SIGINT, then SIGKILL)."""
        if self._closed:
            return
        self._closed = True
        for subscription in self._subscriptions:
            self.runtime.node.destroy_subscription(subscription)
        self._stop.close()

    # -- helpers ------------------------------------------------------------------------------------

    def _pid(self, robot: str) -> int:
        pid = self._managers[robot].pid
        if pid is None:
            raise NodesError(f"the manager of {robot} is not running")
        return pid

    def _stop_processes(self) -> None:
        processes = self.processes
        for process in self._managers.values():  # one may be frozen
            if process.alive and process.pid is not None:
                os.kill(process.pid, signal.SIGCONT)
        with ThreadPoolExecutor(len(processes)) as pool:
            list(pool.map(lambda process: process.stop(), processes))
