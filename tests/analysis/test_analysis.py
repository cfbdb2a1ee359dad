"""sm-bt analyze: each kind of finding on a model crafted with that one flaw (with its file and
line), and silence on the same model without it; the bundled models' findings; the command."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis_profiles import examples
from model_files import bundled
from model_generator import GeneratedModel, generated_models

from sm_bt.analysis import Kind, Level, analyze
from sm_bt.cli import main
from sm_bt.model.loader import load_model

#: A node with a slow and a fast mode.
DRIVE = """\
drive:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          speed: 1.0
      FAST:
        ros__parameters:
          speed: 2.0
      SLOW:
        ros__parameters:
          speed: 0.5
"""
#: A robot: a drive (one node) and a camera, in a system with a normal and a slow mode.
ROBOT = """\
robot:
  ros__parameters:
    type: system
    parts:
      drive
      camera
    modes:
      __DEFAULT__:
        drive: inactive
        camera: inactive
      NORMAL:
        drive: active.FAST
        camera: active
      SLOW:
        drive: active.SLOW
        camera: active
#RULES
""" + DRIVE + """\
#DRIVE_MODES
camera:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          rate: 10
"""


def model_of(tmp_path: Path, text: str, name: str = "robot.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def kinds(path: Path, trees: tuple[Path, ...] = (), faults: int = 1) -> dict[Kind, list[str]]:
    found: dict[Kind, list[str]] = {}
    for finding in analyze(load_model(path), trees, faults=faults).findings:
        found.setdefault(finding.kind, []).append(f"{Path(finding.location.file).name}:{finding.location.line}: "
                                                  f"{finding.level.value}: {finding.message}")
    return found


def line_of(path: Path, text: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if text in line)


def test_a_mode_that_asks_a_shared_node_for_two_modes_is_unreachable(tmp_path: Path) -> None:
    flawed = (ROBOT.replace("      camera\n    modes:", "      camera\n      left\n      right\n    modes:")
              .replace("        camera: inactive\n", "        camera: inactive\n        left: inactive\n"
                       "        right: inactive\n", 1)
              .replace("#RULES\n", "      BOTH:\n        left: active.FAST\n        right: active.SLOW\n")) + """\
left:
  ros__parameters:
    type: system
    parts:
      motor
    modes:
      __DEFAULT__:
        motor: inactive
      FAST:
        motor: active.FAST
right:
  ros__parameters:
    type: system
    parts:
      motor
    modes:
      __DEFAULT__:
        motor: inactive
      SLOW:
        motor: active.SLOW
""" + DRIVE.replace("drive:", "motor:")
    path = model_of(tmp_path, flawed)
    found = kinds(path, faults=0)
    assert found[Kind.UNREACHABLE] == [
        f"robot.yaml:{line_of(path, 'BOTH:')}: error: mode BOTH of robot can never be reached: it asks motor "
        "active.FAST (through left) and active.SLOW (through right)"]
    fixed = model_of(tmp_path, flawed.replace("        motor: active.SLOW\n", "        motor: active.FAST\n"),
                     "ok.yaml")
    assert Kind.UNREACHABLE not in kinds(fixed, faults=0)


def test_a_node_mode_no_system_mode_asks_for_is_reached_only_as_an_override(tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT.replace("#DRIVE_MODES\n", "      TURBO:\n        ros__parameters:\n"
                                                            "          speed: 4.0\n"))
    assert kinds(path, faults=0)[Kind.OVERRIDE_ONLY] == [
        f"robot.yaml:{line_of(path, 'TURBO:')}: warning: mode TURBO of drive: no mode of robot (or the systems above "
        "it) asks for it, so only a direct request reaches it, and the manager takes that for an override of "
        "robot's target"]
    assert Kind.OVERRIDE_ONLY not in kinds(model_of(tmp_path, ROBOT, "ok.yaml"), faults=0)


def test_two_system_modes_with_the_same_configuration_are_ambiguous(tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT.replace("        drive: active.SLOW\n", "        drive: active.FAST\n"))
    [finding] = kinds(path, faults=0)[Kind.AMBIGUOUS]
    assert finding.startswith(f"robot.yaml:{line_of(path, 'SLOW:')}: warning: modes NORMAL and SLOW of robot cannot "
                              "be told apart")
    assert finding.endswith("and with none inference reports NORMAL")
    assert Kind.AMBIGUOUS not in kinds(model_of(tmp_path, ROBOT, "ok.yaml"), faults=0)


CIRCLE = """\
    rules:
      slow_down:
        if_target: active.NORMAL
        if_part: [drive, unconfigured]
        new_target: active.SLOW
      speed_up:
        if_target: active.SLOW
        if_part: [drive, unconfigured]
        new_target: active.NORMAL
