"""A mission run on ROS 2 (``sm-bt run --ros``, ``sm-bt test --ros``, :class:`RosSystem`): the
documentation's scenario passes and fails as on simulated nodes, and each of a scenario's faults
is carried out on real node processes and seen by the manager as on a robot."""

from __future__ import annotations

import re
import shutil
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ros_processes import Starter, wait_until

from sm_bt import bundled
from sm_bt.cli import main
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.loader import load_model
from sm_bt.model.states import State

pytestmark = pytest.mark.ros

EXAMPLES = Path(__file__).parents[2] / "docs" / "examples"


def finish(request: object, timeout: float = 15.0) -> None:
    wait_until(lambda: bool(getattr(request, "done", False)), timeout, f"{request} not done")


@pytest.mark.long
def test_the_documented_scenario_passes_and_fails_on_ros_as_on_simulated_nodes(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    for name in ("nav_mission.xml", "nav_stubs.yaml", "nav_scenario.yaml"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    good = tmp_path / "nav_scenario.yaml"
    bad = tmp_path / "nav_scenario_bad.yaml"
    bad.write_text(good.read_text().replace("{at: 3.5, modes: {pilot: active.f_slow_mode,",
                                            "{at: 3.5, modes: {pilot: active.f_degraded_mode,"))
    junit, runs = tmp_path / "results.xml", tmp_path / "runs"
    code = main(["test", str(good), str(bad), "--ros", "--junit", str(junit), "--runs", str(runs)])
    out, err = capsys.readouterr()
    assert (code, err) == (1, ""), out
    lines = out.splitlines()
    assert re.fullmatch(rf"PASSED {re.escape(str(good))}: 6 of 6 expectations held; the tree SUCCESS at "
                        r"\d+\.\d\d s", lines[0]), out
    assert lines[1].startswith(f"FAILED {bad}: 5 of 6 expectations held"), out
    assert lines[2] == f"  {bad}:12: at 3.5 s pilot is active.f_slow_mode, expected active.f_degraded_mode", out
    assert re.fullmatch(rf"  the run: sm-bt view {re.escape(str(runs / 'nav_scenario_bad.jsonl'))} --at 3\.[5-9]",
                        lines[3]), lines[3]
    suite = ET.parse(junit).getroot()
    assert (suite.get("tests"), suite.get("failures")) == ("2", "1")


@pytest.mark.long
def test_each_fault_of_a_scenario_happens_to_the_node_processes() -> None:
    from sm_bt.ros.mission_system import RosSystem

    model = load_model(bundled.path("pilot"))
    with RosSystem(model, "pilot", separate={"laser_resender"}) as system:
        manager = system.manager
        assert system.clock.now() < 1.0  # the run's time starts once every node is reached

        system.fail_next("amcl", Transition.CONFIGURE)
        request = manager.change_state("amcl", "configure")
        finish(request)
        assert not request.succeeded and manager.observation("amcl").state is State.UNCONFIGURED

        system.hang_next("amcl", Transition.CONFIGURE)
        hung = manager.change_state("amcl", "configure", timeout=2.0)
        finish(hung)
        assert not hung.succeeded and "hung in configuring" in hung.reason, hung.reason

        system.reject_parameters("controller_server", "busy")
        request = manager.change_mode("controller_server", "DEGRADED")  # parameters to set
        finish(request)
        assert not request.succeeded and "busy" in request.reason, request.reason
        system.reject_parameters("controller_server", None)

        name, changed = "FollowPath.max_vel_x", 0.15  # not its value now
        assert manager.observation("controller_server").parameters[name] != changed
        system.set_parameter("controller_server", name, changed)
        wait_until(lambda: manager.observation("controller_server").parameters.get(name) == changed, 5.0,
                   "the manager never heard of the parameter's change")

        system.crash("laser_resender")
        wait_until(lambda: not manager.observation("laser_resender").reachable, 10.0,
                   "a stopped process was never reported gone")
        began = time.monotonic()
        system.restart("laser_resender")
        wait_until(lambda: manager.observation("laser_resender").reachable, 15.0, "the restarted node never came back")
        assert manager.observation("laser_resender").state is State.UNCONFIGURED
        assert time.monotonic() - began < 15.0

        system.vanish("laser_resender")
        wait_until(lambda: not manager.observation("laser_resender").reachable, 10.0, "an ended process stayed")
        with pytest.raises(ValueError, match="shares its process with other nodes"):
            system.crash("amcl")
        system.run(0.1)  # the processes a fault ended are no failure of the run


def test_attached_the_run_manages_the_nodes_already_running_and_says_which_faults_need_its_own(
        capsys: pytest.CaptureFixture[str], node_processes: Starter, tmp_path: Path) -> None:
    nodes = node_processes("pilot")
    scenario = tmp_path / "attached.yaml"
    scenario.write_text("events:\n  - {at: 0.5, crash: amcl}\n  - {at: 0.5, fail_next: {node: amcl, transition: "
                        "cleanup}}\nexpect:\n  - {at: 1.0, modes: {pilot: active.f_normal_mode}}\n")
    code = main(["run", "pilot", str(EXAMPLES / "nav_mission.xml"), "--stubs", str(EXAMPLES / "nav_stubs.yaml"),
                 "--ros", "--attach", "--until", "1.5", "--quiet", "--scenario", str(scenario)])
    out, err = capsys.readouterr()
    assert code == 1 and err == "", (out, err)
    assert out.splitlines()[1:] == [
        f"{scenario}: 1 of 3 expectations held",
        f"  FAILED {scenario}:2: the crash at 0.5 s could not be made: sm-bt does not crash a node it did not start "
        "(with --attach, amcl is a real node)",
        f"  FAILED {scenario}:3: the fail_next at 0.5 s could not be made: cannot fail a transition of amcl with "
        "--attach: only sm-bt's simulated nodes take sim.* faults"]
    assert nodes.alive  # attached: the nodes are the user's, left running


def test_ros_options_that_do_not_go_together_are_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    tree = str(EXAMPLES / "nav_mission.xml")
    assert main(["run", "pilot", tree, "--attach"]) == 2
    assert "--attach goes with --ros" in capsys.readouterr().err
    assert main(["run", "pilot", tree, "--ros", "--speed", "0"]) == 2
    assert "with --ros the run is in real time" in capsys.readouterr().err
    assert main(["test", str(EXAMPLES / "nav_scenario.yaml"), "--attach"]) == 2
    assert "--attach goes with --ros" in capsys.readouterr().err
