"""py_trees_ros 2.2.2 and devel with sm_bt: the docs' recipe for hosting a mission in
``py_trees_ros.trees.BehaviourTree`` (docs/ros.md, the block marked ``py_trees_ros``), run as
written, and ``py-trees-blackboard-watcher`` showing ``/system_modes/pilot`` of a mission hosted
there, by ``sm-bt mission`` and by ``sm-bt demo --ros``.

No package index has py_trees_ros, so ``make interop`` exports its sources
(``tools/py_trees_ros.sh``: GitHub or ``SM_BT_GIT_MIRRORS``) and runs this module; ``make test``
only compiles the block. Each version runs the block in a process of its own
(``py_trees_ros_runner.py``) against the pilot's simulated nodes: the mission (configure, then
``f_slow_mode``) must succeed, with the manager attached after py_trees_ros set the tree up, as the
recipe does (2.2.2 cannot pass the manager through ``setup``). Every process is stopped by PID
(SIGINT, then SIGKILL).
"""

from __future__ import annotations

import contextlib
import re
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from functools import cache
from pathlib import Path

import pytest
from ros_processes import Starter

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "ros.md"
RUNNER = Path(__file__).with_name("py_trees_ros_runner.py")
DIRECTIVE = re.compile(r"^<!-- readme-test: py_trees_ros\b.* -->$")


def recipe() -> str:
    """The page's block marked ``py_trees_ros`` (exactly one)."""
    lines = PAGE.read_text(encoding="utf-8").splitlines()
    starts = [i for i, line in enumerate(lines) if DIRECTIVE.match(line)]
    assert len(starts) == 1, f"{PAGE}: {len(starts)} blocks marked py_trees_ros, expected 1"
    fence = starts[0] + 1
    assert lines[fence] == "```python", f"{PAGE}:{fence + 1}: the marked block is not python"
    end = lines.index("```", fence + 1)
    return "\n".join(lines[fence + 1:end]) + "\n"


@cache
def versions() -> dict[str, Path]:
    done = subprocess.run(["bash", str(ROOT / "tools" / "py_trees_ros.sh")], capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    return {line.split()[0]: Path(line.split()[1]) for line in done.stdout.splitlines()}


@pytest.mark.parametrize("version", ["2.2.2", "devel"])
def test_the_docs_recipe_hosts_a_mission_in_py_trees_ros(version: str, node_processes: Starter,
                                                          tmp_path: Path) -> None:
    sources = versions()[version]
    block = tmp_path / "recipe.py"
    block.write_text(recipe())
    node_processes("pilot")
    done = subprocess.run([sys.executable, str(RUNNER), "recipe", str(sources), str(block)], capture_output=True,
                          text=True, timeout=120, check=False)
    last = done.stdout.strip().splitlines()[-1:] or [""]
    assert done.returncode == 0, f"{version}: {last[0]}\n{done.stderr[-3000:]}"
    assert last[0].startswith("mission SUCCESS: pilot is active.f_slow_mode"), last[0]


@contextmanager
def _running(command: list[str], cwd: Path | None = None) -> Iterator[subprocess.Popen[str]]:
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=cwd)
    try:
        yield process
    finally:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
            try:
                process.wait(5.0)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5.0)


def _read_until(process: subprocess.Popen[str], wanted: str, timeout: float) -> list[str]:
    """Lines of ``process``'s stdout until one matches the pattern ``wanted`` (``AssertionError``
    after ``timeout``)."""
    assert process.stdout is not None
    lines: list[str] = []
    with selectors.DefaultSelector() as selector:
        selector.register(process.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if not selector.select(max(0.0, deadline - time.monotonic())):
                break
            line = process.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip("\n"))
            if re.search(wanted, line):
                return lines
    raise AssertionError(f"no line with {wanted!r} within {timeout:g} s; got:\n" + "\n".join(lines[-30:]))


#: The watcher's line (py_trees_ros pads the name, sm_bt does not).
SLOW = r"/system_modes/pilot\s*: active\.f_slow_mode \(target active\.f_slow_mode\)"


def _watch(version: str, wanted: str, *args: str, silence: float | None = None) -> list[str]:
    """Run ``py-trees-blackboard-watcher ARGS`` until it prints ``wanted``. The watcher looks for the
    services for a few seconds only and gives up ("service not found"): on a loaded machine a fresh
    process may need longer to discover them, so it is started again, six times at most. With
    ``silence``, a watcher that shows nothing for that long is started again too (see the caller)."""
    command = [sys.executable, "-u", str(RUNNER), "watch", str(versions()[version]), *args]  # -u: lines as printed
    for attempt in range(6):
        with _running(command) as watcher:
            try:
                return _read_until(watcher, wanted, silence or 30.0)
            except AssertionError:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    watcher.wait(1.0 if silence else 5.0)
                # still running: it found the services, and did not show the line
                if attempt == 5 or (watcher.poll() is None and silence is None):
                    raise
    raise AssertionError("unreachable")


@pytest.mark.parametrize("version", ["2.2.2", "devel"])
def test_the_blackboard_watcher_shows_the_modes_in_a_py_trees_ros_host(version: str, node_processes: Starter,
                                                                        tmp_path: Path) -> None:
    """py_trees_ros serves the blackboard itself there: what sm_bt puts on it must copy and pickle.
    Its exchange closes a stream that has no subscriber yet at a tick (its workaround for readers
    that vanish), so a watcher whose subscription matched after the next tick waits for ever: such a
    watcher is started again."""
    block = tmp_path / "recipe.py"
    block.write_text(recipe())
    node_processes("pilot")
    with _running([sys.executable, "-u", str(RUNNER), "recipe", str(versions()[version]), str(block), "120"]) as host:
        _read_until(host, r"mission SUCCESS", 60.0)
        _watch(version, SLOW, "/system_modes/pilot", silence=10.0)


MISSION = """<root main_tree_to_execute="Mission">
  <BehaviorTree ID="Mission">
    <Sequence name="Mission">
      <ModesToBlackboard name="Modes"/>
      <ChangeState name="Configure" part="pilot" transition="configure" timeout="10"/>
      <ChangeMode name="Slow" part="pilot" mode="f_slow_mode" timeout="10"/>
      <ModesToBlackboard name="Modes again"/>
      <Running name="Hold on"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


@pytest.mark.parametrize("version", ["2.2.2", "devel"])
def test_the_blackboard_watcher_shows_the_modes_of_sm_bt_mission(version: str, node_processes: Starter,
                                                                  tmp_path: Path) -> None:
    (tmp_path / "mission.xml").write_text(MISSION)
    node_processes("pilot")
    with _running([sys.executable, "-m", "sm_bt.cli", "mission", "pilot", "mission.xml", "--rate", "20"], cwd=tmp_path):
        _watch(version, SLOW, "/system_modes/pilot")


def test_the_blackboard_watcher_shows_the_modes_of_the_ros_demo() -> None:
    """The demo's tree writes every part's status; its start, the pilot in its normal mode, shows."""
    with _running([sys.executable, "-m", "sm_bt.cli", "demo", "--ros", "--quiet", "--speed", "5"]):
        _watch("devel", r"/system_modes/pilot: active\.f_normal_mode \(target active\.f_normal_mode\)",
               "/system_modes/pilot")
