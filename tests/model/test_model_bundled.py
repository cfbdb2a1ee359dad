"""The models shipped with sm_bt, and compatibility with the reference's own model files."""

from __future__ import annotations

from pathlib import Path

import pytest

import sm_bt.models as bundled
from sm_bt.model import (
    DEFAULT_MODE,
    ModelError,
    NodePart,
    Severity,
    State,
    StateMode,
    SystemPart,
    load_model,
)

REPO = Path(__file__).resolve().parents[2]
REFERENCE_CANDIDATES = (REPO.parent / "shared" / "reference" / "models", Path("/work/shared/reference/models"))


def reference_folder() -> Path:
    for folder in REFERENCE_CANDIDATES:
        if folder.is_dir():
            return folder
    pytest.skip("the reference model files are not available on this machine")


def node(model_name: str, part: str) -> NodePart:
    found = load_model(bundled.path(model_name)).part(part)
    assert isinstance(found, NodePart)
    return found


def test_bundled_names() -> None:
    assert {"actuation", "pilot", "pilot_rules"} <= set(bundled.names())


def test_actuation() -> None:
    model = load_model(bundled.path("actuation"))
    actuation = model.part("actuation")
    assert isinstance(actuation, SystemPart)
    assert actuation.parts == ("manipulator", "drive_base")
    assert list(actuation.modes) == [DEFAULT_MODE, "MODERATE", "PERFORMANCE"]
    assert actuation.modes["PERFORMANCE"].entries["manipulator"].target == StateMode(State.ACTIVE, "STRONG")
    assert [r.name for r in actuation.rules] == [
        "degrade_from_MODERATE", "degrade_from_PERFORMANCE", "inactive_from_MODERATE", "inactive_from_PERFORMANCE",
    ]
    drive = model.part("drive_base")
    assert isinstance(drive, NodePart)
    assert drive.modes["SLOW"].values() == {"max_speed": 0.2, "controller": "PID"}
    assert drive.modes["FAST"].values() == {"max_speed": 0.9, "controller": "MPC"}
    # The deliberate __DEFAULT__/WEAK ambiguity of the manipulator is reported, not refused.
    (warning,) = model.warnings
    assert warning.severity is Severity.WARNING and "'__DEFAULT__' and 'WEAK'" in warning.message


def test_pilot() -> None:
    model = load_model(bundled.path("pilot"))
    assert model.warnings == ()
    pilot = model.part("pilot")
    assert isinstance(pilot, SystemPart)
    assert pilot.parts == ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")
    assert pilot.rules == ()
    assert list(pilot.modes) == [DEFAULT_MODE, "f_normal_mode", "f_degraded_mode", "f_performance_mode",
                                 "f_energy_saving_mode", "f_slow_mode"]
    assert all(e.target == StateMode(State.INACTIVE) for e in pilot.modes[DEFAULT_MODE].entries.values())
    degraded = pilot.modes["f_degraded_mode"]
    assert degraded.entries["laser_resender"].target == StateMode(State.UNCONFIGURED)
    assert degraded.entries["amcl"].target == StateMode(State.ACTIVE, "DEGRADED")
    assert degraded.stages == (("pointcloud_to_laser",), ("amcl", "controller_server"), ("laser_resender",))
    assert pilot.modes["f_normal_mode"].stages == ((*pilot.parts,),)
    slow, saving = pilot.modes["f_slow_mode"], pilot.modes["f_energy_saving_mode"]
    assert {p: e.target for p, e in slow.entries.items()} == {p: e.target for p, e in saving.entries.items()}

    controller = model.part("controller_server")
    assert isinstance(controller, NodePart)
    assert controller.modes["DEGRADED"].values()["FollowPath.transform_tolerance"] == 2.5
    assert controller.modes["SLOW"].values() == {
        "FollowPath.max_vel_x": 0.1, "FollowPath.max_speed_xy": 0.1,
        "FollowPath.max_vel_theta": 0.5, "FollowPath.transform_tolerance": 0.2,
    }
    assert controller.modes["FAST"].values()["FollowPath.max_vel_theta"] == 1.5
    amcl = model.part("amcl")
    assert isinstance(amcl, NodePart)
    assert amcl.modes["DEGRADED"].values() == {"transform_tolerance": 2.5, **{f"alpha{i}": 0.05 for i in range(1, 6)}}
    assert node("pilot", "laser_resender").modes[DEFAULT_MODE].values() == {"node_name": "laser_resender"}


