"""The ``sm-bt`` console script: ``check`` and ``modes``, error paths and exit codes."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from sm_bt.cli import COMMANDS, main
from sm_bt.cli.common import bundled_names
from sm_bt.cli.modes import format_value

MODELS = Path(__file__).parents[1] / "models"
OK = MODELS / "cli_ok.yaml"
BAD = MODELS / "cli_bad.yaml"
LENIENT = MODELS / "cli_lenient.yaml"


def run(capsys: pytest.CaptureFixture[str], *argv: str | Path) -> tuple[int, str, str]:
    code = main([str(arg) for arg in argv])
    out, err = capsys.readouterr()
    return code, out, err


# -- check -------------------------------------------------------------------------------------


def test_check_ok(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "check", OK)
    assert code == 0
    assert out.splitlines()[0] == f"{OK}: ok (2 systems, 5 nodes)"
    assert err == ""


def test_check_bad_model_reports_every_error_with_its_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "check", BAD)
    assert code == 1
    assert out == ""
    lines = err.splitlines()
    errors = [line for line in lines if ": error: " in line]
    assert len(errors) == 2, err
    assert errors[0].startswith(f"{BAD}:10: error: ")
    assert "'inactive'" in errors[0]  # tells how to fix the upper-case label
    assert errors[1].startswith(f"{BAD}:21: error: ")
    assert "'wrong'" in errors[1]
    assert lines[-1] == f"{BAD}: failed (2 errors)"
    assert "Traceback" not in err


def test_check_several_models_fails_if_any_fails(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "check", OK, BAD)
    assert code == 1
    assert f"{OK}: ok" in out
    assert f"{BAD}: failed" in err


def test_check_missing_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    missing = tmp_path / "nope.yaml"
    code, out, err = run(capsys, "check", missing)
    assert code == 1
    assert out == ""
    assert err.splitlines() == [f"sm-bt: error: {missing}: no such file, and no bundled model of that name "
                                f"(bundled: {', '.join(bundled_names()) or 'none'})"]


def test_check_unknown_bundled_name(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "check", "no_such_model_anywhere")
    assert code == 1
    assert err.startswith("sm-bt: error: no_such_model_anywhere: no such file")


def test_check_directory(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, "check", tmp_path)
    assert (code, out) == (1, "")
    assert str(tmp_path) in err
    assert "directory" in err.lower()
    assert "Traceback" not in err


def test_check_tells_scenarios_and_stubs_from_models_and_checks_what_a_scenario_names(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    examples = Path(__file__).parents[2] / "docs" / "examples"
    for name in ("nav_mission.xml", "nav_stubs.yaml", "nav_scenario.yaml"):
        (tmp_path / name).write_text((examples / name).read_text())
    code, out, err = run(capsys, "check", tmp_path)
    assert (code, err) == (0, "")
    assert out.splitlines() == [
        f"{tmp_path / 'nav_scenario.yaml'}: ok (scenario: 3 events, 5 expectations, against pilot)",
        f"{tmp_path / 'nav_mission.xml'}: ok against pilot",
        f"{tmp_path / 'nav_stubs.yaml'}: ok (stubs)",
        f"{tmp_path / 'nav_mission.xml'}: ok against pilot",
        "3 files checked, 0 failed"]
    scenario = tmp_path / "nav_scenario.yaml"
    scenario.write_text(scenario.read_text().replace("crash: laser_resender", "crash: laser_resendr"))
    (tmp_path / "nav_stubs.yaml").write_text("FollowPath: {status: runing}\n")
    code, out, err = run(capsys, "check", tmp_path)
    assert code == 1
    assert f"{scenario}:8: error: 'laser_resendr' is not a node of the model (did you mean 'laser_resender'?)" in err
    assert f"{tmp_path / 'nav_stubs.yaml'}:1: error:" in err and "3 files checked, 2 failed" in err


def test_check_invalid_yaml(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    broken = tmp_path / "broken.yaml"
    broken.write_text("a:\n  ros__parameters:\n    type: [node\n")
    code, _, err = run(capsys, "check", broken)
    assert code == 1
    assert f"{broken}:" in err
    assert "Traceback" not in err


def test_check_lenient_downgrades_undefined_part(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "check", LENIENT)
    assert code == 1
    assert f"{LENIENT}:12: error: " in err
    assert "ghost" in err

    code, out, err = run(capsys, "check", "--lenient", LENIENT)
    assert code == 0
    assert err == ""
    lines = out.splitlines()
    assert lines[0] == f"{LENIENT}: ok (1 system, 1 node)"
    assert any(line.startswith(f"{LENIENT}:12: warning: ") and "ghost" in line for line in lines[1:])


def test_check_bundled_models_by_name(capsys: pytest.CaptureFixture[str]) -> None:
    assert set(bundled_names()) >= {"pilot", "actuation"}
    for name in bundled_names():
        code, out, err = run(capsys, "check", name)
        assert code == 0, err
        assert out.startswith(f"{name}: ok (")


def test_check_pilot_by_name(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "check", "pilot")
    assert code == 0
    assert out.startswith("pilot: ok (1 system, ")


def test_a_file_wins_over_a_bundled_name(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "pilot").write_text(OK.read_text())
    monkeypatch.chdir(tmp_path)
    code, out, _ = run(capsys, "check", "pilot")
    assert code == 0
    assert out.startswith("pilot: ok (2 systems, 5 nodes)")


def test_check_a_tree_file_against_the_model_given_with_it(capsys: pytest.CaptureFixture[str],
                                                         tmp_path: Path) -> None:
    from sm_bt.trees import pilot

    code, out, err = run(capsys, "check", "pilot", pilot.XML)
    assert (code, err) == (0, "")
    assert out.splitlines()[-1] == f"{pilot.XML}: ok against pilot"
    bad = tmp_path / "bad.xml"
    bad.write_text('<root>\n  <BehaviorTree ID="M">\n    <Sequence>\n      <ModeIs part="pilto" mode="x"/>\n'
                   '      <Bogus/>\n    </Sequence>\n  </BehaviorTree>\n</root>\n')
    code, out, err = run(capsys, "check", "pilot", bad, pilot.XML)
    assert code == 1
    assert err.splitlines() == [f"{bad}:4: error: <ModeIs 'ModeIs'>: unknown part 'pilto' (did you mean 'pilot'?) "
                                "(parts: pilot, amcl, controller_server, pointcloud_to_laser, laser_resender)",
                                f"{bad}:5: error: unknown node <Bogus> (declare it in <TreeNodesModel> to run it as a "
                                "stand-in, or pass its class in registry=)", f"{bad}: failed (2 errors against pilot)",
                                "3 files checked, 1 failed"]
    assert out.splitlines()[-1] == f"{pilot.XML}: ok against pilot"  # the other files are still checked


def test_the_projects_own_models_and_trees_check_clean(capsys: pytest.CaptureFixture[str]) -> None:
    """The shipped tree names its model (<!-- sm_bt model: pilot -->): not checked against the others;
    the pilot's scenarios are checked as scenarios, with the tree they name."""
    root = Path(__file__).resolve().parents[2]
    code, out, err = run(capsys, "check", root / "models", root / "trees")
    assert (code, err) == (0, ""), err
    scenarios = root / "trees" / "pilot" / "scenarios"
    assert f"{scenarios / 'laser_failure.yaml'}: ok (scenario: 2 events, 5 expectations, against pilot)" in out
    assert out.splitlines()[-2:] == [f"{root / 'trees' / 'pilot' / 'pilot.xml'}: ok against pilot",
                                     "8 files checked, 0 failed"]  # fleet.yaml among the models


