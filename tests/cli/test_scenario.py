"""``sm-bt run --scenario``: faults and outside requests on a timeline, expectations judged, every
mistake of the file with its line (sm_bt.scenario)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sm_bt.cli import main

TREE = """<root main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence name="Mission">
      <ChangeMode part="pilot" mode="f_normal_mode" timeout="10"/>
      <FollowPath path="{path}"/>
      <ModeIs part="pilot" mode="f_degraded_mode"/>
    </Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="FollowPath"><input_port name="path"/></Action>
  </TreeNodesModel>
</root>
"""
STUBS = "FollowPath: {status: running, for: 4.0, then: success}\n"
SCENARIO = """events:
  - {at: 2.0, request: {pilot: f_degraded_mode}}
  - {at: 2.5, fail_next: {node: amcl, transition: cleanup}}
expect:
  - {at: 1.0, modes: {pilot: active.f_normal_mode}}
  - {at: 3.0, modes: {pilot: active.f_degraded_mode, laser_resender: unconfigured}}
  - {never: {amcl: finalized}}
  - {tree: SUCCESS}
"""


def run(capsys: pytest.CaptureFixture[str], tmp_path: Path, scenario: str) -> tuple[int, str, str]:
    for name, text in (("mission.xml", TREE), ("stubs.yaml", STUBS), ("scenario.yaml", scenario)):
        (tmp_path / name).write_text(text)
    code = main(["run", "pilot", str(tmp_path / "mission.xml"), "--stubs", str(tmp_path / "stubs.yaml"),
                 "--scenario", str(tmp_path / "scenario.yaml"), "--speed", "0", "--quiet"])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_scenario_whose_expectations_hold_passes(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, tmp_path, SCENARIO)
    assert (code, err) == (0, ""), out
    assert out.splitlines() == [f"{tmp_path / 'mission.xml'}: SUCCESS at 4.10 s",
                                f"{tmp_path / 'scenario.yaml'}: 5 of 5 expectations held"]


def test_a_changed_expectation_fails_with_what_was_there_and_its_line(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, _ = run(capsys, tmp_path, SCENARIO.replace("{at: 1.0, modes: {pilot: active.f_normal_mode}}",
                                                          "{at: 1.0, modes: {pilot: active.f_slow_mode}}")
                       .replace("{never: {amcl: finalized}}", "{never: {amcl: active}}"))
    assert code == 1
    path = tmp_path / "scenario.yaml"
    assert out.splitlines()[1:] == [
        f"{path}: 3 of 5 expectations held",
        f"  FAILED {path}:7: at 0.10 s amcl is active.__DEFAULT__, which must never be",
        f"  FAILED {path}:5: at 1 s pilot is active.f_normal_mode, expected active.f_slow_mode"]


def test_every_mistake_of_a_scenario_has_its_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, tmp_path, """events:
  - {at: 1, crash: lidar}
  - {at: -2, vanish: amcl}
  - {at: 3, explode: amcl}
  - {at: 4, request: {pilot: f_nrmal_mode}}
  - {at: 5, fail_next: {node: amcl, transition: activte}}
expect:
  - {at: 6, modes: {pilto: active}}
  - {tree: DONE}
  - {whenever: {amcl: active}}
extras: 1
""")
    assert (code, out) == (1, "")
    path = tmp_path / "scenario.yaml"
    assert err.splitlines() == [
        f"{path}:2: error: 'lidar' is not a node of the model",
        f"{path}:3: error: at is seconds of the run (0 or more), not '-2'",
        f"{path}:4: error: no event 'explode' (events: crash, vanish, restart, fail_next, hang_next, "
        "reject_parameters, set_parameter, request, world)",
        f"{path}:5: error: pilot has no mode 'f_nrmal_mode' (did you mean 'f_normal_mode'?) (modes: __DEFAULT__, "
        "f_normal_mode, f_degraded_mode, f_performance_mode, f_energy_saving_mode, f_slow_mode)",
        f"{path}:6: error: 'activte' is not a transition (did you mean 'activate'?) (transitions: configure, "
        "activate, deactivate, cleanup, shutdown)",
        f"{path}:8: error: no part 'pilto' (did you mean 'pilot'?)",
        f"{path}:9: error: tree ends as one of SUCCESS, FAILURE, RUNNING, not 'DONE'",
        f"{path}:10: error: an expectation is {{at: SECONDS, modes: {{PART: STATE[.MODE]}}}}, {{never: {{PART: "
        "STATE[.MODE]}} or {tree: SUCCESS|FAILURE|RUNNING}",
        f"{path}:11: error: no section 'extras' (sections: events, expect, model, tree, stubs, until, world)",
        f"{path}: failed (9 errors)"]


def test_world_events_are_checked_against_the_world_the_scenario_names(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from sm_bt.scenario import load_world

    world = "world: sm_bt.trees.pilot.world:PilotWorld\n"
    events = """events:
  - {at: 1, world: {laser: brokn}}
  - {at: 2, world: {door: open}}
  - {at: 3, world: {laser: broken, battery: low}}
