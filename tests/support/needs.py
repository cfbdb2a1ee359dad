"""What a test needs beyond ``pip install -e '.[test]'``, and what happens when it is missing.

Three markers (registered here):

- ``ros``: the ``ros`` extra (rclpy) and the two interface packages (tools/ensure_interfaces.sh);
- ``browser``: a headless Chromium on PATH (tools/ensure_chromium.sh) and the page's scripts
  (``python -m sm_bt.view.assets``);
- ``netns``: root and iproute2's ``ip``, to make network namespaces (the across-hosts tests).

Where something is missing, the tests that need it are skipped, each with the reason and the fix,
and the run is green for everything else. ``make test`` sets ``SM_BT_TESTS_NEED_ALL=1``: there a
missing requirement fails those tests instead, so that a broken environment cannot pass for a
green run. A module that imports rclpy (or the interface packages) at its top carries the marker
too; where ROS is missing it cannot even be imported, and :func:`pytest_make_collect_report` turns
that import error into a skip of the module (one skip, with the reason).
"""

from __future__ import annotations

import functools
import importlib.util
import os
import shutil
from collections.abc import Generator

import pytest

#: The environment variable that turns skips for missing requirements into failures.
NEED_ALL = "SM_BT_TESTS_NEED_ALL"

#: Marker -> (what is needed, how to get it).
WHAT = {
    "ros": ("ROS 2 (the ros extra and the interface packages)",
            "pip install -c constraints.txt -e '.[ros]' && tools/ensure_interfaces.sh VENV, or make test"),
    "browser": ("Chromium and the page's scripts", "tools/ensure_chromium.sh and python -m sm_bt.view.assets, "
                "or make test"),
    "netns": ("root and iproute2 (network namespaces)", "run as root with `ip` on PATH, as make test does in CI"),
}
#: Fixtures whose tests need ROS whether or not they carry the marker.
ROS_FIXTURES = frozenset({"node_processes", "ros_context", "start_manager"})


@functools.cache
def missing(marker: str) -> str | None:
    """Why ``marker``'s requirement is not met here, or ``None`` when it is."""
    if marker == "ros":
        lacking = [name for name in ("rclpy", "system_modes_msgs", "py_trees_ros_interfaces")
                   if importlib.util.find_spec(name) is None]
        return f"no {', '.join(lacking)}" if lacking else None
    if marker == "browser":
        from sm_bt.view.assets import missing as missing_assets

        lacking = [] if shutil.which("chromium") or shutil.which("chromium-browser") else ["no chromium on PATH"]
        if missing_assets():
            lacking.append("the py_trees_js scripts are not extracted")
        return "; ".join(lacking) or None
    if marker == "netns":
        if os.geteuid() != 0:
            return "not root"
        return None if shutil.which("ip") else "no `ip` on PATH"
    raise ValueError(f"unknown requirement marker {marker!r}")


def required() -> bool:
    return os.environ.get(NEED_ALL, "") not in ("", "0")


def reason(marker: str, why: str) -> str:
    what, fix = WHAT[marker]
    return f"needs {what}: {why}; {fix}"


#: The top-level packages of ROS 2 that a test module may import (the ros extra and the interfaces).
ROS_PACKAGES = frozenset({"rclpy", "rosidl_runtime_py", "lifecycle_msgs", "rcl_interfaces", "std_msgs",
                          "builtin_interfaces", "diagnostic_msgs", "unique_identifier_msgs", "action_msgs",
                          "geometry_msgs", "system_modes_msgs", "py_trees_ros_interfaces"})


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Generator[None, pytest.CollectReport,
                                                                          pytest.CollectReport]:
    """A test module that cannot be imported because ROS 2 is missing here is skipped, with the reason
    (under ``make test`` it stays an error)."""
    report = yield
    why = missing("ros")
    if report.failed and why is not None and not required() and isinstance(collector, pytest.Module):
        error = str(report.longrepr)
        if any(f"No module named '{package}" in error for package in ROS_PACKAGES):
            report.outcome = "skipped"
            report.longrepr = (str(collector.path), 0, f"Skipped: {reason('ros', why)}")
    return report


#: Under ``make test``: the tests whose requirement is missing, with the reason (they fail at setup).
_unmet: dict[str, str] = {}


def pytest_configure(config: pytest.Config) -> None:
    for marker, (what, _) in WHAT.items():
        config.addinivalue_line("markers", f"{marker}: needs {what} (skipped where missing; tests/support/needs.py)")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark the tests that use the ROS fixtures ``ros``; skip (or, under ``make test``, fail) every
    marked test whose requirement is missing here."""
    _unmet.clear()
    for item in items:
        if ROS_FIXTURES & set(getattr(item, "fixturenames", ())) and item.get_closest_marker("ros") is None:
            item.add_marker(pytest.mark.ros)
        for marker in WHAT:
            why = missing(marker) if item.get_closest_marker(marker) else None
            if why is None:
                continue
            if required():
                _unmet[item.nodeid] = reason(marker, why)
            else:
                item.add_marker(pytest.mark.skip(reason=reason(marker, why)))


def pytest_runtest_setup(item: pytest.Item) -> None:
    if item.nodeid in _unmet:
        pytest.fail(f"{_unmet[item.nodeid]} ({NEED_ALL} is set: nothing may be skipped)", pytrace=False)
