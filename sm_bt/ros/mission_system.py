"""A mission's system on ROS 2: what ``sm-bt run --ros`` and ``sm-bt test --ros`` tick a tree against.

:class:`RosSystem` offers what :class:`~sm_bt.sim.SimulatedSystem` offers a run (a manager, a
clock, time passing, a tree set up with both, and a scenario's faults), with the model's nodes as
simulated rclpy lifecycle nodes in child processes (``sm-bt sim-nodes``) or, ``attach=True``, the
real nodes already running. The manager is embedded (:class:`~sm_bt.ros.runtime.RosRuntime`) and
serves the system_modes interface meanwhile. Time is real: the run's clock counts seconds from
when the manager reached every node.

A scenario's faults become what they are on a robot. A node that is to ``crash``, ``vanish`` or
``restart`` runs in a process of its own (``separate``): a crash stops the process (SIGSTOP: it
answers nothing, and is reported gone after the liveness window), a vanish ends it (it leaves the
graph), a restart starts a new one. ``fail_next``, ``hang_next`` and ``reject_parameters`` set the
node's ``sim.*`` parameters, ``set_parameter`` its parameter, each from a client of this process's
own (the manager hears of it as of anyone else's change). Attached to real nodes, only
``set_parameter`` applies: the others need sm_bt's simulated nodes, and say so.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Collection, Mapping
from contextlib import ExitStack
from typing import Any

import py_trees

from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model, ParamValue
from sm_bt.ros.environment import prepare, require_ros
from sm_bt.ros.node_process import NodesError, NodesProcess
from sm_bt.ros.runtime import MANAGER_NODE_NAME, RosRuntime

#: Until the manager reaches every node (processes start in a few seconds on a loaded machine).
REACH_TIMEOUT = 30.0
#: Each parameter set of a fault.
SET_TIMEOUT = 5.0
#: The backend's options: short enough that a stopped process shows within the run.
BACKEND_OPTIONS: dict[str, Any] = {"call_timeout": 5.0, "acquire_timeout": 2.0, "liveness_timeout": 2.0}
#: The ``sim.*`` parameters (sm_bt.ros.sim_nodes; not imported: it starts rclpy's C side).
FAIL_NEXT, HANG_NEXT, REJECT_PARAMETERS = "sim.fail_next", "sim.hang_next", "sim.reject_parameters"


class RunClock:
    """``clock``'s time from ``start`` on, its timers kept: a run's time starts at 0."""

    def __init__(self, clock: Clock, start: float) -> None:
        self._clock = clock
        self._start = start

    def now(self) -> float:
        return self._clock.now() - self._start

    def call_later(self, delay: float, callback: Callable[[], None]) -> TimerHandle:
        return self._clock.call_later(delay, callback)


class RosSystem:
    """The model's nodes on ROS 2 and an embedded manager, for a run (module doc). ``model_name``
    is what a node process loads (a file or a bundled model's name); ``say`` tells the user what
    it is doing. :meth:`close` stops everything it started."""

    def __init__(self, model: Model, model_name: str, *, attach: bool = False, separate: Collection[str] = (),
                 manager_options: Mapping[str, Any] | None = None, node_name: str = MANAGER_NODE_NAME,
                 say: Callable[[str], None] | None = None) -> None:
        self.model = model
        self.model_name = model_name
        self.attach = attach
        self._say = say or (lambda text: None)
        self._processes: dict[str, NodesProcess] = {}  # node -> the process it runs in
        self._stopped: set[int] = set()  # pids stopped by a fault: not a failure of the run
        with ExitStack() as stack:
            # Simulated nodes: this run's own domain unless the user chose one. Attached: the
            # user's settings, whatever they are (the robot's nodes may be on other hosts).
            prepare(own_domain=not attach, local_only=not attach)
            require_ros()
            stack.callback(self._stop_processes)
            if not attach:
                self._start_processes(separate)
            self.runtime = RosRuntime(model, node_name=node_name, serve=True, own_domain=not attach,
                                      manager_options=manager_options, backend_options=BACKEND_OPTIONS)
            stack.callback(self.runtime.close)
            self.manager: ModeManager = self.runtime.manager
            began = time.monotonic()
            if attach:
                self._say(f"waiting up to {REACH_TIMEOUT:g} s for the model's nodes on the ROS graph")
            try:
                self.runtime.wait_for_nodes(REACH_TIMEOUT)
            except TimeoutError as error:
                raise NodesError(f"the manager did not reach the model's nodes: {error}"
                                 + ("" if not attach else " (with --attach they must be running already, in this "
                                                          "shell's ROS_DOMAIN_ID)")) from None
            self._say(f"the manager reaches every node ({time.monotonic() - began:.1f} s)")
            self._faults = _ParameterClient(self.runtime.context)
            stack.callback(self._faults.close)
            self.clock = RunClock(self.runtime.clock, self.runtime.clock.now())
            self._close = stack.pop_all()

    def _start_processes(self, separate: Collection[str]) -> None:
        names = [node.name for node in self.model.nodes]
        rest = [name for name in names if name not in separate]
        groups = ([rest] if rest else []) + [[name] for name in names if name in separate]
        for group in groups:
            process = NodesProcess(self.model_name, "--only", ",".join(group))
            for name in group:
                self._processes[name] = process
            began = time.monotonic()
            process.start()
            self._say(f"node process {process.pid} READY after {time.monotonic() - began:.1f} s: {', '.join(group)}")

    def _stop_processes(self) -> None:
        for process in {id(p): p for p in self._processes.values()}.values():
            if process.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(process.pid, signal.SIGCONT)  # a crashed (stopped) one must run to exit
            process.stop()

    def close(self) -> None:
        self._close.close()

    def __enter__(self) -> RosSystem:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- what a run needs ---------------------------------------------------------------------------

    def run(self, seconds: float) -> None:
        """Let ``seconds`` of real time pass; :class:`NodesError` if a node process died by itself."""
        for process in set(self._processes.values()):
            if process.pid not in self._stopped:
                process.check()
        time.sleep(seconds)

    def tree(self, root: py_trees.behaviour.Behaviour, **setup: Any) -> py_trees.trees.BehaviourTree:
        """A tree around ``root``, set up with the manager and the run's clock."""
        tree = py_trees.trees.BehaviourTree(root)
        tree.setup(**{"manager": self.manager, "clock": self.clock, **setup})
        return tree

    # -- a scenario's faults ------------------------------------------------------------------------

    def crash(self, node: str) -> None:
        """The node's process stops answering (SIGSTOP); reported gone after the liveness window."""
        process = self._own_process(node, "crash")
        self._stopped.add(process.pid or 0)
        os.kill(process.pid or 0, signal.SIGSTOP)

    def vanish(self, node: str) -> None:
        """The node's process ends (SIGINT, as when it exits): it leaves the graph."""
        process = self._own_process(node, "end")
        self._stopped.add(process.pid or 0)
        with contextlib.suppress(ProcessLookupError):
            os.kill(process.pid or 0, signal.SIGCONT)
        process.stop()

    def restart(self, node: str) -> None:
        """A new process of the node starts, unconfigured (the old one is ended first)."""
        process = self._own_process(node, "restart")
        self.vanish(node)
        process.start()
        self._say(f"node process {process.pid} READY: {node} restarted")

    def fail_next(self, node: str, transition: Transition) -> None:
        self._set(node, {FAIL_NEXT: transition.label}, "fail a transition of")

    def hang_next(self, node: str, transition: Transition) -> None:
        self._set(node, {HANG_NEXT: transition.label}, "hang a transition of")

    def reject_parameters(self, node: str, reason: str | None) -> None:
        self._set(node, {REJECT_PARAMETERS: reason or ""}, "make parameter sets fail on")

    def set_parameter(self, node: str, name: str, value: ParamValue) -> None:
        """Parameter ``name`` of ``node`` changes, set by another client than the manager."""
        self._faults.set(node, {name: value})

    def _own_process(self, node: str, what: str) -> NodesProcess:
        process = self._processes.get(node)
        if process is None:
            raise ValueError(f"sm-bt does not {what} a node it did not start (with --attach, {node} is a real node)")
        if [name for name, other in self._processes.items() if other is process] != [node]:
            raise ValueError(f"{node} shares its process with other nodes: name it in the scenario's events so "
                             "that it runs alone")
        return process

    def _set(self, node: str, values: Mapping[str, ParamValue], what: str) -> None:
        if self.attach:
            raise ValueError(f"cannot {what} {node} with --attach: only sm-bt's simulated nodes take sim.* faults")
        self._faults.set(node, values)


class _ParameterClient:
    """``set_parameters`` calls from a node of this process's own (not the manager's), spun by a
    thread of its own; every call with a timeout."""

    def __init__(self, context: Any) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self._node = rclpy.create_node("sm_bt_scenario_faults", context=context, start_parameter_services=False,
                                       use_global_arguments=False)
        self._executor = SingleThreadedExecutor(context=context)
        self._executor.add_node(self._node)
        self._clients: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._spin, name="sm_bt-scenario-faults", daemon=True)
        self._running = True
        self._thread.start()

    def _spin(self) -> None:
        while self._running:
            with contextlib.suppress(Exception):  # the context going away as close() runs
                self._executor.spin_once(timeout_sec=0.1)

    def set(self, node: str, values: Mapping[str, ParamValue]) -> None:
        """Set ``values`` on ``node``; ``ValueError`` with the node's reason when it refuses, or
        when it does not answer within :data:`SET_TIMEOUT`."""
        from rcl_interfaces.srv import SetParameters

        from sm_bt.ros.node_calls import answer
        from sm_bt.ros.parameters import to_parameters

        name = f"/{node}/set_parameters"
        client = self._clients.get(name) or self._clients.setdefault(
            name, self._node.create_client(SetParameters, name))
        request = SetParameters.Request(parameters=to_parameters(dict(values)))
        # Asking twice changes nothing: a first request whose answer was lost (the path back to a
        # new client is matched late) is asked again.
        for _ in range(2):
            response = answer(client, request, SET_TIMEOUT / 2)
            if response is not None:
                refused = [result.reason for result in response.results if not result.successful]
                if refused:
                    raise ValueError(f"{node} refused {', '.join(values)}: {refused[0]}")
                return
        raise ValueError(f"{node} did not answer a parameter set within {SET_TIMEOUT:g} s")

    def close(self) -> None:
        self._running = False
        self._thread.join(2.0)
        self._executor.shutdown(timeout_sec=1.0)
        self._node.destroy_node()
