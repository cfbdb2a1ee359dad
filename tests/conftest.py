"""What every test shares: the ROS environment (a domain per run and per xdist worker), the
requirement markers (tests/support/needs.py), the ROS fixtures; the project's own model files live
in tests/models/, the helpers in tests/support/."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any

import pytest

import sm_bt.ros.environment


def worker_domain_id(run_domain: int, worker: int) -> int:
    """The ROS domain of xdist worker ``worker`` in a run whose controller has ``run_domain``: the ones
    after it in the range :func:`~sm_bt.ros.environment.run_domain_id` picks from (10..99), wrapping."""
    return 10 + (run_domain - 10 + 1 + worker) % 90


# Before any test starts rclpy or a ROS process (they inherit it): local discovery, this run's domain.
# prepare() itself needs no rclpy, so this is harmless where ROS 2 is not installed.
sm_bt.ros.environment.prepare(own_domain=True)
# Under pytest-xdist every worker inherits the controller's domain: each takes one of its own next to
# it, so that the nodes one worker's tests start are not seen by another's.
if os.environ.get("PYTEST_XDIST_WORKER", "").startswith("gw"):
    os.environ["ROS_DOMAIN_ID"] = str(worker_domain_id(int(os.environ["ROS_DOMAIN_ID"]),
                                                        int(os.environ["PYTEST_XDIST_WORKER"][2:])))
# `sm-bt mode`/`state` would start a client daemon that outlives the test: tests that want one start
# it themselves, by pid (tests/ros/test_client_daemon.py).
os.environ["SM_BT_DAEMON"] = "0"

# A run started where SIGINT is ignored (a background job of a non-interactive shell) would hand
# that on to every process it starts, and a test that stops one with SIGINT would wait in vain
# (Python installs its KeyboardInterrupt handler only where SIGINT is not ignored at start).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

MODELS = Path(__file__).parent / "models"

# The ROS test fixtures (node_processes, ros_context; the module imports rclpy only when used), the
# requirement markers (skips, or failures under make test), and pytest's own pytester (the
# simulated_system fixture is tested as users run it).
pytest_plugins = ("ros_processes", "needs", "pytester")


@pytest.fixture
def models_dir() -> Path:
    return MODELS


#: Modules whose tests share what a module fixture made (the ROS demo's one run, the demo's recording
#: replayed, the demo's runs that tests only read) or a tally (the fuzz campaigns): under pytest-xdist
#: one worker runs each of them whole, so that it is made once. (xdist's own xdist_group mark groups
#: nothing under pytest 9: it renames node ids through an attribute pytest no longer reads.)
ONE_WORKER = frozenset({"tests/e2e/test_demo_ros.py", "tests/model/test_model_fuzz.py", "tests/e2e/test_demo.py",
                        "tests/view/test_view_replay.py"})


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """Tests go to workers one by one, as with ``-n`` alone, but for the modules of :data:`ONE_WORKER`."""
    from xdist.scheduler import LoadScopeScheduling

    class OneByOne(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0]
            return module if module in ONE_WORKER else nodeid

    return OneByOne(config, log)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "long: takes ten seconds or more (waits on other processes): started first")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The long tests first, so that under pytest-xdist they start while the short ones fill the
    other workers, instead of one of them starting last and holding up the end of the run."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)