def test_pilot_rules_adds_exactly_one_rule() -> None:
    plain, ruled = load_model(bundled.path("pilot")), load_model(bundled.path("pilot_rules"))
    ruled_pilot = ruled.part("pilot")
    assert isinstance(ruled_pilot, SystemPart)
    (rule,) = ruled_pilot.rules
    assert rule.name == "degrade_from_normal"
    assert rule.if_target == StateMode(State.ACTIVE, "f_normal_mode")
    assert (rule.if_part, rule.if_part_state) == ("laser_resender", StateMode(State.UNCONFIGURED))
    assert rule.new_target == StateMode(State.ACTIVE, "f_degraded_mode")
    plain_pilot = plain.part("pilot")
    assert isinstance(plain_pilot, SystemPart)
    assert plain_pilot.modes.keys() == ruled_pilot.modes.keys()
    for name, part in plain.parts.items():
        if name != "pilot":
            assert isinstance(part, NodePart)
            other = ruled.parts[name]
            assert isinstance(other, NodePart)
            assert {m: mode.values() for m, mode in part.modes.items()} == {
                m: mode.values() for m, mode in other.modes.items()}


# --- the reference's own files (third-party data, only read when present) ------------------------


def test_every_reference_model_loads_except_the_known_bad_ones() -> None:
    folder = reference_folder()
    files = sorted(folder.glob("*.yaml"))
    assert files
    expected_failures = {"system_modes__test__test_modes_wrong.yaml",
                         "system_modes_examples__example_modes_with_namespace.yaml"}
    for path in files:
        if path.name in expected_failures:
            with pytest.raises(ModelError):
                load_model(path)
        else:
            model = load_model(path)
            assert model.parts, path.name


def test_reference_wrong_model_reports_labels_and_parameter() -> None:
    path = reference_folder() / "system_modes__test__test_modes_wrong.yaml"
    if not path.exists():
        pytest.skip("file not present")
    with pytest.raises(ModelError) as caught:
        load_model(path)
    by_line = {i.location.line: i.message for i in caught.value.issues}
    assert "write 'inactive' (labels are lower-case)" in by_line[12]
    assert "write 'active.WEAK' (labels are lower-case)" in by_line[15]
    assert "parameter 'wrong' is not in the default mode" in by_line[31]
    assert "parameter 'wrong' is not in the default mode" in by_line[36]


def test_reference_namespace_example_typo() -> None:
    path = reference_folder() / "system_modes_examples__example_modes_with_namespace.yaml"
    if not path.exists():
        pytest.skip("file not present")
    with pytest.raises(ModelError) as caught:
        load_model(path)
    (issue,) = caught.value.issues
    assert issue.location.line == 23 and "did you mean 'right/manipulator'?" in issue.message
    model = load_model(path, strict=False)
    typo = [w for w in model.warnings if w.location.line == 23]
    assert typo and "right/manipulsator" in typo[0].message
    actuation = model.part("actuation")
    assert isinstance(actuation, SystemPart)
    assert actuation.modes["PERFORMANCE"].entries["right/manipulator"].inherited


def test_reference_defaultmode_files_resolve_default_in_rules() -> None:
    path = reference_folder() / "refactoring-branch__system_modes_examples__example_modes.yaml"
    if not path.exists():
        pytest.skip("file not present")
    actuation = load_model(path).part("actuation")
    assert isinstance(actuation, SystemPart)
    assert actuation.default_mode == "DEFAULT"
    assert {r.new_target for r in actuation.rules} == {StateMode(State.ACTIVE, "DEFAULT"), StateMode(State.INACTIVE)}
    assert actuation.modes["DEFAULT"].entries["drive_base"].target == StateMode(State.ACTIVE, "NORMAL")
