"""Host a mission tree on ROS 2: one node, the manager embedded, the tree ticked at a rate.

The program is ``sm-bt mission`` (:mod:`sm_bt.cli.mission`); from Python, :class:`MissionHost`
does the same with objects::

    host = MissionHost(load_model("robot.yaml"), load_tree("mission.xml"), node=my_node)
    status = host.run()
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import threading
import time
from collections.abc import Iterator, Sequence
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.manager_access import attach_manager
from sm_bt.engine.events import Event, EventKind
from sm_bt.model.errors import Error
from sm_bt.model.types import Model, SystemPart
from sm_bt.ros.blackboard_streams import BlackboardStreams
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
        try:
            self.tree.setup(**(setup or {}))
        except Exception as error:  # a behaviour's own setup (user code): its message, not a traceback
            self._release()
            raise HostError(f"the tree cannot be set up: {error}") from error
        self.streams = SnapshotStreams(node, self.tree)
        self.blackboard_streams = BlackboardStreams(node, self.tree)
        self._shown: dict[str, str] = {}
        self._subscription = self.manager.subscribe(self._on_event, kinds=(EventKind.ACTUAL,))
        self._stop = threading.Event()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        from sm_bt.ros.runtime import spun

        with contextlib.suppress(ExternalShutdownException):  # the context was shut down under us
            while not spun(self._executor.spin, "sm_bt-mission-spin"):
                pass  # a callback raised (logged): spin on

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
            self.blackboard_streams.close()
            self.tree.shutdown()
            self.tree.interrupt()
        finally:  # ROS is released whatever a behaviour's shutdown did
            self._release()

    def _release(self) -> None:
        self.runtime.close()
        if self._executor is not None:
            self._executor.shutdown(timeout_sec=2.0)
        if self._thread is not None:
            self._thread.join(3.0)


@contextlib.contextmanager
def mission_node(ros_args: Sequence[str]) -> Iterator[Any]:
    """A node named :data:`NODE_NAME` (unless ``ros_args`` remap it) in a context of its own,
    destroyed with its context on leaving."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(args=["sm-bt", "--ros-args", *ros_args] if ros_args else ["sm-bt"], context=context,
               signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(NODE_NAME, context=context)
    try:
        yield node
    finally:
        node.destroy_node()
        context.try_shutdown()


def declare(node: Any, name: str, default: Any, description: str) -> Any:
    """Declare the ROS parameter ``name`` of ``node``; its value (``default`` unless set)."""
    from rcl_interfaces.msg import ParameterDescriptor

    return node.declare_parameter(name, default, ParameterDescriptor(description=description)).value


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
