"""The behaviour-scenario harness on real ROS 2: the model's nodes as rclpy lifecycle nodes in another
process, the manager embedded in the test process (``RosRuntime``), wall time.

Faults go to the nodes as their ``sim.*`` parameters (see :mod:`sm_bt.ros.sim_nodes`), set with a
plain ``set_parameters`` call that must be confirmed.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import py_trees
from harness import MANAGER_OPTIONS
from ros_processes import NodeProcess

from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.requests import Request
from sm_bt.model.types import Model, ParamValue
from sm_bt.ros.runtime import RosRuntime
from sm_bt.sim import NotReached, Tick, tick_until

#: Short enough that a test notices a dead node quickly, long enough for a loaded CI machine.
BACKEND_OPTIONS: dict[str, Any] = {"call_timeout": 5.0, "acquire_timeout": 2.0, "liveness_timeout": 2.0}
DISCOVERY_LIMIT = 15.0


class RosHarness:
    """``model``'s nodes in ``process`` (already READY), managed from this process."""

    def __init__(self, model: Model, process: NodeProcess, *, backend_options: dict[str, Any] | None = None,
                 **manager_options: Any) -> None:
        self.process = process
        options = {**MANAGER_OPTIONS, **manager_options}
        self.runtime = RosRuntime(model, node_name="sm_bt_test_manager", manager_options=options,
                                  backend_options={**BACKEND_OPTIONS, **(backend_options or {})})
        self.manager = self.runtime.manager
        names = [node.name for node in model.nodes]
        self.run_until(lambda: all(self.manager.observation(n).reachable for n in names), DISCOVERY_LIMIT)

    def now(self) -> float:
        return self.manager.clock.now()

    def tree(self, root: py_trees.behaviour.Behaviour) -> py_trees.trees.BehaviourTree:
        tree = py_trees.trees.BehaviourTree(root)
        tree.setup(manager=self.manager)
        return tree

    def tick_until(self, tree: py_trees.trees.BehaviourTree, condition: Callable[[], bool], *,
                   step: float = 0.05, timeout: float = 10.0) -> list[Tick]:
        return tick_until(tree, condition, now=self.now, advance=time.sleep, step=step, timeout=timeout)

    def run_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> float:
        start = self.now()
        while not condition():
            if self.now() - start > timeout:
                raise NotReached(f"condition not met within {timeout:g} s")
            time.sleep(0.01)
        return self.now() - start

    def finish(self, request: Request, timeout: float = 10.0) -> Request:
        self.run_until(lambda: request.done, timeout)
        return request

    def set_parameter(self, node: str, name: str, value: ParamValue) -> None:
        """Set one parameter of ``node`` directly (not through the manager); it must be accepted."""
        result = self.runtime.set_parameters(node, {name: value})
        assert result.ok, f"{node} refused {name}={value!r}: {result.reason}"

    def fail_next(self, node: str, transition: Transition) -> None:
        self.set_parameter(node, "sim.fail_next", transition.label)

    def reject_parameters(self, node: str, reason: str) -> None:
        self.set_parameter(node, "sim.reject_parameters", reason)

    def fail(self, node: str) -> None:
        self.set_parameter(node, "sim.broken", True)

    def close(self) -> None:
        self.runtime.close()