"""


def test_rules_that_go_round_in_a_circle_on_one_fault_are_an_error(tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", CIRCLE))
    found = analyze(load_model(path), faults=1)
    circles = [f for f in found.findings if f.kind is Kind.RULE_PING_PONG]
    static = [f for f in circles if f.location.line == line_of(path, "slow_down:")]
    assert static and static[0].level is Level.ERROR and static[0].example == (
        "active.NORMAL -> active.SLOW -> active.NORMAL")
    # The runs show it too: the drive fails in NORMAL, and the rules switch robot back and forth.
    ran = [f for f in circles if f.location.line == line_of(path, "robot:")]
    assert ran and "active.SLOW (rule slow_down) -> active.NORMAL (rule speed_up) -> active.SLOW" in ran[0].example
    one_way = model_of(tmp_path, ROBOT.replace("#RULES\n", CIRCLE.split("      speed_up:")[0]), "ok.yaml")
    assert Kind.RULE_PING_PONG not in kinds(one_way)


def test_a_rule_a_mode_change_sets_off_half_way_is_the_pattern_of_system_modes_94(tmp_path: Path) -> None:
    """The DMARCE benchmark's guard: a rule of SLOW watches the drive in what NORMAL asks of it."""
    guard = ("    rules:\n      back_to_normal:\n        if_target: active.SLOW\n"
             "        if_part: [drive, active.FAST]\n        new_target: active.NORMAL\n")
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", guard))
    [finding] = kinds(path, faults=0)[Kind.RULE_UNDOES_REQUEST]
    assert finding.startswith(f"robot.yaml:{line_of(path, 'back_to_normal:')}: warning: rule back_to_normal of robot "
                              "fires when drive is active.FAST while robot should be active.SLOW, which is what mode "
                              "NORMAL asks of drive")
    faulty = model_of(tmp_path, ROBOT.replace("#RULES\n", guard.replace("active.FAST]", "unconfigured]")), "ok.yaml")
    assert Kind.RULE_UNDOES_REQUEST not in kinds(faulty, faults=0)


def test_a_fault_no_rule_handles_is_a_warning_and_a_rule_for_it_silences_it(tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT)
    unhandled = kinds(path)[Kind.FAULT_UNHANDLED]
    assert "robot.yaml:1: warning: a crash or loss of camera leaves robot diverged and no rule of it reacts (from " \
           "__DEFAULT__, NORMAL, SLOW)" in unhandled
    handled = ROBOT.replace("#RULES\n", """\
      BLIND:
        drive: active.SLOW
        camera: __DONTCARE__
    rules:
      blind_in_normal:
        if_target: active.NORMAL
        if_part: [camera, unknown]
        new_target: active.BLIND
      blind_in_slow:
        if_target: active.SLOW
        if_part: [camera, unknown]
        new_target: active.BLIND
""")
    fixed = model_of(tmp_path, handled, "ok.yaml")
    left = kinds(fixed).get(Kind.FAULT_UNHANDLED, [])
    # A crash or loss of the camera in NORMAL or SLOW is handled now; in __DEFAULT__ no rule watches.
    assert "ok.yaml:1: warning: a crash or loss of camera leaves robot diverged and no rule of it reacts (from " \
           "__DEFAULT__)" in left, left


def test_a_rule_no_fault_sets_off_never_fires(tmp_path: Path) -> None:
    never = ("    rules:\n      on_finalized:\n        if_target: active.NORMAL\n"
             "        if_part: [drive, finalized]\n        new_target: active.SLOW\n")
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", never))
    [finding] = kinds(path)[Kind.RULE_NEVER_FIRES]
    assert re.fullmatch(rf"robot.yaml:{line_of(path, 'on_finalized:')}: warning: rule on_finalized of robot fired in "
                        r"none of \d+ runs with faults \(crash, failure, deactivation, loss\) of its nodes: it "
                        r"waits for drive to be finalized while robot is active\.NORMAL", finding), finding
    fires = model_of(tmp_path, ROBOT.replace("#RULES\n", never.replace("finalized]", "unconfigured]")), "ok.yaml")
    assert Kind.RULE_NEVER_FIRES not in kinds(fires)


