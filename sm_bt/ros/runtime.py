"""An embedded mode manager on ROS 2: one rclpy node, its executor thread, the backend, the manager.

``RosRuntime(model)`` is what a mission tree (or ``sm-bt manager``) needs to drive real nodes::

    with RosRuntime(load_model("robot.yaml")) as ros:
        tree.setup(manager=ros.manager)
        ...tick...

By default it owns its own rclpy context (so it never disturbs another user of rclpy in the
process) and three nodes, each spun by its own executor thread (py_trees ticks in the caller's
thread; the manager is thread-safe): ``node`` serves the reference's mode manager interface
(:class:`~sm_bt.ros.manager_node.ModeManagerServer`), ``backend_node`` (``<name>_backend``) makes
the calls that change the managed nodes and hears their events, and ``watch_node``
(``<name>_watch``) asks for their state and parameters (discovery, liveness). All nodes of a
context share one DDS participant.

``RosRuntime(model, node=app_node)`` uses a node the application owns and spins (the node of a
``py_trees_ros`` tree, a launch file's node) instead: the interface is served on it, the helper
nodes join its context (still one participant per process), and ``close()`` removes only what the
runtime added. Either side may shut down first: ``close()`` after the node was destroyed or the
context shut down has nothing left to remove and does not raise.
Apart, each executor wakes over its own entities only: rclpy's executor rebuilds its wait set
over every entity of its nodes for every message it handles, and the backend handles one per
answer and event. The backend's node, where almost all of the traffic is, and the watching node
(woken by every liveness probe) are spun by rclpy's ``EventsExecutor`` where the installed rclpy
has it (``events_executor=False``: the plain one): it dispatches from the middleware's own
notifications, without a wait set, which costs the manager's process less CPU on a change and
when idle. Each wait lasts up to ``EVENTS_WAIT`` s and serves every event that comes meanwhile,
back to back: a wait per event put a burst of answers behind itself. The measurements are in
docs/performance.md.
``close()`` stops in the order rclpy needs: the interface's executor, then the interface,
the manager and backend, the other executors, the nodes and context.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from types import TracebackType
from typing import Any

from sm_bt.engine.backend import CallResult
from sm_bt.engine.clock import WallClock
from sm_bt.engine.manager import REQUEST_TIMEOUT, ModeManager
from sm_bt.model.types import Model, ParamValue
from sm_bt.ros.environment import prepare, require_ros

log = logging.getLogger("sm_bt.ros.runtime")

#: The reference manager's node name.
MANAGER_NODE_NAME = "__mode_manager"
#: After a callback raised out of an executor's spin, its thread waits this long before it spins again.
FAILED_PAUSE = 0.01
#: How long the EventsExecutor waits at a time (see the module's doc).
EVENTS_WAIT = 1.0


def _quietly(action: Callable[[], object], what: str) -> None:
    """Shutdown steps that the other side's shutdown may have done already."""
    try:
        action()
    except Exception:
        log.debug("%s: already done by the application's shutdown", what, exc_info=True)


