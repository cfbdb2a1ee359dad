"""``sm-bt mission``: a mission tree hosted on ROS 2 from a launch-file style command line (ROS
parameters, or MODEL TREE), serving the system_modes interface while it ticks, ending cleanly on SIGINT."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from ros_processes import DUMPABLE, RosContext, Starter, communicate_or_dump, wait_until
from system_modes_msgs.srv import GetMode

pytestmark = pytest.mark.ros

PILOT_XML = Path(__file__).resolve().parents[2] / "trees" / "pilot" / "pilot.xml"

MISSION = """<root main_tree_to_execute="Mission">
  <BehaviorTree ID="Mission">
    <Sequence name="Mission">
      <ChangeState name="Configure" part="pilot" transition="configure" timeout="10"/>
      <ChangeMode name="f_slow_mode" part="pilot" mode="f_slow_mode" timeout="10"/>
      <WaitForMode name="Slow?" part="pilot" mode="f_slow_mode" timeout="5"/>
      {last}
    </Sequence>
  </BehaviorTree>
</root>
"""


def _host(tmp_path: Path, *parameters: str, positional: tuple[str, ...] = (),
          ros_args: tuple[str, ...] = ()) -> subprocess.Popen[str]:
    """``sm-bt mission [POSITIONAL...] --ros-args [ROS_ARGS...] -p PARAMETER...``"""
    command = [sys.executable, "-m", "sm_bt.cli", "mission", *positional, "--ros-args", *ros_args]
    for parameter in parameters:
        command += ["-p", parameter]
    return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            env={**os.environ, **DUMPABLE})


def _stop(process: subprocess.Popen[str]) -> tuple[int, str]:
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    _, err = communicate_or_dump(process, 8.0)
    return process.returncode, err


@pytest.fixture
def observer() -> Iterator[RosContext]:
    ros = RosContext("sm_bt_test_observer")
    yield ros
    ros.close()


def test_a_hosted_mission_serves_the_interface_and_stops_cleanly_on_sigint(
        node_processes: Starter, observer: RosContext, tmp_path: Path) -> None:
    node_processes("pilot")
    (tmp_path / "mission.xml").write_text(MISSION.format(last='<Running name="Hold on"/>'))
    host = _host(tmp_path, "model:=pilot", "tree:=mission.xml", "rate:=20.0", ros_args=("-r", "__node:=mission"))
    try:
        def mode() -> str:
            return str(observer.call(GetMode, "/pilot/get_mode", GetMode.Request(), timeout=2.0).current_mode)

        wait_until(lambda: host.poll() is not None or mode() == "f_slow_mode", 30.0, "pilot in f_slow_mode")
        assert host.poll() is None, host.stderr.read() if host.stderr else ""
        # The remap names the mission's node only; its helper nodes keep names of their own.
        # (Node names come with the participant's own graph news, which may lag its services'.)
        def names() -> list[str]:
            return sorted(name for name in observer.node.get_node_names() if name.startswith("mission"))

        wait_until(lambda: names() == ["mission", "mission_backend", "mission_watch"], 10.0,
                   "the mission's three nodes under their own names")
    finally:
        code, err = _stop(host)
    assert code == 0, err
    assert "Traceback" not in err, err
    assert "pilot is active.f_slow_mode" in err
    assert "mission RUNNING" in err


def test_a_mission_that_ends_sets_the_exit_status(node_processes: Starter, tmp_path: Path) -> None:
    node_processes("pilot")
    (tmp_path / "mission.xml").write_text(MISSION.format(last='<ModeIs name="Fast?" part="pilot" '
                                                               'mode="f_performance_mode"/>'))
    host = _host(tmp_path, "rate:=20.0", positional=("pilot", "mission.xml"))  # as typed in a shell
    try:
        code, err = host.wait(40.0), ""
    finally:
        code, err = _stop(host)
    assert code == 1, err  # ModeIs fails: the pilot is in f_slow_mode
    assert "mission FAILURE" in err and "Traceback" not in err


@pytest.mark.parametrize(("parameters", "message"), [
    (("model:=pilot",), "give the tree: sm-bt mission MODEL TREE, or as ROS parameters"),
    (("model:=nope.yaml", "tree:=mission.xml"), "nope.yaml: no such file, and no bundled model of that name"),
    (("model:=pilot", "tree:=bad.xml"), "bad.xml:3: error: unknown node <Sequense>"),
    (("model:=pilot", "tree:=mission.xml", "rate:=0.0"), "rate must be more than 0"),
    # the pilot's own trees need its simulated world: said, not a traceback
    (("model:=pilot", f"tree:={PILOT_XML}"), "the tree cannot be set up: BatteryToBlackboard/"),
    (("model:=pilot", "tree:=sm_bt.trees.pilot:create_root"), "run in `sm-bt demo` (or `sm-bt demo --ros`)"),
])
def test_a_wrong_parameter_is_one_error_line_and_exit_1(tmp_path: Path, parameters: tuple[str, ...],
                                                       message: str) -> None:
    (tmp_path / "mission.xml").write_text(MISSION.format(last=""))
    (tmp_path / "bad.xml").write_text('<root>\n  <BehaviorTree ID="M">\n    <Sequense/>\n  </BehaviorTree>\n</root>')
    host = _host(tmp_path, *parameters)
    try:
        host.wait(20.0)
    finally:
        code, err = _stop(host)
    assert code == 1, err
    assert message in err and "Traceback" not in err and "terminate called" not in err, err
