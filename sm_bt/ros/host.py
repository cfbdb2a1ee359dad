"""Host a mission tree on ROS 2: one node, the manager embedded, the tree ticked at a rate.

As a program (``sm-bt-mission``, e.g. from a launch file), configured with ROS parameters::

    sm-bt-mission --ros-args -p model:=robot.yaml -p tree:=mission.xml -p rate:=10.0

    # launch file
    ExecuteProcess(cmd=["sm-bt-mission", "--ros-args", "-p", "model:=/path/robot.yaml",
                        "-p", "tree:=/path/mission.xml", "-r", "__node:=mission"])

Parameters: ``model`` (an SMH model file, or a bundled model's name), ``tree`` (a tree file,
``.xml``, or ``package.module:function`` returning the root), ``rate`` (ticks per second, default
10), ``wait_for_nodes`` (seconds to wait for the model's nodes before the first tick, default 10;
0 starts at once). The node (``sm_bt_mission`` unless remapped) serves the system_modes interface
of the model's parts; the process has one DDS participant. The tree runs until its root succeeds
or fails (exit status 0 or 1) or the process gets SIGINT/SIGTERM (0). Discovery and the domain
are the user's (``ROS_DOMAIN_ID``, ``ROS_AUTOMATIC_DISCOVERY_RANGE``), so nodes may be on other
machines. One log line per change of the root's status and per mode or state a system reaches.

From Python, :class:`MissionHost` does the same with objects::

    host = MissionHost(load_model("robot.yaml"), load_tree("mission.xml"), node=my_node)
    status = host.run()
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.manager_access import attach_manager
from sm_bt.engine.events import Event, EventKind
from sm_bt.model.errors import Error, ModelError
from sm_bt.model.types import Model, SystemPart
from sm_bt.ros.snapshot_streams import SnapshotStreams

log = logging.getLogger("sm_bt.ros.host")

NODE_NAME = "sm_bt_mission"


class HostError(Error, RuntimeError):
    """The host cannot start: a parameter, the model or the tree is wrong (the message says how)."""


class MissionHost:
    """Tick ``root`` at ``rate`` Hz with a :class:`~sm_bt.ros.runtime.RosRuntime` on ``node``.

    The runtime serves the interface on ``node`` and joins its context; the host spins ``node``
    in a thread of its own unless ``spin=False`` (the application spins it). ``setup`` kwargs go
    to ``tree.setup`` (the manager is attached to the tree, not passed there).
    """

    def __init__(self, model: Model, root: py_trees.behaviour.Behaviour, node: Any, *, rate: float = 10.0,
                 spin: bool = True, runtime_options: dict[str, Any] | None = None,
                 setup: dict[str, Any] | None = None) -> None:
        from rclpy.executors import SingleThreadedExecutor

        from sm_bt.ros.runtime import RosRuntime

        if not rate > 0:
            raise HostError(f"rate must be more than 0 ticks per second, not {rate}")
        self.period = 1.0 / rate
        self.node = node
        self.runtime = RosRuntime(model, node=node, **(runtime_options or {}))
        self.manager = self.runtime.manager
        self._executor: Any = None
        self._thread: threading.Thread | None = None
        if spin:
            self._executor = SingleThreadedExecutor(context=node.context)
            self._executor.add_node(node)
            self._thread = threading.Thread(target=self._spin, name="sm_bt-mission-spin", daemon=True)
            self._thread.start()
        self.tree = py_trees.trees.BehaviourTree(attach_manager(root, self.manager))
        self.tree.setup(**(setup or {}))
        self.streams = SnapshotStreams(node, self.tree)
        self._shown: dict[str, str] = {}
        self._subscription = self.manager.subscribe(self._on_event, kinds=(EventKind.ACTUAL,))
        self._stop = threading.Event()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):  # the context was shut down under us
            self._executor.spin()

    def _on_event(self, event: Event) -> None:
        if isinstance(self.manager.model.parts[event.part], SystemPart) and event.actual is not None \
                and event.actual.known:
            shown = str(event.actual)
            if self._shown.get(event.part) != shown:  # not again for a new reason only
                self._shown[event.part] = shown
                log.info("%s is %s", event.part, shown)

    def wait_for_nodes(self, timeout: float) -> None:
        """Until the model's nodes are reachable; :class:`HostError` naming the others."""
        try:
            self.runtime.wait_for_nodes(timeout)
        except TimeoutError as error:
            raise HostError(str(error)) from None

    def stop(self) -> None:
        """Make :meth:`run` return after the tick in progress (from any thread or a signal)."""
        self._stop.set()

    def run(self, limit: float | None = None) -> Status:
        """Tick every period until the root succeeds or fails, :meth:`stop`, or ``limit``
        seconds; returns the root's last status."""
        began = time.monotonic()
        shown = Status.INVALID
        next_tick = time.monotonic()
        while not self._stop.is_set():
            self.tree.tick()
            status = self.tree.root.status
            if status is not shown:
                log.info("mission %s: %s", status.value, self.tree.root.feedback_message or self.tree.root.name)
                shown = status
            if status in (Status.SUCCESS, Status.FAILURE):
                return status
            if limit is not None and time.monotonic() - began >= limit:
                break
            next_tick += self.period
            self._stop.wait(max(0.0, next_tick - time.monotonic()))
        return self.tree.root.status

    def close(self) -> None:
        """Shut the tree down (every behaviour's ``shutdown``), then the runtime, then the spin
        thread; the node and its context are the caller's."""
        try:
            self._subscription.cancel()
            self.streams.close()
            self.tree.shutdown()
            self.tree.interrupt()
        finally:  # ROS is released whatever a behaviour's shutdown did
            self.runtime.close()
            if self._executor is not None:
                self._executor.shutdown(timeout_sec=2.0)
            if self._thread is not None:
                self._thread.join(3.0)


