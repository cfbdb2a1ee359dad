"""The ROS 2 side of ``sm-bt demo --ros``: the pilot's nodes in a child process, the manager on ROS.

:class:`RosPlatform` is what :class:`sm_bt.trees.pilot.demo.Demo` runs on with ``--ros``: the pilot's nodes as
real rclpy lifecycle nodes in a child :class:`~sm_bt.ros.node_process.NodesProcess`, an embedded
:class:`~sm_bt.ros.runtime.RosRuntime` that also serves the system_modes interface while the
demo runs, real time between ticks, and the laser failure as the node's ``sim.broken`` parameter
(set with a confirmed ``set_parameters`` call, so the node then fails by itself as the pilot's
laser_resender does).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from contextlib import ExitStack
from typing import Any

import py_trees

from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model, ParamValue
from sm_bt.ros.blackboard_streams import BlackboardStreams
from sm_bt.ros.environment import prepare, require_ros
from sm_bt.ros.node_process import NodesError, NodesProcess, sigterm_as_interrupt
from sm_bt.ros.runtime import MANAGER_NODE_NAME, RosRuntime
from sm_bt.ros.snapshot_streams import SnapshotStreams
from sm_bt.trees.pilot.world import World

DISCOVERY_TIMEOUT = 15.0  # until the manager reaches every node
CALL_TIMEOUT = 5.0  # every service call of the backend
TICK = 0.02  # wall seconds between ticks of the tree
#: The backend's options: short enough that a dead node process shows quickly.
BACKEND_OPTIONS: dict[str, Any] = {"call_timeout": CALL_TIMEOUT, "acquire_timeout": 2.0, "liveness_timeout": 2.0}
BROKEN = "sim.broken"  # sm_bt.ros.sim_nodes.BROKEN (not imported: that module starts rclpy's C side)


class RosPlatform:
    """The demo's platform on ROS 2 (see :class:`sm_bt.trees.pilot.demo.Platform`).

    Starts ``model``'s nodes in a child process (``model_name`` is what the child loads: a file or
    a bundled model's name), the runtime (manager with ``manager_options``), waits until the
    manager reaches every node, and gives them ``initial_parameters`` ({node: {name: value}}).
    World time runs ``world.time_scale`` times faster than the wall clock the manager uses.
    ``say`` tells the user what it is doing. Anything that fails on the way stops what was started.
    """

    time_unit = "wall"
    description = "ROS 2 lifecycle nodes"

    def __init__(self, model: Model, model_name: str, world: World, *, manager_options: Mapping[str, Any],
                 initial_parameters: Mapping[str, Mapping[str, ParamValue]], laser: str = "laser_resender",
                 node_name: str = MANAGER_NODE_NAME, tick: float = TICK,
                 say: Callable[[str], None] | None = None) -> None:
        self.world = world
        self.laser = laser
        self.tick = tick
        self._say = say or (lambda text: None)
        self._closed = False
        self._streams: tuple[SnapshotStreams, BlackboardStreams] | None = None
        with ExitStack() as stack:
            stack.enter_context(sigterm_as_interrupt())
            # The child inherits the environment: local discovery, and a domain id of this run's own
            # unless the user chose one.
            prepare(own_domain=True)
            require_ros()
            self.nodes = NodesProcess(model_name)
            stack.callback(self.nodes.stop)
            started = time.monotonic()
            names = self.nodes.start().names
            self._say(f"node process {self.nodes.pid} READY after {time.monotonic() - started:.1f} s: "
                      f"{', '.join(names)}")
            self.runtime = RosRuntime(model, node_name=node_name, serve=True, own_domain=True,
                                      manager_options=manager_options, backend_options=BACKEND_OPTIONS)
            stack.callback(self.runtime.close)
            self.manager: ModeManager = self.runtime.manager
            self.clock = self.runtime.clock
            self._wait_for_nodes(model, time.monotonic())
            for node, values in initial_parameters.items():
                self.set_parameters(node, values)
            self._wait_for_parameters(initial_parameters)
            self._say(f"manager {node_name} reaches every node; initial parameters set "
                      f"({time.monotonic() - started:.1f} s)")
            self._stop = stack.pop_all()  # kept running; close() unwinds it

    # -- set-up -------------------------------------------------------------------------------------

    def _wait_for_nodes(self, model: Model, since: float) -> None:
        names = [node.name for node in model.nodes]
        while True:
            missing = [name for name in names if not self.manager.observation(name).reachable]
            if not missing:
                return
            self.nodes.check()
            if time.monotonic() - since > DISCOVERY_TIMEOUT:
                raise NodesError(f"the manager did not reach {', '.join(missing)} within {DISCOVERY_TIMEOUT:.0f} s")
            time.sleep(0.02)

    def _wait_for_parameters(self, expected: Mapping[str, Mapping[str, ParamValue]]) -> None:
        """Until the manager has seen the parameter events (the actions read its observations)."""
        deadline = time.monotonic() + CALL_TIMEOUT
        while True:
            stale = [f"{node}.{name}" for node, values in expected.items() for name, value in values.items()
                     if self.manager.observation(node).parameters.get(name) != value]
            if not stale:
                return
            if time.monotonic() > deadline:
                raise NodesError(f"the manager did not see the new values of {', '.join(stale)}")
            time.sleep(0.02)

    def set_parameters(self, node: str, values: Mapping[str, ParamValue]) -> None:
        """Set parameters of ``node`` directly (not as a mode); they must be accepted."""
        # The backend answers within its call timeout; the margin only guards against a bug.
        result = self.runtime.set_parameters(node, values, timeout=CALL_TIMEOUT + 2.0)
        if not result.ok:
            raise NodesError(result.reason)

    # -- the Platform protocol ----------------------------------------------------------------------

    def advance(self, seconds: float) -> None:
        """Let ``seconds`` of real time pass (the nodes and the manager live in it)."""
        self.nodes.check()
        time.sleep(seconds)

    def break_laser(self) -> None:
        self.world.laser_ok = False
        self.set_parameters(self.laser, {BROKEN: True})

    def repair_laser(self) -> None:
        self.set_parameters(self.laser, {BROKEN: False})
        self.world.laser_ok = True

    def serve(self, tree: py_trees.trees.BehaviourTree) -> None:
        """Serve ``tree``'s snapshot and blackboard streams on the manager's node (py-trees-tree-watcher,
        py-trees-blackboard-watcher)."""
        self._streams = (SnapshotStreams(self.runtime.node, tree), BlackboardStreams(self.runtime.node, tree))
        name = self.runtime.node.get_fully_qualified_name()
        self._say(f"tree snapshot and blackboard streams on {name}/snapshot_streams and {name}/blackboard_streams "
                  "(py-trees-tree-watcher, py-trees-blackboard-watcher)")

    def close(self) -> None:
        """Close the runtime, then stop the node process (SIGINT, then SIGKILL); idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            for streams in self._streams or ():
                streams.close()
        finally:  # the runtime and the node process stop whatever happened above
            self._close_runtime_and_nodes()

    def _close_runtime_and_nodes(self) -> None:
        self._stop.close()
