"""``sm-bt plan MODEL PART MODE``: a change previewed offline, from a configuration given."""

from __future__ import annotations

import json

import pytest

from sm_bt.cli import main


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_a_plan_from_a_configuration_given(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "plan", "pilot", "pilot", "f_degraded_mode", "--from", "pilot=active.f_normal_mode")
    assert (code, err) == (0, "")
    lines = out.splitlines()
    assert lines[:4] == ["change_mode pilot f_degraded_mode: 5 calls", "  pilot -> active.f_degraded_mode",
                         "    stage 1/3", "      pointcloud_to_laser: inactive -> active.__DEFAULT__: activate"]
    assert "          FollowPath.max_vel_x 0.3 -> 0.1" in lines
    assert lines[-1] == "      laser_resender: active.__DEFAULT__ -> unconfigured: deactivate, cleanup"


def test_by_default_from_every_node_unconfigured_and_as_json(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "plan", "pilot", "pilot", "f_normal_mode", "--json")
    preview = json.loads(out)
    assert code == 0 and preview["possible"] and preview["calls"] == 7
    assert [node["node"] for node in preview["plan"]["stages"][0]] == [
        "amcl", "controller_server", "pointcloud_to_laser", "laser_resender"]


def test_a_change_that_cannot_be_made_exits_1_with_why(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "plan", "pilot", "amcl", "activate")
    assert code == 1
    assert out == ("change_state amcl activate: cannot be made now: amcl: transition activate is not valid in state "
                   "unconfigured (valid: configure, shutdown)\n")


@pytest.mark.parametrize(("argv", "message"), [
    (("pilto", "f_normal_mode"), "unknown part 'pilto' (did you mean 'pilot'?)"),
    (("pilot", "f_nrmal_mode"), "unknown mode 'f_nrmal_mode' of pilot (did you mean 'f_normal_mode'?)"),
    (("pilot", "f_normal_mode", "--from", "amcl=active.FAST"), "--from amcl=active.FAST: amcl has no mode 'FAST'"),
    (("pilot", "f_normal_mode", "--from", "somewhere"), "--from 'somewhere': name unconfigured, inactive, active"),
])
def test_names_the_model_does_not_have_are_usage_errors(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...],
                                                         message: str) -> None:
    code, out, err = run(capsys, "plan", "pilot", *argv)
    assert (code, out) == (2, "") and message in err, err