def load_root(spec: str, model: Model) -> py_trees.behaviour.Behaviour:
    """The tree ``spec`` names: a tree file (``.xml``, checked against ``model``) or
    ``package.module:function`` (called with no arguments)."""
    if spec.endswith(".xml"):
        from sm_bt.trees.mission_xml import TreeFileError, load_tree

        try:
            return load_tree(spec, model=model)
        except TreeFileError as error:
            raise HostError(f"the tree file has mistakes:\n{error}") from None
    module_name, _, function = spec.partition(":")
    if not module_name or not function:
        raise HostError(f"tree must be a .xml file or package.module:function, not {spec!r}")
    try:
        factory = getattr(importlib.import_module(module_name), function)
    except (ImportError, AttributeError) as error:
        raise HostError(f"cannot load the tree {spec!r}: {error}") from None
    root = factory()
    if not isinstance(root, py_trees.behaviour.Behaviour):
        raise HostError(f"{spec} returned {type(root).__name__}, not a py_trees behaviour")
    return root


def _parameters(node: Any) -> tuple[str, str, float, float]:
    from rcl_interfaces.msg import ParameterDescriptor

    def declare(name: str, default: Any, description: str) -> Any:
        return node.declare_parameter(name, default, ParameterDescriptor(description=description)).value

    model = declare("model", "", "SMH model file, or a bundled model's name")
    tree = declare("tree", "", "mission tree: a .xml file or package.module:function")
    rate = declare("rate", 10.0, "ticks per second")
    wait = declare("wait_for_nodes", 10.0, "seconds to wait for the model's nodes (0: do not wait)")
    if not model or not tree:
        missing = " and ".join(name for name, value in (("model", model), ("tree", tree)) if not value)
        raise HostError(f"set the {missing} parameter: sm-bt-mission --ros-args -p model:=robot.yaml "
                        "-p tree:=mission.xml")
    return str(model), str(tree), float(rate), float(wait)


def _load_model(name: str) -> Model:
    from sm_bt.bundled import names as bundled_names
    from sm_bt.bundled import path as bundled_path
    from sm_bt.model.loader import load_model

    path = Path(name)
    if not path.exists():
        if name not in bundled_names():
            raise HostError(f"no model file {name} (nor a bundled model: {', '.join(bundled_names())})")
        path = bundled_path(name)
    try:
        return load_model(path)
    except ModelError as error:
        raise HostError(f"the model has mistakes:\n{error}") from None


def main(argv: Sequence[str] | None = None) -> int:
    """``sm-bt-mission``: see the module's documentation."""
    from sm_bt.ros.console_log import configure_logging
    from sm_bt.ros.environment import RosUnavailable, prepare, require_ros

    configure_logging("info")
    args = list(sys.argv if argv is None else ["sm-bt-mission", *argv])
    prepare(local_only=False)  # a robot's nodes may be on other machines: the user's discovery
    try:
        require_ros()
    except RosUnavailable as error:
        log.error("%s", error)
        return 1
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(args=args, context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(NODE_NAME, context=context)
    host: MissionHost | None = None
    try:
        model_name, tree_spec, rate, wait = _parameters(node)
        model = _load_model(model_name)
        host = MissionHost(model, load_root(tree_spec, model), node, rate=rate)
        _stop_on_signals(host.stop)
        log.info("mission %s on node %s: %s at %g Hz, model %s", tree_spec, node.get_fully_qualified_name(),
                 host.tree.root.name, rate, model.path)
        if wait > 0:
            host.wait_for_nodes(wait)
        status = host.run()
        return 1 if status is Status.FAILURE else 0
    except HostError as error:
        log.error("%s", error)
        return 1
    finally:
        if host is not None:
            host.close()
        node.destroy_node()
        context.try_shutdown()


def _stop_on_signals(stop: Callable[[], None]) -> None:
    def handler(signum: int, frame: FrameType | None) -> None:
        stop()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