class RosRuntime:
    """Manage ``model``'s nodes over ROS 2 from this process.

    ``manager_options`` go to :class:`ModeManager` (``grace_period``, ``request_timeout``, ...),
    ``backend_options`` to :class:`~sm_bt.ros.backend.RosBackend` (``liveness_timeout``, ...;
    ``call_timeout`` is the request timeout unless given). ``serve=False`` leaves out the ROS
    services and topics (the behaviours alone); ``serve_nodes=False`` serves the systems'
    interface only, not each node's. ``own_domain`` is for self-contained runs (demo, tests): a
    per-run ``ROS_DOMAIN_ID`` and discovery on this machine unless set; otherwise the user's
    settings (and ROS's defaults) apply, so nodes and manager may run on different machines.
    ``namespace`` is the robot's (``/robot1``): the model's nodes are looked for under it
    (``/robot1/amcl``), its parts served under it (``/robot1/pilot/change_mode``), and the
    manager's own node made in it; a robot of a fleet, beside others in one ROS domain.

    ``switch_interval``: if given, the interpreter's GIL switch interval (``sys.setswitchinterval``)
    while the runtime runs, put back by :meth:`close`; by default (``None``) the interpreter's own.
    Answers and events are handled in the executor thread that heard them, so a shorter interval
    buys no latency here and costs CPU in handing the lock over (docs/performance.md).
    ``events_executor``: spin
    the backend's and the watching node with rclpy's ``EventsExecutor`` where there is one (see the
    module's doc).
    """

    def __init__(self, model: Model, *, node_name: str = MANAGER_NODE_NAME, serve: bool = True,
                 own_domain: bool = False, manager_options: Mapping[str, Any] | None = None,
                 backend_options: Mapping[str, Any] | None = None, node: Any = None,
                 switch_interval: float | None = None, events_executor: bool = True,
                 requester: str = "operator", serve_nodes: bool = True, namespace: str = "/") -> None:
        self._switch_interval: tuple[float, float] | None = None
        if node is None:
            prepare(own_domain=own_domain, local_only=own_domain)
        require_ros()
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        from sm_bt.model.remote_parts import check_fleet
        from sm_bt.ros.backend import RosBackend
        from sm_bt.ros.diagnostics import DiagnosticsPublisher
        from sm_bt.ros.manager_node import ModeManagerServer
        from sm_bt.ros.remote_parts import RemoteBackend

        fleet = check_fleet(model)  # before anything is made that would have to be closed
        self.model = model
        self._owns_node = node is None
        if node is None:
            self.context = Context()
            # No rclpy signal handlers: the owner of the process decides what SIGINT means (a
            # mission tree, sm-bt manager), and the shutdown order stays close()'s.
            rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
            self.node = rclpy.create_node(node_name, namespace=namespace, context=self.context)
        else:
            self.context = node.context
            self.node = node
            node_name = node.get_name()
        self.clock = WallClock("sm_bt-ros-clock")
        # The helper nodes have no parameters: without parameter services they wake over fewer
        # entities. They ignore the context's command-line arguments, whose remaps are the main
        # node's (`-r __node:=mission` would give all three its name), and sit in its namespace.
        helper: dict[str, Any] = {"context": self.context, "start_parameter_services": False,
                                  "use_global_arguments": False, "namespace": self.node.get_namespace()}
        self.backend_node = rclpy.create_node(f"{node_name}_backend", **helper)
        self.watch_node = rclpy.create_node(f"{node_name}_watch", **helper)
        self.executor = SingleThreadedExecutor(context=self.context)
        if self._owns_node:  # an application's node is spun by the application
            self.executor.add_node(self.node)
        self.backend_executor = (_events_executor(self.context) if events_executor else None) or \
            SingleThreadedExecutor(context=self.context)
        self.backend_executor.add_node(self.backend_node)
        self.watch_executor = (_events_executor(self.context) if events_executor else None) or \
            SingleThreadedExecutor(context=self.context)
        self.watch_executor.add_node(self.watch_node)
        self._executors = (self.executor, self.backend_executor, self.watch_executor)
        spun = [(self.executor, self.node, "executor")] if self._owns_node else []
        spun += [(self.backend_executor, self.backend_node, "backend"), (self.watch_executor, self.watch_node, "watch")]
        self._spinners = [_Spinner(executor, node, name, self.context) for executor, node, name in spun]
        managing = dict(manager_options or {})
        backing = dict(backend_options or {})
        # A change of a node may take as long as the request it serves: a node busy in a long
        # transition answers nothing meanwhile (see RosBackend).
        backing.setdefault("call_timeout", managing.get("request_timeout", REQUEST_TIMEOUT))
        self.backend: RosBackend | RemoteBackend
        if fleet:  # its parts are other managers' systems: asked through their interface
            self.backend = RemoteBackend(self.backend_node, model, clock=self.clock, **{
                name: value for name, value in backing.items() if name in RemoteBackend.OPTIONS})
        else:
            self.backend = RosBackend(self.backend_node, model, clock=self.clock, watch_node=self.watch_node,
                                      namespace=namespace, **backing)
        self.manager = ModeManager(model, self.backend, **managing)
        # The manager's view for operators and aggregators, with the interface it serves.
        self.diagnostics = DiagnosticsPublisher(self.node, self.manager, self.clock,
                                                link=self.backend.link) if serve else None
        # Requests through the system_modes interface come from ``requester`` (its priority
        # decides against the holds of the manager's own users, a tree in this process).
        self.server = ModeManagerServer(self.node, self.manager,
                                        self.diagnostics.requested if self.diagnostics else None,
                                        requester=requester, nodes=serve_nodes, namespace=namespace) if serve else None
        if switch_interval is not None:
            self._switch_interval = (sys.getswitchinterval(), switch_interval)
            sys.setswitchinterval(switch_interval)
        self._closed = False

    def set_parameters(self, node: str, values: Mapping[str, ParamValue], timeout: float = 10.0) -> CallResult:
        """Set parameters of ``node`` directly, not as a mode (for tools, tests, fault injection);
        blocks until the node answers (at most the backend's call timeout, bounded by
        ``timeout``): not for a tick or a callback."""
        done = threading.Event()
        results: list[CallResult] = []

        def finished(result: CallResult) -> None:
            results.append(result)
            done.set()

        self.backend.set_parameters(node, values, finished)
        if not done.wait(timeout):
            return CallResult(False, f"set_parameters on {node}: no answer within {timeout:g} s")
        return results[0]

    def wait_for_nodes(self, timeout: float = 10.0, nodes: Sequence[str] | None = None) -> None:
        """Block until the manager reaches every node of the model (or ``nodes``): found on the
        ROS graph, answering, state and parameters known. ``TimeoutError`` after ``timeout``
        seconds names the ones it does not reach and why. For start-up, not for a tick."""
        names = list(nodes) if nodes is not None else [node.name for node in self.model.nodes]
        for name in names:
            self.manager.observation(name)  # RequestError for a name the model does not have as a node
        deadline = time.monotonic() + timeout
        while True:
            missing = [name for name in names if not self.manager.observation(name).reachable]
            if not missing:
                return
            if time.monotonic() >= deadline:
                why = [f"{name} ({self.manager.observation(name).gone or 'not found on the ROS graph'})"
                       for name in missing]
                raise TimeoutError(f"not reachable after {timeout:g} s: {', '.join(why)}")
            time.sleep(0.02)

    def close(self) -> None:
        """Stop serving and managing; idempotent. Removes only what the runtime made: an
        application's node stays (without the interface), its context too."""
        if self._closed:
            return
        self._closed = True
        # The interface's executor stops before its services and publishers go: rclpy does not
        # guard an entity destroyed while an executor thread builds its wait set over it (an
        # InvalidHandle in that thread). An application's node is the application's to stop.
        interface = [spinner for spinner in self._spinners if spinner.node is self.node]
        for spinner in interface:
            spinner.stop()
        # Then the work (no new calls; those in flight cancelled while their callbacks still have
        # an executor), then the other spinning, then the executors, nodes and context.
        if self.server is not None:  # the application may have destroyed its node first
            _quietly(self.server.close, "removing the interface")
        if self.diagnostics is not None:
            _quietly(self.diagnostics.close, "removing the diagnostics")
        self.manager.close()
        self.clock.close()
        for spinner in self._spinners:
            spinner.stop()
        for spinner in self._spinners:
            spinner.remove_waker()
        for executor in self._executors:  # a context shut down first has stopped them already
            _quietly(functools.partial(executor.shutdown, timeout_sec=2.0), "executor shutdown")
        helpers = [self.backend_node, self.watch_node] + ([self.node] if self._owns_node else [])
        for node in helpers:  # the application may have shut the context down first
            _quietly(node.destroy_node, f"destroying {node.get_name()}")
        if self._owns_node:
            self.context.try_shutdown()
        if self._switch_interval is not None:
            before, ours = self._switch_interval
            if abs(sys.getswitchinterval() - ours) < 1e-7:  # unless someone has set it since
                sys.setswitchinterval(before)

    def __enter__(self) -> RosRuntime:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()


