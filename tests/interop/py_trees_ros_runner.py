"""Run the docs' py_trees_ros recipe as written, or one of py_trees_ros's programs, with
py_trees_ros from its sources.

    python tests/interop/py_trees_ros_runner.py recipe SOURCES BLOCK_FILE [HOLD]
    python tests/interop/py_trees_ros_runner.py watch SOURCES [ARGS...]   (py-trees-blackboard-watcher)

``SOURCES`` holds the package ``py_trees_ros`` (tools/py_trees_ros.sh exports it; no package index
has it). Its package imports every module, and three of them need what no index has either:
``tf2_ros`` (transforms), ``ros2cli``/``ros2topic`` (the echo program). Hosting a tree uses none
of them, so they are importable here as empty modules whose every name is a placeholder class;
anything else missing is a real failure. The block runs in a namespace holding what the page has
defined by then (``root``: the modes to the blackboard, configure, then ``f_slow_mode``; ``model``:
the pilot; the imports), and ``rclpy.spin`` there returns once the mission ended and ``HOLD``
more seconds passed (the tree keeps ticking, for a watcher to look). Exit 0 when it succeeded, 1
otherwise; the last line of stdout says how it ended.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
import time
import types
from pathlib import Path
from typing import Any

ABSENT = ("tf2_ros", "ros2cli", "ros2topic")
LIMIT = 60.0


class _Absent(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, name: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if name.split(".")[0] in ABSENT:
            return importlib.machinery.ModuleSpec(name, self, is_package=True)
        return None

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType | None:
        return None

    def exec_module(self, module: types.ModuleType) -> None:
        module.__path__ = []

        def placeholder(name: str) -> type:
            if name.startswith("__"):
                raise AttributeError(name)
            return type(name, (), {})

        module.__getattr__ = placeholder  # type: ignore[method-assign]


def _use(sources: str) -> None:
    sys.meta_path.insert(0, _Absent())
    sys.path.insert(0, sources)


def watch(sources: str, *args: str) -> int:
    _use(sources)
    from py_trees_ros.programs import blackboard_watcher

    return int(blackboard_watcher.main(list(args)) or 0)


def recipe(sources: str, block_file: str, hold: str = "0") -> int:
    _use(sources)
    import py_trees
    import py_trees_ros
    import rclpy
    from py_trees.common import Status

    from sm_bt.behaviours import ChangeMode, ChangeState, ModesToBlackboard, attach_manager
    from sm_bt.bundled import path
    from sm_bt.model.loader import load_model
    from sm_bt.ros.runtime import RosRuntime

    assert Path(py_trees_ros.__file__).is_relative_to(sources), py_trees_ros.__file__
    rclpy.init()
    mission = py_trees.composites.Sequence("Mission", memory=True, children=[
        ChangeState("Configure", "pilot", "configure", timeout=10.0),
        ChangeMode("Slow", "pilot", "f_slow_mode", timeout=10.0)])
    # The modes to the blackboard on every tick; the mission once (py_trees_ros keeps ticking the
    # root, and the mission must not start over while held).
    root = py_trees.composites.Sequence("Root", memory=False, children=[
        ModesToBlackboard(), py_trees.decorators.OneShot("Once", mission, py_trees.common.OneShotPolicy.ON_COMPLETION)])

    def spin(node: Any) -> None:
        deadline = time.monotonic() + LIMIT
        while root.status not in (Status.SUCCESS, Status.FAILURE) and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
        print(f"mission {root.status.value}", flush=True)
        deadline = time.monotonic() + float(hold)
        while time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)

    namespace: dict[str, Any] = {
        "py_trees": py_trees, "py_trees_ros": py_trees_ros, "rclpy": types.SimpleNamespace(spin=spin),
        "RosRuntime": RosRuntime, "attach_manager": attach_manager, "model": load_model(path("pilot")),
        "root": root}
    exec(compile(Path(block_file).read_text(), block_file, "exec"), namespace)
    ros, tree = namespace["ros"], namespace["tree"]
    print(f"mission {root.status.value}: pilot is {ros.manager.actual('pilot')}; "
          + "; ".join(f"{b.name}: {b.feedback_message}" for b in mission.children), flush=True)
    ros.close()
    tree.shutdown()
    rclpy.try_shutdown()
    return 0 if root.status is Status.SUCCESS else 1


if __name__ == "__main__":
    sys.exit({"recipe": recipe, "watch": watch}[sys.argv[1]](*sys.argv[2:]))