def test_a_tree_is_checked_against_the_model_it_names_or_model_or_each_given_saying_which(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    tree = ('<root>\n  <BehaviorTree ID="M">\n    <ModeIs part="pilot" mode="f_normal_mode"/>\n'
            '  </BehaviorTree>\n</root>\n')
    (tmp_path / "plain.xml").write_text(tree)
    code, _, err = run(capsys, "check", "pilot", "actuation", tmp_path / "plain.xml")
    assert code == 1 and err.splitlines()[0].startswith(f"{tmp_path / 'plain.xml'}:3: error: ") \
        and err.splitlines()[0].endswith(" [against actuation]"), err
    assert f"{tmp_path / 'plain.xml'}: failed (1 error against actuation)" in err.splitlines()
    assert run(capsys, "check", "actuation", tmp_path / "plain.xml", "--model", "pilot")[0] == 0
    (tmp_path / "named.xml").write_text("<!-- sm_bt model: pilot -->\n" + tree)
    code, out, err = run(capsys, "check", "actuation", tmp_path / "named.xml")
    assert (code, err) == (0, "") and f"{tmp_path / 'named.xml'}: ok against pilot" in out
    (tmp_path / "lost.xml").write_text("<!-- sm_bt model: robot.yaml -->\n" + tree)
    code, out, err = run(capsys, "check", tmp_path / "lost.xml")
    assert code == 1 and f"{tmp_path / 'lost.xml'}: failed (its model {tmp_path / 'robot.yaml'} does not load)" in err


# -- modes -------------------------------------------------------------------------------------


def test_modes_prints_the_hierarchy(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "modes", OK)
    assert code == 0, err
    assert err == ""
    lines = out.splitlines()
    expected = [
        "system robot",
        "  parts: base, arm, sensors",
        "  modes:",
        "    * __DEFAULT__",
        "        base: active.__DEFAULT__",
        "        arm: inactive",
        "        sensors: active.__DEFAULT__",
        "        order: sensors -> base, arm",
        "      FAST",
        "        base: active.FAST",
        "        arm: (keep)",
        "        sensors: active.__DEFAULT__",
        "        order: sensors -> base, arm",
        "      SAFE",
        "        base: active.SLOW",
        "        arm: inactive",
        "        sensors: active.FULL",
        "        order: sensors -> base, arm",
        "  rules:",
        "    slow_down: if target active.FAST and sensors is inactive -> active.SAFE",
        "  system sensors",
        "    parts: lidar, camera",
        "    modes:",
        "      * __DEFAULT__",
        "          lidar: active.__DEFAULT__",
        "          camera: inactive",
        "        FULL",
        "          lidar: active.HIGH",
        "          camera: active.__DEFAULT__",
    ]
    start = lines.index("system robot")
    assert lines[start:start + len(expected)] == expected


def test_modes_lists_every_node_with_full_parameter_sets(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "modes", OK)
    assert code == 0
    lines = out.splitlines()
    base = lines.index("  node base (part of robot)")
    assert lines[base:base + 12] == [
        "  node base (part of robot)",
        "    modes:",
        "      * __DEFAULT__",
        "          max_speed: 0.5  ~ tolerance 0.05",
        "          controller: 'pid'",
        "        FAST",
        "          max_speed: 2.0  ~ tolerance 0.05",
        "          controller: 'pid'",
        "        SLOW",
        "          max_speed: 0.2  ~ [0.1, 0.3]",
        "          controller: 'pid'",
        "  node arm (part of robot)",
    ]
    assert "          exposure: 1000.0" in lines  # 1e3 is a double in ROS 2
    assert "  node lidar (part of sensors)" in lines
    logger = lines.index("  node logger (in no system)")
    assert lines[logger:logger + 6] == [
        "  node logger (in no system)",
        "    modes:",
        "      * QUIET",
        "          level: 20",
        "        VERBOSE",
        "          level: 10",
    ]
    # Nodes come after every system.
    assert logger > lines.index("  system sensors")


def test_modes_and_check_show_remote_parts_by_their_manager_and_mode_names(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "fleet.yaml"
    path.write_text("fleet:\n  ros__parameters:\n    type: system\n    modes:\n      __DEFAULT__:\n"
                    "        robot1: active\n        robot2: inactive\n"
                    "robot1:\n  ros__parameters:\n    type: remote\n    manager: /robot1\n    system: pilot\n"
                    "    modes: [__DEFAULT__, NIGHT]\n"
                    "robot2:\n  ros__parameters:\n    type: remote\n    modes: [__DEFAULT__]\n")
    code, out, err = run(capsys, "modes", path)
    assert (code, err) == (0, "")
    lines = out.splitlines()
    assert lines[0] == f"model {path}: 1 system, 0 nodes, 2 remote parts"
    start = lines.index("nodes and remote parts")
    assert lines[start + 1:start + 5] == [
        "  remote robot1 (pilot of the manager at /robot1, part of fleet)",
        "    modes: *__DEFAULT__, NIGHT",
        "  remote robot2 (robot2 of the manager at /, part of fleet)",
        "    modes: *__DEFAULT__",
    ]
    assert run(capsys, "check", path)[1] == f"{path}: ok (1 system, 0 nodes, 2 remote parts)\n"


def test_modes_error_handling(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, out, err = run(capsys, "modes", BAD)
    assert (code, out) == (1, "")
    assert f"{BAD}:10: error: " in err

    code, out, err = run(capsys, "modes", tmp_path / "missing.yaml")
    assert (code, out) == (1, "")
    assert err.startswith("sm-bt: error: ")


def test_modes_lenient_prints_warnings_to_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "modes", "--lenient", LENIENT)
    assert code == 0
    assert f"{LENIENT}:12: warning: " in err
    assert "system system" in out.splitlines()


def test_modes_bundled_pilot(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "modes", "pilot")
    assert code == 0
    assert "system pilot" in out.splitlines()


def test_format_value() -> None:
    assert format_value(True) == "true"
    assert format_value(8) == "8"
    assert format_value(1e3) == "1000.0"
    assert format_value("yes") == "'yes'"
    assert format_value((1.0, 2.5)) == "[1.0, 2.5]"
    assert format_value(float("inf")) == ".inf"


# -- usage -------------------------------------------------------------------------------------


def test_usage_errors_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 2
    assert main(["frobnicate"]) == 2
    assert main(["check"]) == 2
    assert main(["modes", str(OK), str(OK)]) == 2
    err = capsys.readouterr().err
    assert "usage: sm-bt" in err
    assert "Traceback" not in err


def test_help_lists_every_command(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command.name in out
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("sm-bt ")


def test_a_command_imports_its_own_module_not_the_others() -> None:
    """A command's start is what a robot's launch file and every `sm-bt mode` wait for: the other
    commands' modules (the demo, the analysis, ROS) are not imported for it."""
    probe = ("import sys; from sm_bt.cli import main; code = main(['check', sys.argv[1]]); "
             "print(sorted(m for m in sys.modules if m.startswith(('sm_bt.cli.', 'sm_bt.analysis', 'rclpy', "
             "'importlib.metadata')))); "
             "sys.exit(code)")
    done = subprocess.run([sys.executable, "-c", probe, str(OK)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    loaded = done.stdout.splitlines()[-1]
    assert "'sm_bt.cli.check'" in loaded, loaded
    # importlib.metadata is for --version alone: a fifth of this command's start
    for other in ("sm_bt.cli.demo", "sm_bt.cli.analyze", "sm_bt.cli.remote", "sm_bt.analysis", "rclpy",
                  "importlib.metadata"):
        assert f"'{other}" not in loaded, loaded


def test_console_script() -> None:
    script = Path(sys.executable).with_name("sm-bt")
    assert script.exists(), f"console script not installed next to {sys.executable}"
    ok = subprocess.run([str(script), "check", str(OK)], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith(f"{OK}: ok (2 systems, 5 nodes)")
    bad = subprocess.run([str(script), "check", str(BAD)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1
    assert f"{BAD}:10: error: " in bad.stderr
    assert "Traceback" not in bad.stderr
    usage = subprocess.run([str(script), "bogus"], capture_output=True, text=True, timeout=60)
    assert usage.returncode == 2


def test_view_of_a_bad_recording_says_which_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "view", tmp_path / "missing.jsonl")
    assert code == 1 and err.startswith(f"sm-bt: error: cannot read {tmp_path / 'missing.jsonl'}")
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"tick": 1, "tree": {}, "modes": []}\n{"oops": true}\nnot json\n')
    code, _, err = run(capsys, "view", bad)
    assert (code, err) == (1, f"sm-bt: error: {bad}:2: not a frame of sm-bt's view (tick, tree, modes)\n")


def test_check_reports_every_file_of_a_mixed_set_and_never_an_internal_error(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    files = {"control.yaml": b"a:\x00\n", "deep.yaml": b"[" * 5000, "latin1.yaml": b"a: caf\xe9\n",
             "alias.yaml": b"*a\n"}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    code, out, err = run(capsys, "check", *(tmp_path / name for name in files), "pilot")
    assert code == 1
    assert out.splitlines()[-1] == "pilot: ok (1 system, 4 nodes)"  # checked after the bad ones
    for name in files:
        assert f"{tmp_path / name}: failed" in err
        assert f"{tmp_path / name}:0:" not in err  # every error has a real line
    assert "internal error" not in err and "Traceback" not in err


def test_check_of_a_directory_reports_every_good_and_bad_file_and_exits_1(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from sm_bt.bundled import path as bundled_path

    (tmp_path / "nested").mkdir()
    (tmp_path / "good.yaml").write_bytes(bundled_path("pilot").read_bytes())
    (tmp_path / "nested" / "also_good.yml").write_bytes(bundled_path("actuation").read_bytes())
    (tmp_path / "nested" / "truncated.yaml").write_bytes(bundled_path("pilot").read_bytes()[:300])
    (tmp_path / "binary.yaml").write_bytes(b"\x00\x01\x02")
    (tmp_path / "notes.txt").write_text("not a model")
    code, out, err = run(capsys, "check", tmp_path)
    assert code == 1
    assert f"{tmp_path / 'good.yaml'}: ok (1 system, 4 nodes)" in out
    assert f"{tmp_path / 'nested' / 'also_good.yml'}: ok (" in out
    assert f"{tmp_path / 'nested' / 'truncated.yaml'}: failed (" in err
    assert f"{tmp_path / 'binary.yaml'}:1: error: character" in err
    assert "notes.txt" not in out + err
    assert err.splitlines()[-1] == "4 files checked, 2 failed"
    assert "Traceback" not in err and "internal error" not in err


def test_check_of_an_empty_directory_says_so(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "check", tmp_path)
    assert (code, err) == (1, f"sm-bt: error: {tmp_path}: a directory with no model (.yaml, .yml) or tree (.xml) "
                              "files\n")


def test_check_reports_an_internal_error_for_its_file_and_checks_the_others(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """A bug in the loader (simulated: it raises on one file) costs that file, not the run; --debug
    adds the traceback."""
    import sm_bt.cli.common as cli

    real = cli.load_model

    def buggy(path: str, **kwargs: bool) -> object:
        if str(path).endswith("buggy.yaml"):
            raise ZeroDivisionError("division by zero")
        return real(path, **kwargs)

    monkeypatch.setattr(cli, "load_model", buggy)
    (tmp_path / "buggy.yaml").write_text("a: 1\n")
    code, out, err = run(capsys, "check", tmp_path / "buggy.yaml", "pilot")
    assert code == 1
    assert out.splitlines()[0] == "pilot: ok (1 system, 4 nodes)"
    assert err.splitlines() == [f"{tmp_path / 'buggy.yaml'}: internal error: ZeroDivisionError: division by zero "
                                "(this is a bug in sm-bt: please report it with this file; --debug shows the "
                                "traceback)", "2 files checked, 1 failed"]
    code, _, err = run(capsys, "check", "--debug", tmp_path / "buggy.yaml", "pilot")
    assert code == 1 and "Traceback (most recent call last):" in err and 'raise ZeroDivisionError' in err


def test_an_unreadable_model_file_is_named_without_a_line(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from sm_bt.model import ModelError, load_model

    with pytest.raises(ModelError) as raised:
        load_model(tmp_path / "missing.yaml")
    assert str(raised.value).startswith(f"{tmp_path / 'missing.yaml'}: error: cannot read the model file: ")


@pytest.mark.parametrize(("variable", "value", "says"), [
    ("ROS_DOMAIN_ID", "abc", "ROS_DOMAIN_ID='abc' is not a ROS 2 domain id: set it to a whole number from 0 to 232"),
    ("ROS_DOMAIN_ID", "300", "ROS_DOMAIN_ID='300' is not a ROS 2 domain id"),
    ("ROS_AUTOMATIC_DISCOVERY_RANGE", "lan", "ROS_AUTOMATIC_DISCOVERY_RANGE='lan' is not a discovery range: use one "
                                             "of SUBNET, LOCALHOST, OFF, SYSTEM_DEFAULT"),
])
# sm-bt monitor --ros looks for rclpy before it reads the variables (sm-bt manager checks them first).
@pytest.mark.parametrize("command", [pytest.param(("monitor", "pilot", "--ros", "--once"), marks=pytest.mark.ros),
                                     ("manager", "pilot")])
def test_a_bad_ros_variable_is_named_with_its_fix(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
                                                  variable: str, value: str, says: str,
                                                  command: tuple[str, ...]) -> None:
    """rcl only says "failed to initialize rcl" (it was an internal error, exit 1, with a hint of a bug)."""
    import sm_bt.cli.manager

    # In this process: no root log handler, no signal handlers left behind by `sm-bt manager`.
    monkeypatch.setattr(sm_bt.cli.manager, "configure_logging", lambda level: None)
    monkeypatch.setattr(sm_bt.cli.manager, "install_stop_handlers", lambda stop: None)
    monkeypatch.setenv(variable, value)
    code, _, err = run(capsys, *command)
    assert code == 1
    assert err.startswith(f"sm-bt: error: {says}") and "internal error" not in err


@pytest.mark.parametrize(("change", "says"), [
    ("pilot=f_nrmal_mode", "--change pilot=f_nrmal_mode: 'f_nrmal_mode' is neither a mode of pilot nor a transition "
                           "(did you mean 'f_normal_mode'?)"),
    ("pilto=configure", "--change pilto=configure: no part 'pilto' in pilot (did you mean 'pilot'?)"),
    ("pilot=configur", "--change pilot=configur: 'configur' is neither a mode of pilot nor a transition (did you "
                       "mean 'configure'?)"),
    ("pilot=xyzzy", "--change pilot=xyzzy: 'xyzzy' is neither a mode of pilot nor a transition (modes: __DEFAULT__, "
                    "f_normal_mode, f_degraded_mode, f_performance_mode, f_energy_saving_mode, f_slow_mode; "
                    "transitions: configure, activate, deactivate, cleanup, shutdown)"),
])
def test_a_typo_in_a_change_is_a_usage_error_with_the_closest_name(capsys: pytest.CaptureFixture[str], change: str,
                                                                   says: str) -> None:
    code, out, err = run(capsys, "monitor", "pilot", "--change", change, "--once")
    assert (code, out, err) == (2, "", f"sm-bt monitor: error: {says}\n")


def test_the_managers_start_up_lines_name_the_nodes_only_when_it_serves_them() -> None:
    from model_files import bundled

    from sm_bt.cli.manager import startup_lines

    every = startup_lines(bundled("pilot"))
    systems = startup_lines(bundled("pilot"), nodes=False)
    assert "- node 'amcl'" in every and "  - /amcl/change_mode" in every
    assert systems == [line for line in every if line.startswith(("- system", "  - /pilot/"))]
    assert "  - /pilot/change_state" in systems



#: A process whose import of the commands is interrupted by Ctrl-C (as on a busy machine, where
#: loading them takes a second or more), then runs sm-bt.
_INTERRUPTED_LOAD = """
import sys

class Interrupt:
    def find_spec(self, name, path=None, target=None):
        if name == "sm_bt.cli.app":
            raise KeyboardInterrupt
        return None

sys.meta_path.insert(0, Interrupt())
from sm_bt.cli import main
sys.exit(main(["modes", "pilot"]))
"""


def test_ctrl_c_while_the_commands_load_ends_the_command_as_interrupted() -> None:
    done = subprocess.run([sys.executable, "-c", _INTERRUPTED_LOAD], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stderr) == (130, "sm-bt: interrupted\n")