def spun(spin: Callable[[], object], thread: str) -> bool:
    """``spin()`` (an executor's) in ``thread``: False, with what a callback raised out of it logged,
    for the thread to spin again (after :data:`FAILED_PAUSE`, so that a failure that repeats cannot
    take a core). Left to end the thread, it would leave the node deaf to its peers and its clients
    for good. The context's shutdown (ExternalShutdownException) goes through."""
    from rclpy.executors import ExternalShutdownException

    try:
        spin()
    except ExternalShutdownException:
        raise
    except Exception:
        log.exception("%s: a callback failed", thread)
        time.sleep(FAILED_PAUSE)
        return False
    return True


def _events_executor(context: Any) -> Any:
    """rclpy's EventsExecutor for ``context``, or None where this rclpy has none.

    Made as ``rclpy.experimental.EventsExecutor`` makes it, except that it leaves the process's
    ``faulthandler`` alone (enabling it is not a library's choice, and fails where ``sys.stderr``
    has no file descriptor, as under pytest or in an embedding application)."""
    try:
        from rclpy.impl.implementation_singleton import rclpy_implementation

        executor = rclpy_implementation.EventsExecutor(context)
    except (ImportError, AttributeError):
        return None
    context.on_shutdown(executor.wake)
    return executor


class _Spinner:
    """One executor's thread, stoppable between callbacks.

    ``spin()`` itself cannot be stopped safely: ``Executor.shutdown()`` under a spinning thread drops
    its guard condition while callbacks may still schedule work (an AttributeError in that thread).
    :meth:`stop` sets a flag and ends the current wait so that the thread sees the flag: a plain
    executor's ``spin_once()`` is woken by a guard condition whose callback does nothing; an
    EventsExecutor (which has no guard conditions) waits in ``spin_until_future_complete`` on a
    future of ours, which :meth:`stop` completes.
    """

    def __init__(self, executor: Any, node: Any, name: str, context: Any) -> None:
        self.executor = executor
        self.node = node
        self._context = context
        self._stopping = threading.Event()
        self._plain = hasattr(executor, "wait_for_ready_callbacks")
        self._waker: Any = None
        self._guard = threading.Lock()
        self._until: Any = None  # the future that ends the EventsExecutor's current wait
        if self._plain:
            self._waker = node.create_guard_condition(lambda: None)
        self._thread = threading.Thread(target=self._spin, name=f"sm_bt-ros-{name}", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException
        from rclpy.task import Future

        with contextlib.suppress(ExternalShutdownException):  # the context shut down under us
            if self._plain:
                while not self._stopping.is_set() and self._context.ok():
                    spun(self.executor.spin_once, self._thread.name)
                return
            while self._context.ok():
                with self._guard:
                    if self._stopping.is_set():
                        return
                    self._until = Future()
                spun(functools.partial(self.executor.spin_until_future_complete, self._until,
                                       timeout_sec=EVENTS_WAIT), self._thread.name)

    def _wake(self) -> None:
        if self._waker is not None:
            _quietly(self._waker.trigger, "waking the executor")
            return
        with self._guard:
            until = self._until
        if until is not None:
            _quietly(functools.partial(until.set_result, True), "ending the wait")

    def stop(self, timeout: float = 3.0) -> None:
        """Return once the thread has left its wait (or after ``timeout``); idempotent."""
        if not self._stopping.is_set():
            with self._guard:
                self._stopping.set()
            self._wake()
        self._thread.join(timeout)

    def remove_waker(self) -> None:
        if self._waker is not None:
            _quietly(functools.partial(self.node.destroy_guard_condition, self._waker), "removing the waker")
