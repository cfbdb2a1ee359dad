"""``sm-bt demo --fleet --ros``: the fleet's shift over two robots that are real processes (each the pilot's
simulated nodes and its own ``sm-bt manager``), robot1's manager frozen and let go on meanwhile.

It tells the same story as the simulated fleet (tests/e2e/test_demo.py), and what each robot's own manager
says at the end is what the fleet says; every process it started is gone afterwards. It inherits the
session's ROS environment (conftest: local discovery, a domain id of this run's own).
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import signal
import subprocess
import sys
import time

import pytest
from rich.console import Console
from ros_processes import DUMPABLE, communicate_or_dump
from tree_helpers import assert_in_order

from sm_bt.cli import main
from sm_bt.trees.fleet.demo import FleetDemo, FleetOptions
from sm_bt.trees.fleet.ros_platform import RosFleet

pytestmark = pytest.mark.ros

#: What either fleet tells, in order: the day shift, robot1 lost and the rule's night (which cannot reach it
#: yet), robot1 back and brought to the night, the end of the shift. (robot2 is put to rest after the rule,
#: before or after robot1 is back.)
STORY = (
    "change_mode fleet __DEFAULT__ started [tree]",
    "change_mode fleet __DEFAULT__ succeeded",
    "robot1: target active.__DEFAULT__, actual unknown (fault: no answer from the manager of robot1",
    "fleet !! rule robot1_lost: robot1 is unknown -> active.NIGHT",
    "restore robot1 to active.f_energy_saving_mode succeeded",
    "change_state fleet deactivate succeeded",
    "shift SUCCESS",
)
RULE, ROBOT2_AT_REST = STORY[3], "restore robot2 to inactive succeeded"


def _rests_robot2_after_the_rule(text: str) -> None:
    assert text.find(ROBOT2_AT_REST) > text.find(RULE) >= 0, text


@pytest.mark.long
def test_the_fleet_demo_on_ros_runs_the_shift_over_real_processes_and_stops_them() -> None:
    out = io.StringIO()
    demo = FleetDemo(FleetOptions(ros=True), Console(file=out, width=250, highlight=False))
    platform = demo.platform
    assert isinstance(platform, RosFleet)
    code = demo.run()
    text = out.getvalue()
    assert code == 0, text
    assert_in_order(text, ["robots started: robot1 (nodes pid", "the fleet's manager fleet_manager has read robot1, "
                           "robot2", *STORY[:2], "robot1's manager is frozen (SIGSTOP)", *STORY[2:4],
                           "robot1's manager goes on (SIGCONT)", *STORY[4:], "robots, by their own managers: robot1 "
                           "inactive, robot2 inactive; as the fleet sees them: robot1 inactive, robot2 inactive",
                           "as expected"])
    _rests_robot2_after_the_rule(text)
    # Each robot's own requests, as its manager ends them (request_outcome), in the narrative.
    for robot, said in (("robot1", "change_mode pilot __DEFAULT__ [fleet] succeeded"),
                        ("robot2", "change_mode pilot __DEFAULT__ [fleet] succeeded"),
                        ("robot2", "change_state pilot deactivate [fleet] succeeded"),
                        ("robot1", "change_mode pilot f_energy_saving_mode [fleet] succeeded"),
                        ("robot1", "change_state pilot deactivate [fleet] succeeded")):
        assert f"{robot}'s manager <- request #" in text and said in text, (robot, said, text)
    left = [process.pid for process in platform.processes if process.alive]
    assert not left, f"processes left running: {left}"


def test_the_simulated_fleet_demo_tells_the_same_story() -> None:
    out = io.StringIO()
    assert FleetDemo(FleetOptions(speed=0.0), Console(file=out, width=250, highlight=False)).run() == 0
    text = out.getvalue()
    assert_in_order(text, [*STORY[:2], "robot1 is cut off from the fleet", *STORY[2:4], "robot1 is reachable again",
                           *STORY[4:]])
    _rests_robot2_after_the_rule(text)


def test_the_fleet_demo_on_ros_runs_in_real_time(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--fleet", "--ros", "--speed", "0"]) == 2
    assert "--fleet --ros runs in real time: --speed paces the simulated fleet only" in capsys.readouterr().err


def test_sigterm_stops_the_fleet_demo_on_ros_and_every_robot_process() -> None:
    """An operator's ``kill`` (SIGTERM) mid-shift unwinds as Ctrl-C does: the robots' four processes stop too."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **DUMPABLE}
    demo = subprocess.Popen([sys.executable, "-m", "sm_bt.cli", "demo", "--fleet", "--ros"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    children: list[int] = []
    try:
        assert demo.stdout is not None
        deadline = time.monotonic() + 60.0
        for line in demo.stdout:  # the set-up says the robots' pids, then the shift starts
            if "robots started:" in line:
                children = [int(pid) for pid in re.findall(r"pid (\d+)", line)]
            if "fleet shift over" in line or time.monotonic() > deadline:
                break
        assert len(children) == 4, demo.stderr.read() if demo.stderr else ""
        demo.send_signal(signal.SIGTERM)
        _, err = communicate_or_dump(demo, 20.0)
        assert demo.returncode == 130 and "sm-bt: interrupted" in err, err
        for pid in children:
            with pytest.raises(ProcessLookupError):
                os.kill(pid, 0)
        children = []  # gone: their pids are not ours any more
    finally:
        if demo.poll() is None:  # only if the test failed half-way: SIGINT, then SIGKILL
            demo.send_signal(signal.SIGINT)
            with contextlib.suppress(subprocess.TimeoutExpired):
                demo.wait(5.0)
            if demo.poll() is None:
                demo.kill()
                demo.wait(5.0)
        for pid in children:  # still there (the demo left them): by the pids it gave
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
