"""Rules parsing, like the reference's unit test, plus the checks the reference does not make."""

from __future__ import annotations

from pathlib import Path

import pytest

from sm_bt.model import DEFAULT_MODE, ModelError, ModelIssue, State, StateMode, SystemPart, load_model, load_model_text

MODELS = Path(__file__).parents[1] / "models"
RULES_MODEL = (MODELS / "loader_rules.yaml").read_text()


def rules_system() -> SystemPart:
    part = load_model(MODELS / "loader_rules.yaml").part("system")
    assert isinstance(part, SystemPart)
    return part


def errors_of(text: str) -> list[ModelIssue]:
    with pytest.raises(ModelError) as caught:
        load_model_text(text)
    return list(caught.value.issues)


def with_rule(body: str) -> str:
    """The rules model with its rules replaced by one rule ``r`` (body lines at 8 spaces)."""
    start = RULES_MODEL.index("    rules:\n")
    end = RULES_MODEL.index("\npart0:")
    return RULES_MODEL[:start] + "    rules:\n      r:\n" + body + RULES_MODEL[end:]


def test_four_rules_sorted_by_name() -> None:
    rules = rules_system().rules
    assert [r.name for r in rules] == ["degrade_from_AA", "degrade_from_BB", "inactive_from_AA", "inactive_from_BB"]
    assert all(r.system == "system" for r in rules)


def test_rules_for_target_aa() -> None:
    aa = [r for r in rules_system().rules if r.if_target == StateMode(State.ACTIVE, "AA")]
    assert [r.name for r in aa] == ["degrade_from_AA", "inactive_from_AA"]
    degrade, inactive = aa
    assert degrade.if_part == "part0"
    assert degrade.if_part_state == StateMode(State.INACTIVE)
    assert degrade.new_target == StateMode(State.ACTIVE, DEFAULT_MODE)
    assert degrade.location.line == 25
    assert inactive.if_part == "part1"
    assert inactive.new_target == StateMode(State.INACTIVE)


def test_active_without_mode_in_a_rule_is_the_default_mode() -> None:
    (bb,) = [r for r in rules_system().rules if r.name == "degrade_from_BB"]
    assert bb.new_target == StateMode(State.ACTIVE, DEFAULT_MODE)


def test_if_part_may_name_a_nested_part_and_a_transition_state() -> None:
    model = load_model(MODELS / "loader_nested.yaml")
    robot = model.part("robot")
    assert isinstance(robot, SystemPart)
    (rule,) = robot.rules
    assert rule.if_part == "lidar" and rule.if_part_state == StateMode(State.ERRORPROCESSING)
    assert model.nodes_under("robot") == ("base", "lidar", "camera")
    assert model.ancestors("lidar") == ("sensing", "robot")


def test_a_rule_needs_all_three_keys() -> None:
    (issue,) = errors_of(with_rule("        if_target: active.AA\n        if_part: [part0, inactive]\n"))
    assert issue.location.line == 21
    assert "missing 'new_target'" in issue.message
    (issue,) = errors_of(with_rule("        if_part: [part0, inactive]\n"))
    assert "missing 'if_target' and 'new_target'" in issue.message


def test_if_part_must_be_a_two_string_list() -> None:
    for bad in ("[part0]", "[part0, inactive, active]", "part0", "[1, 2]"):
        (issue,) = errors_of(with_rule(f"        if_target: active.AA\n        if_part: {bad}\n"
                                       "        new_target: inactive\n"))
        assert issue.location.line == 23, bad
        assert "if_part must be a list of two strings" in issue.message


def test_if_part_must_be_below_the_system() -> None:
    (issue,) = errors_of(with_rule("        if_target: active.AA\n        if_part: [part2, inactive]\n"
                                   "        new_target: inactive\n"))
    assert issue.location.line == 23
    assert "'part2', which is not one of the parts of 'system' (did you mean 'part1'?)" in issue.message


def test_rule_states_are_checked_against_the_right_part() -> None:
    issues = errors_of(with_rule("        if_target: active.FOO\n        if_part: [part0, active.AA]\n"
                                 "        new_target: INACTIVE\n"))
    assert [i.location.line for i in issues] == [22, 23, 24]
    assert "part 'system' has no mode 'FOO'" in issues[0].message
    assert "part 'part0' has no mode 'AA'" in issues[1].message
    assert "write 'inactive' (labels are lower-case)" in issues[2].message


def test_unknown_rule_key() -> None:
    issues = errors_of(with_rule("        if_target: active.AA\n        if_part: [part0, inactive]\n"
                                 "        new_target: inactive\n        if_parts: x\n"))
    assert [i.location.line for i in issues] == [25]
    assert "unknown key 'if_parts' (did you mean 'if_part'?)" in issues[0].message


def test_rules_under_a_node_are_allowed() -> None:
    text = RULES_MODEL.replace(
        "part1:\n  ros__parameters:\n    type: node\n",
        "part1:\n  ros__parameters:\n    type: node\n    rules:\n      retry:\n        if_target: active.AAA\n"
        "        if_part: [part1, inactive]\n        new_target: active\n",
    )
    part1 = load_model_text(text).part("part1")
    (rule,) = part1.rules
    assert rule.system == "part1" and rule.new_target == StateMode(State.ACTIVE, DEFAULT_MODE)