expect:
  - {tree: SUCCESS}
"""
    code, out, err = run(capsys, tmp_path, world + events)
    path = tmp_path / "scenario.yaml"
    assert (code, out) == (1, "")
    assert err.splitlines() == [
        f"{path}:3: error: laser is one of broken, repaired, not 'brokn' (did you mean 'broken'?)",
        f"{path}:4: error: the world has no event 'door' (events: laser)",
        f"{path}:5: error: a world event is {{NAME: VALUE}}, one at a time",
        f"{path}: failed (3 errors)"]
    code, out, err = run(capsys, tmp_path, events.replace("brokn", "broken"))
    assert code == 1 and err.splitlines()[0] == (f"{path}:2: error: a world event needs the scenario's world "
                                                 "(world: MODULE:NAME)")
    for reference, message in (("nowhere.at_all:World", "cannot import nowhere.at_all"),
                               ("sm_bt.trees.pilot.world:Nothing", "sm_bt.trees.pilot.world has no Nothing"),
                               ("sm_bt.trees.pilot.world", "is not MODULE:NAME"),
                               ("sm_bt.trees.pilot.world:World", "is not a world")):
        with pytest.raises(ValueError, match=message):
            load_world(reference)


def test_each_kind_of_event_reaches_the_simulated_nodes(tmp_path: Path) -> None:
    from model_files import bundled

    from sm_bt.engine.events import EventKind
    from sm_bt.scenario import Checks, load_scenario
    from sm_bt.sim import SimulatedSystem

    path = tmp_path / "scenario.yaml"
    path.write_text("""events:
  - {at: 0, fail_next: {node: amcl, transition: configure}}
  - {at: 0, hang_next: {node: controller_server, transition: configure}}
  - {at: 0, reject_parameters: {node: pointcloud_to_laser, reason: busy}}
  - {at: 0, set_parameter: {node: controller_server, name: FollowPath.max_vel_x, value: 0.3}}
  - {at: 0, crash: laser_resender}
  - {at: 2, restart: laser_resender}
  - {at: 3, vanish: laser_resender}
  - {at: 2.5, request: {pilot: f_normal_mode}}
expect:
  - {at: 1.5, modes: {laser_resender: unknown}}
  - {at: 2.5, modes: {laser_resender: unconfigured}}
""")
    system = SimulatedSystem(bundled("pilot"), recovery=False)
    asked: list[str] = []
    system.manager.subscribe(lambda event: asked.append(event.request.requester) if event.request else None,
                             kinds=[EventKind.REQUEST])
    scenario, issues = load_scenario(path, system.model)
    assert issues == []
    checks = Checks(scenario, system)
    for _ in range(40):
        checks.at(system.clock.now())
        system.run(0.1)
    faults = [str(event) for event in system.backend.events if event.kind.value in ("fault", "started", "vanished")]
    for expected in ("armed: next on_configure returns FAILURE", "armed: next configure hangs",
                     "armed: parameter sets rejected (busy)", "parameter FollowPath.max_vel_x changed from outside",
                     "crashed: no more answers", "restarted in unconfigured", "its process ended"):
        assert any(expected in line for line in faults), (expected, faults)
    assert asked and set(asked) == {"operator"}  # the request from outside was made
    assert checks.failures == [] and len(checks.passed) == 2