TREE = """\
<root main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence>
#WATCH
      <ChangeMode name="Go" part="robot" mode="NORMAL"/>
    </Sequence>
  </BehaviorTree>
</root>
"""


def test_a_tree_request_a_fault_makes_unreachable_needs_a_contingency(tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT)
    tree = tmp_path / "mission.xml"
    tree.write_text(TREE.replace("#WATCH\n", ""))
    found = kinds(path, (tree,))
    assert found[Kind.TREE_UNREACHABLE] == [
        f"mission.xml:{line_of(tree, '<ChangeMode')}: warning: the tree asks for robot NORMAL, which a fault of drive, "
        "camera makes unreachable, and no contingency of the tree (OnDivergence, SwitchOnDivergence) watches them"]
    assert found[Kind.TREE_UNASKED] == ["robot.yaml:1: note: no tree asks for robot SLOW, robot __DEFAULT__"]
    every = tmp_path / "every.xml"
    every.write_text(TREE.replace("#WATCH\n", '      <ChangeMode part="robot" mode="SLOW"/>\n'
                                              '      <ChangeMode part="robot" mode="__DEFAULT__"/>\n'))
    assert Kind.TREE_UNASKED not in kinds(path, (every,), faults=0)
    watched = tmp_path / "watched.xml"
    watched.write_text(TREE.replace("#WATCH\n", '      <SwitchOnDivergence name="Lost" system="robot" mode="SLOW"/>\n'))
    assert Kind.TREE_UNREACHABLE not in kinds(path, (watched,))


def test_the_bundled_models_findings_are_the_ones_the_readme_explains() -> None:
    pilot = analyze(bundled("pilot"), faults=1)
    assert not pilot.errors
    assert sorted({(f.kind, f.level) for f in pilot.findings}) == sorted(
        {(Kind.AMBIGUOUS, Level.WARNING), (Kind.FAULT_UNHANDLED, Level.WARNING)})
    rules = analyze(bundled("pilot_rules"), faults=2)
    assert {f.kind for f in rules.findings} == {Kind.AMBIGUOUS, Kind.FAULT_UNHANDLED, Kind.RULE_UNDOES_REQUEST}
    assert any(rule == "degrade_from_normal" for o in rules.outcomes for rule, _, _ in o.rules)


