"""The layers' import rules: model imports nothing of sm_bt, the engine imports no rclpy."""

from __future__ import annotations

import ast
import contextlib
import io
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def imported_modules(folder: Path) -> set[str]:
    found: set[str] = set()
    for path in folder.rglob("*.py"):
        found |= imported_modules_of(path)
    return found


def test_model_layer_depends_on_nothing_of_sm_bt_above_it() -> None:
    modules = imported_modules(ROOT / "sm_bt" / "model")
    assert not {m for m in modules if m.startswith("sm_bt.") and not m.startswith("sm_bt.model")}


def test_engine_depends_only_on_the_model() -> None:
    modules = imported_modules(ROOT / "sm_bt" / "engine")
    allowed = ("sm_bt.model", "sm_bt.engine")
    assert not {m for m in modules if m.startswith("sm_bt.") and not m.startswith(allowed)}
    assert not {m for m in modules if m.split(".")[0] in {"rclpy", "py_trees", "rich"}}


def test_engine_and_sim_import_without_rclpy_loaded() -> None:
    # A fresh interpreter where importing rclpy would fail loudly: the engine must not need it.
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "import sm_bt.engine.manager, sm_bt.engine.inference, sm_bt.sim, sm_bt.model.loader\n"
        "assert not any(m == 'rclpy' or m.startswith('rclpy.') for m in sys.modules if sys.modules[m])\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_reasoner_is_usable_without_py_trees() -> None:
    reasoner = imported_modules_of(ROOT / "sm_bt" / "reasoner.py")
    assert "sm_bt.model.states" in reasoner
    assert not {m for m in reasoner if m.split(".")[0] in {"py_trees", "rclpy"}}


def test_behaviours_and_trees_sit_above_the_engine() -> None:
    engine_and_model = imported_modules(ROOT / "sm_bt" / "engine") | imported_modules(ROOT / "sm_bt" / "model")
    assert not {m for m in engine_and_model if m.startswith(("sm_bt.behaviours", "sm_bt.trees", "sm_bt.sim"))}
    behaviours = imported_modules(ROOT / "behaviours")
    assert not {m for m in behaviours if m.startswith(("sm_bt.trees", "sm_bt.trees.pilot.demo", "sm_bt.cli"))}


def test_the_ros_adapters_import_no_command_line_and_no_example() -> None:
    """Executables and the pilot example sit at the top: the CLI and the example start the ROS
    adapters, never the other way round; the simulated backend knows no example either."""
    ros = imported_modules(ROOT / "sm_bt" / "ros")
    assert not {m for m in ros if m.startswith(("sm_bt.cli", "sm_bt.trees.pilot"))}
    sim = imported_modules(ROOT / "sm_bt" / "sim")
    assert not {m for m in sim if m.startswith(("sm_bt.cli", "sm_bt.trees", "sm_bt.behaviours", "sm_bt.view"))}


def test_the_pilot_example_is_one_wing() -> None:
    """Everything of the pilot example but its model file lives in trees/pilot/; outside it, only the
    CLI (`sm-bt demo`) reaches into it."""
    outside = set()
    for folder in (ROOT / "sm_bt", ROOT / "behaviours"):
        for path in folder.rglob("*.py"):
            if (ROOT / "sm_bt" / "cli") not in path.parents:
                outside |= {m for m in imported_modules_of(path) if m.startswith("sm_bt.trees.pilot")}
    assert not outside
    assert not list((ROOT / "trees").glob("pilot_*.py")) and not (ROOT / "sm_bt" / "demo.py").exists()


def imported_modules_of(path: Path) -> set[str]:
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
    return found


def test_only_the_ros_adapters_import_rclpy() -> None:
    ros_names = {"rclpy", "lifecycle_msgs", "rcl_interfaces", "system_modes_msgs", "std_msgs", "builtin_interfaces"}
    outside = set()
    for folder in (ROOT / "sm_bt", ROOT / "behaviours", ROOT / "trees"):
        for path in folder.rglob("*.py"):
            if (ROOT / "sm_bt" / "ros") in path.parents:
                continue
            outside |= {m for m in imported_modules_of(path) if m.split(".")[0] in ros_names}
    assert not outside, "rclpy and ROS messages belong in sm_bt.ros"
    # The simulated side never reaches up into the ROS adapters; of the trees, only the examples'
    # platforms for `sm-bt demo --ros` and `sm-bt demo --fleet --ros` do (imported by those commands alone).
    platforms = {ROOT / "trees" / "pilot" / "ros_platform.py", ROOT / "trees" / "fleet" / "ros_platform.py"}
    trees = set().union(*(imported_modules_of(path) for path in (ROOT / "trees").rglob("*.py")
                          if path not in platforms))
    below = imported_modules(ROOT / "sm_bt" / "engine") | imported_modules(ROOT / "sm_bt" / "sim") | \
        imported_modules(ROOT / "behaviours") | trees
    assert not {m for m in below if m.startswith("sm_bt.ros")}
    for platform in platforms:  # the rule can fail
        assert {m for m in imported_modules_of(platform) if m.startswith("sm_bt.ros")}, platform


def test_the_pilot_and_fleet_demos_import_without_rclpy() -> None:
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "import sm_bt.trees.pilot.demo, sm_bt.trees.pilot.metacontrol, sm_bt.trees.fleet.demo\n"
        "assert not any(m == 'rclpy' or m.startswith('rclpy.') for m in sys.modules if sys.modules[m])\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_the_cli_starts_without_rclpy() -> None:
    # `sm-bt check/modes/demo` must work where the ros extra is missing: ROS is imported lazily.
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "from sm_bt import cli\n"
        "assert cli.main(['modes', 'pilot']) == 0\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, capture_output=True)


def test_the_manager_command_without_rclpy_says_how_to_install_it() -> None:
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "from sm_bt import cli\n"
        "sys.exit(cli.main(['manager', 'pilot']))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=30)
    assert result.returncode == 1
    assert "ROS 2 is not available here" in result.stderr and "[ros]" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_request_from_the_monitor_enters_the_manager_only_to_ask_and_to_read() -> None:
    """The manager is a façade: following one request of ``sm-bt monitor`` (on simulated nodes),
    calls into ``engine/manager.py`` from elsewhere are the request itself and reading the result
    (the parts shown, the divergences counted, under its lock for one consistent table); settling,
    the drivers' calls and the backend's reports go to the modules that own them."""
    from sm_bt.cli import main

    manager_py = str(ROOT / "sm_bt" / "engine" / "manager.py")
    entered: set[str] = set()

    def profile(frame: Any, event: str, arg: Any) -> None:
        if event == "call" and frame.f_code.co_filename == manager_py and frame.f_back is not None \
                and frame.f_back.f_code.co_filename != manager_py:
            entered.add(frame.f_code.co_name)

    sys.setprofile(profile)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            code = main(["monitor", "pilot", "--change", "pilot=f_normal_mode", "--once", "--json", "--speed", "0"])
    finally:
        sys.setprofile(None)
    assert code == 0
    setting_up = {"__init__", "subscribe", "close"}
    assert entered & setting_up  # the profile saw the manager at all
    assert entered - setting_up <= {"change_mode", "status", "divergences", "lock"}, sorted(entered)
