"""Hosting the embedded manager on a node the application owns: one DDS participant per process,
the interface served on that node, a public wait for the nodes, and a clean shutdown in either
order (the runtime first, or the application's node and context first)."""

from __future__ import annotations

import threading

import py_trees
import pytest
from model_files import bundled
from py_trees.common import Status
from ros_harness import BACKEND_OPTIONS
from ros_processes import RosContext, Starter, wait_until
from system_modes_msgs.srv import GetMode

from sm_bt.behaviours import ChangeMode, attach_manager
from sm_bt.model.errors import RequestError
from sm_bt.ros.runtime import RosRuntime

pytestmark = pytest.mark.ros

APP = "sm_bt_test_mission"


class _Spy(py_trees.behaviours.Success):
    def __init__(self, name: str, shut: list[str]) -> None:
        super().__init__(name)
        self._shut = shut

    def shutdown(self) -> None:
        self._shut.append(self.name)


def _runtime_on(app: RosContext) -> RosRuntime:
    return RosRuntime(bundled("pilot"), node=app.node, manager_options={"recovery": False},
                      backend_options=BACKEND_OPTIONS)


def _participants(observer: RosContext, names: set[str]) -> dict[str, bytes]:
    """The DDS participant (GUID prefix) of each of ``names``, from its /rosout publisher."""
    found: dict[str, bytes] = {}
    for info in observer.node.get_publishers_info_by_topic("/rosout"):
        if info.node_name in names:
            found[info.node_name] = bytes(info.endpoint_gid[:12])
    return found


def _served_by(observer: RosContext, node: str) -> set[str]:
    try:
        return {name for name, _ in observer.node.get_service_names_and_types_by_node(node, "/")}
    except Exception:  # not discovered yet
        return set()


def test_the_runtime_serves_on_the_application_node_in_one_participant(node_processes: Starter) -> None:
    node_processes("pilot")
    app, observer = RosContext(APP), RosContext("sm_bt_test_observer")
    runtime = _runtime_on(app)
    try:
        runtime.wait_for_nodes(15.0)
        assert runtime.node is app.node and runtime.context is app.context
        answer = observer.call(GetMode, "/pilot/get_mode", GetMode.Request())
        assert answer.current_mode in ("", "unknown", "__DEFAULT__")
        wait_until(lambda: "/pilot/change_mode" in _served_by(observer, APP), 10.0, "the interface on the app's node")
        ours = {APP, f"{APP}_backend", f"{APP}_watch"}
        wait_until(lambda: set(_participants(observer, ours)) == ours, 10.0, "the three nodes on the graph")
        assert len(set(_participants(observer, ours).values())) == 1, "one process, one participant"
        root = attach_manager(ChangeMode("Normal", "pilot", "f_normal_mode", timeout=10.0), runtime.manager)
        tree = py_trees.trees.BehaviourTree(root)
        tree.setup()
        wait_until(lambda: tree.tick() or root.status is Status.SUCCESS, 15.0, "pilot in f_normal_mode")
    finally:
        runtime.close()
        observer.close()
        app.close()


@pytest.mark.parametrize("first", ["runtime", "application"])
def test_either_side_may_shut_down_first(node_processes: Starter, first: str) -> None:
    node_processes("pilot")
    app = RosContext(APP)
    runtime = _runtime_on(app)
    shut: list[str] = []
    tree = py_trees.trees.BehaviourTree(py_trees.composites.Sequence("Mission", memory=True, children=[
        _Spy("A", shut), attach_manager(ChangeMode("Normal", "pilot", "f_normal_mode"), runtime.manager),
        _Spy("B", shut)]))
    tree.setup()
    errors: list[BaseException] = []
    hook, threading.excepthook = threading.excepthook, lambda args: errors.append(args.exc_value)  # type: ignore[assignment,return-value]
    try:
        runtime.wait_for_nodes(15.0)
        tree.tick()
        if first == "runtime":
            runtime.close()
            tree.shutdown()
            app.close()
        else:
            tree.shutdown()
            app.close()  # the node destroyed and the context shut down under the runtime
            runtime.close()
        runtime.close()  # idempotent
    finally:
        threading.excepthook = hook  # type: ignore[assignment]
    assert shut == ["A", "B"]
    assert errors == [], errors


def test_waiting_for_nodes_that_are_not_there_names_them() -> None:
    app = RosContext(APP)
    runtime = _runtime_on(app)
    try:
        with pytest.raises(TimeoutError, match=r"not reachable after 0.5 s: amcl \(not found on the ROS graph\)"):
            runtime.wait_for_nodes(0.5, ["amcl"])
        with pytest.raises(RequestError, match=r"unknown part 'amlc' \(did you mean 'amcl'\?\)"):
            runtime.wait_for_nodes(0.1, ["amlc"])
    finally:
        runtime.close()
        app.close()


def test_the_runtime_leaves_the_switch_interval_alone_unless_asked_and_puts_it_back() -> None:
    import sys

    before = sys.getswitchinterval()
    left_alone = RosRuntime(bundled("pilot"), serve=False)
    try:
        assert sys.getswitchinterval() == before
    finally:
        left_alone.close()
    asked = before / 4
    runtime = RosRuntime(bundled("pilot"), serve=False, switch_interval=asked)
    try:
        assert abs(sys.getswitchinterval() - asked) < 1e-7
    finally:
        runtime.close()
    assert sys.getswitchinterval() == before