def test_the_command_prints_findings_with_lines_and_json(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", CIRCLE))
    assert main(["analyze", str(path)]) == 1  # an error: the circle
    out = capsys.readouterr().out
    assert f"{path}:{line_of(path, 'slow_down:')}: error: rules slow_down, speed_up of robot go round" in out
    assert out.splitlines()[-1].startswith(f"{path}: 3 errors, ")  # the circle, and two runs that show it
    assert main(["analyze", "pilot", "--json", "--faults", "0"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {f["kind"] for f in data["findings"]} == {"ambiguous"} and data["faults"] == []
    assert main(["analyze", "pilot", "--table", "--faults", "1"]) == 0
    out = capsys.readouterr().out
    assert "  from the start (every node unconfigured): change_mode pilot f_degraded_mode: 8 calls\n" in out
    assert "  pilot=active.f_normal_mode, crash of amcl: pilot unknown (diverged: part state unknown (amcl: no " \
           "answer for 1.0 s (crashed?))); no rule; 3.0 s\n" in out
    bad_tree = tmp_path / "bad.xml"
    bad_tree.write_text(TREE.replace("#WATCH\n", "").replace('mode="NORMAL"', 'mode="NORMALL"'))
    assert main(["analyze", str(path), str(bad_tree)]) == 1
    assert "NORMALL" in capsys.readouterr().err


def test_check_deep_runs_the_analysis(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", CIRCLE))
    assert main(["check", str(path)]) == 0  # well formed
    assert main(["check", str(path), "--deep"]) == 1  # and wrong
    out = capsys.readouterr().out
    assert "error: rules slow_down, speed_up of robot go round in a circle" in out
    assert main(["check", "pilot", "--deep"]) == 0


def test_alike_nodes_are_run_once_for_all_of_them(tmp_path: Path) -> None:
    """Two nodes alike up to their names and values (what inference tells apart is the same) run
    once; a node its system asks for something else stands alone."""
    from sm_bt.analysis.symmetry import alike_nodes

    twins = ROBOT.replace("      camera\n    modes:", "      camera\n      camera2\n    modes:").replace(
        "        camera: inactive\n", "        camera: inactive\n        camera2: inactive\n", 1).replace(
        "        camera: active\n", "        camera: active\n        camera2: active\n") + (
        "camera2:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n"
        "        ros__parameters:\n          rate: 30\n")
    model = load_model(model_of(tmp_path, twins))
    assert alike_nodes(model) == {"drive": [], "camera": ["camera2"]}
    analysis = analyze(model)
    assert all(fault.node != "camera2" for outcome in analysis.outcomes for fault in outcome.faults)
    assert any("of camera (or of camera2, a node like it)" in f.message for f in analysis.findings)
    apart = load_model(model_of(tmp_path, twins.replace("        camera2: active\n", "        camera2: inactive\n",
                                                        1), "apart.yaml"))
    assert alike_nodes(apart) == {"drive": [], "camera": [], "camera2": []}


#: The model of system_modes #94 (DMARCE's safety benchmark): a guard node's own mode switches the
#: system, both ways.
SAFETY = """\
safety:
  ros__parameters:
    type: system
    parts:
      manipulator
      guard
    modes:
      __DEFAULT__:
        manipulator: active.__DEFAULT__
        guard: active.__DEFAULT__
      COMPROMISED:
        manipulator: active.COMPROMISED
        guard: active.COMPROMISED
    rules:
      guard_detect_compromise_in_default:
        if_target: active.__DEFAULT__
        if_part: [guard, active.COMPROMISED]
        new_target: active.COMPROMISED
      guard_detect_default_in_compromise:
        if_target: active.COMPROMISED
        if_part: [guard, active.__DEFAULT__]
        new_target: active.__DEFAULT__
manipulator:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          max_torque: 0.5
      COMPROMISED:
        ros__parameters:
          max_torque: 0.1
guard:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          compromised: false
      COMPROMISED:
        ros__parameters:
          compromised: true
"""


def test_the_guard_triggered_rules_of_system_modes_94_are_found(tmp_path: Path) -> None:
    path = model_of(tmp_path, SAFETY, "safety.yaml")
    found = kinds(path, faults=0)[Kind.RULE_UNDOES_REQUEST]
    assert [f.split(": warning: ")[0] for f in found] == [
        f"safety.yaml:{line_of(path, 'guard_detect_compromise_in_default:')}",
        f"safety.yaml:{line_of(path, 'guard_detect_default_in_compromise:')}"]
    assert "a change from __DEFAULT__ to active.COMPROMISED passes through that" in found[1]


def test_a_rule_with_the_condition_of_an_earlier_one_is_shadowed(tmp_path: Path) -> None:
    rules = CIRCLE.split("      speed_up:")[0] + ("      stop_all:\n        if_target: active.NORMAL\n"
                                                 "        if_part: [drive, unconfigured]\n"
                                                 "        new_target: active.__DEFAULT__\n")
    path = model_of(tmp_path, ROBOT.replace("#RULES\n", rules))
    assert kinds(path, faults=0)[Kind.RULE_SHADOWED] == [
        f"robot.yaml:{line_of(path, 'stop_all:')}: warning: rule stop_all of robot never fires: slow_down has the "
        "same condition (drive unconfigured while active.NORMAL) and comes first (rules are tried in order of "
        "name), sending robot to active.SLOW instead of active.__DEFAULT__"]
    assert Kind.RULE_SHADOWED not in kinds(model_of(tmp_path, ROBOT.replace("#RULES\n", CIRCLE), "ok.yaml"),
                                           faults=0)


@examples(50, stress=2000)
@given(generated_models())
def test_any_model_is_analysed_and_every_finding_has_its_file_and_line(generated: GeneratedModel) -> None:
    model = generated.load()
    analysis = analyze(model, faults=1)
    for finding in analysis.findings:
        assert finding.location.file == model.path and finding.location.line > 0, finding
    assert analysis.outcomes, "no fault run: every model has nodes and a top system"
    json.dumps(analysis.as_json())
