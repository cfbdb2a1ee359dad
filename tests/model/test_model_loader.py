"""The model loader: what it resolves, and what it refuses (with lines and fixes)."""

from __future__ import annotations

from pathlib import Path
from textwrap import dedent

import pytest

from sm_bt.model import (
    DEFAULT_MODE,
    Location,
    ModelError,
    ModelIssue,
    NodePart,
    Severity,
    State,
    StateMode,
    SystemPart,
    load_model,
    load_model_text,
)

MODELS = Path(__file__).parents[1] / "models"

# A valid model; tests below break it in one place. Lines are numbered in the comments.
BASE = """\
sys:
  ros__parameters:
    type: system
    parts:
      a
      b
    modes:
      __DEFAULT__:
        a: inactive
        b: active
      FAST:
        a: active.QUICK
a:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          speed: 0.5
          name: alpha
      QUICK:
        ros__parameters:
          speed: 1.5
b:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          rate: 10
"""


def errors_of(text: str, *, strict: bool = True) -> list[ModelIssue]:
    with pytest.raises(ModelError) as caught:
        load_model_text(text, "m.yaml", strict=strict)
    issues = list(caught.value.issues)
    assert all(i.severity is Severity.ERROR and i.location.file == "m.yaml" for i in issues)
    return issues


def one_error(text: str) -> ModelIssue:
    issues = errors_of(text)
    assert len(issues) == 1, [str(i) for i in issues]
    return issues[0]


def edit(old: str, new: str, text: str = BASE) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def system(model_text: str, name: str = "sys") -> SystemPart:
    part = load_model_text(model_text).part(name)
    assert isinstance(part, SystemPart)
    return part


def node(model_text: str, name: str) -> NodePart:
    part = load_model_text(model_text).part(name)
    assert isinstance(part, NodePart)
    return part


# --- what the loader resolves ------------------------------------------------------------------


def test_base_model_loads_in_file_order_with_locations() -> None:
    model = load_model_text(BASE, "m.yaml")
    assert list(model.parts) == ["sys", "a", "b"]
    assert model.warnings == ()
    sys_part = model.part("sys")
    assert isinstance(sys_part, SystemPart)
    assert sys_part.location == Location("m.yaml", 1)
    assert sys_part.modes["FAST"].location.line == 11
    assert sys_part.modes["FAST"].entries["a"].location.line == 12
    assert model.part("a").location.line == 13


def test_delta_modes_inherit_the_default_parameters() -> None:
    a = node(BASE, "a")
    assert a.default_mode == DEFAULT_MODE
    assert a.modes["QUICK"].values() == {"speed": 1.5, "name": "alpha"}
    assert a.modes["QUICK"].parameters["speed"].location.line == 23
    assert a.modes["QUICK"].parameters["name"].location.line == 20  # inherited: the default's line
    assert a.parameter_names == ("speed", "name")


def test_system_modes_inherit_default_entries_for_every_part() -> None:
    fast = system(BASE).modes["FAST"]
    assert list(fast.entries) == ["a", "b"]
    assert fast.entries["a"].target == StateMode(State.ACTIVE, "QUICK")
    assert not fast.entries["a"].inherited
    assert fast.entries["b"].inherited
    assert fast.entries["b"].location.line == 10
    assert fast.entries["b"].target == StateMode(State.ACTIVE, DEFAULT_MODE)


def test_active_alone_means_the_parts_default_mode() -> None:
    text = edit("        b: active\n", "        b: active.__DEFAULT__\n")
    assert system(text).modes[DEFAULT_MODE].entries["b"].target == system(BASE).modes[DEFAULT_MODE].entries["b"].target
    assert system(BASE).modes[DEFAULT_MODE].entries["b"].target == StateMode(State.ACTIVE, DEFAULT_MODE)


def test_mode_suffix_on_a_non_active_state_is_accepted_and_ignored() -> None:
    text = edit("        a: inactive\n", "        a: inactive.QUICK\n")
    assert system(text).modes[DEFAULT_MODE].entries["a"].target == StateMode(State.INACTIVE)
    text = edit("        a: inactive\n", "        a: unconfigured.__DEFAULT__\n")
    assert system(text).modes[DEFAULT_MODE].entries["a"].target == StateMode(State.UNCONFIGURED)


def test_parts_order_follows_parts_key_or_default_mode() -> None:
    assert system(edit("      a\n      b\n", "      b\n      a\n")).parts == ("b", "a")
    assert system(edit("    parts:\n      a\n      b\n", "")).parts == ("a", "b")
    assert system(edit("    parts:\n      a\n      b\n", "    parts: [b, a]\n")).parts == ("b", "a")


def test_no_order_means_one_parallel_stage() -> None:
    assert system(BASE).modes["FAST"].stages == (("a", "b"),)


def test_namespaced_parts_in_both_spellings() -> None:
    model = load_model(MODELS / "loader_namespaced.yaml")
    assert list(model.parts) == ["arms", "left/gripper", "right/gripper", "wrist"]
    arms = model.part("arms")
    assert isinstance(arms, SystemPart)
    assert arms.parts == ("left/gripper", "right/gripper", "wrist")
    assert model.part("right/gripper").location.line == 32
    grip = arms.modes["GRIP"]
    assert grip.entries["right/gripper"].target == StateMode(State.ACTIVE, "CLOSED")
    assert grip.entries["wrist"].inherited


def test_defaultmode_key_need_not_come_first() -> None:
    model = load_model(MODELS / "loader_defaultmode.yaml")
    cell, conveyor = model.part("cell"), model.part("conveyor")
    assert isinstance(cell, SystemPart) and isinstance(conveyor, NodePart)
    assert cell.default_mode == "IDLE" and conveyor.default_mode == "NORMAL"
    # FAST is a delta over NORMAL although it comes first in the file.
    assert conveyor.modes["FAST"].values() == {"speed": 2.0, "direction": "forward"}
    assert cell.modes["IDLE"].entries["conveyor"].target == StateMode(State.ACTIVE, "NORMAL")
    assert cell.modes["BUSY"].entries["camera"].target == StateMode(State.ACTIVE, DEFAULT_MODE)
    # __DEFAULT__ in a rule names the defaultmode when no mode is literally called so.
    (rule,) = cell.rules
    assert rule.new_target == StateMode(State.ACTIVE, "IDLE")


def test_a_mode_literally_named_default_wins_over_defaultmode() -> None:
    text = edit("    type: node\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n          speed",
                "    type: node\n    defaultmode: QUICK\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n"
                "          speed")
    text = edit("          speed: 1.5\n", "          speed: 1.5\n          name: beta\n", text)
    model = load_model_text(text)
    assert model.part("a").default_mode == "QUICK"
    sys_part = model.part("sys")
    assert isinstance(sys_part, SystemPart)
    text2 = edit("        a: active.QUICK\n", "        a: active.__DEFAULT__\n", text)
    assert system(text2).modes["FAST"].entries["a"].target == StateMode(State.ACTIVE, DEFAULT_MODE)


def test_load_model_accepts_str_and_pathlike() -> None:
    path = MODELS / "loader_rules.yaml"
    assert load_model(str(path)).path == str(path)
    assert list(load_model(path).parts) == ["system", "part0", "part1"]


# --- refusals -----------------------------------------------------------------------------------


def test_missing_file_is_a_model_error() -> None:
    with pytest.raises(ModelError) as caught:
        load_model(MODELS / "does_not_exist.yaml")
    (issue,) = caught.value.issues
    assert issue.location.line == 0
    assert "cannot read the model file" in issue.message and "check the path" in issue.message


def test_type_must_be_node_system_or_remote() -> None:
    issue = one_error(edit("    type: node\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n          rate",
                           "    type: Node\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n          rate"))
    assert issue.location.line == 26
    assert "write 'node' (lower-case)" in issue.message
    issue = one_error(edit("    type: system\n", "    type: sytem\n"))
    assert issue.location.line == 3 and "write 'node', 'system' or 'remote'" in issue.message


def test_missing_type_is_an_error() -> None:
    issue = one_error(edit("    type: system\n", ""))
    assert issue.location.line == 1
    assert "has no 'type': add 'type: node' or 'type: system'" in issue.message


def test_missing_default_mode() -> None:
    issue = one_error(edit("      __DEFAULT__:\n        ros__parameters:\n          rate",
                           "      NORMAL:\n        ros__parameters:\n          rate"))
    assert issue.location.line == 27
    assert "no default mode: add a __DEFAULT__ mode or a 'defaultmode: NAME' key" in issue.message


def test_defaultmode_naming_an_unknown_mode() -> None:
    issue = one_error(edit("    type: system\n", "    type: system\n    defaultmode: FASTER\n"))
    assert issue.location.line == 4
    assert "'FASTER'" in issue.message and "did you mean 'FAST'?" in issue.message


def test_parameter_missing_from_default_mode() -> None:
    issue = one_error(edit("          speed: 1.5\n", "          speed: 1.5\n          wrong: 1.0\n"))
    assert issue.location.line == 24
    assert "parameter 'wrong' is not in the default mode '__DEFAULT__': add it to __DEFAULT__ or remove it" in (
        issue.message)


def test_parameter_type_must_match_the_default() -> None:
    issue = one_error(edit("          speed: 1.5\n", "          speed: 1\n"))
    assert issue.location.line == 23
    assert "write 1.0" in issue.message
    issue = one_error(edit("          speed: 1.5\n", "          name: 7\n"))
    assert "quote the value" in issue.message


def test_mode_names_may_not_contain_dots() -> None:
    issue = one_error(edit("      QUICK:\n", "      QUI.CK:\n", edit("a: active.QUICK", "a: active")))
    assert issue.location.line == 21
    assert "may not contain dots" in issue.message


def test_upper_case_labels_suggest_the_lower_case_form() -> None:
    issues = errors_of(edit("        a: inactive\n        b: active\n", "        a: INACTIVE\n        b: ACTIVE\n",
                            edit("a: active.QUICK", "a: ACTIVE.QUICK")))
    assert [i.location.line for i in issues] == [9, 10, 12]
    assert "write 'inactive' (labels are lower-case)" in issues[0].message
    assert "write 'active.QUICK' (labels are lower-case)" in issues[2].message


def test_unknown_label_gets_a_suggestion() -> None:
    issue = one_error(edit("        a: inactive\n", "        a: inactiv\n"))
    assert issue.location.line == 9 and "did you mean 'inactive'?" in issue.message


def test_transition_state_cannot_be_a_target() -> None:
    issue = one_error(edit("        a: inactive\n", "        a: configuring\n"))
    assert issue.location.line == 9 and "'configuring' is not a state a part can be asked to rest in" in (
        issue.message)


def test_active_with_an_unknown_mode_lists_the_modes() -> None:
    issue = one_error(edit("a: active.QUICK", "a: active.QUIK"))
    assert issue.location.line == 12
    assert "part 'a' has no mode 'QUIK' (did you mean 'QUICK'?): use one of '__DEFAULT__', 'QUICK'" in (
        issue.message)


def test_unknown_mode_after_a_non_active_state_is_a_typo() -> None:
    issue = one_error(edit("        a: inactive\n", "        a: inactive.COMPROMISED\n"))
    assert issue.location.line == 9 and "has no mode 'COMPROMISED'" in issue.message


def test_undefined_part_did_you_mean_and_non_strict_warning() -> None:
    text = edit("        a: active.QUICK\n", "        a: active.QUICK\n        bb: active\n")
    issue = one_error(text)
    assert issue.location.line == 13
    assert "part 'bb' is not defined in this file (did you mean 'b'?)" in issue.message
    model = load_model_text(text, strict=False)
    (warning,) = model.warnings
    assert warning.severity is Severity.WARNING and warning.location.line == 13
    sys_part = model.part("sys")
    assert isinstance(sys_part, SystemPart) and list(sys_part.modes["FAST"].entries) == ["a", "b"]


def test_parts_key_must_agree_with_the_modes() -> None:
    issue = one_error(edit("      a\n      b\n", "      a\n"))
    assert issue.location.line == 9
    assert "part 'b' (used in mode '__DEFAULT__') is missing from 'parts:' (line 4): add it there" in issue.message
    text = edit("      a\n      b\n", "      a\n      b\n      c\n") + dedent(
        """\
        c:
          ros__parameters:
            type: node
            modes:
              __DEFAULT__:
                ros__parameters: {x: 1}
        """
    )
    issue = one_error(text)
    assert issue.location.line == 7
    assert "'c' is listed in 'parts:' but no mode sets it: add 'c: STATE' to the default mode" in issue.message


def test_parts_key_naming_an_undefined_part() -> None:
    issues = errors_of(edit("      a\n      b\n", "      a\n      b\n      q\n"))
    assert [i.location.line for i in issues] == [7]
    assert "not defined in this file" in issues[0].message


def test_a_non_default_mode_may_not_add_a_part() -> None:
    text = edit("    parts:\n      a\n      b\n", "", edit("        b: active\n", ""))
    text = edit("        a: active.QUICK\n", "        a: active.QUICK\n        b: active\n", text)
    issue = one_error(text)
    assert issue.location.line == 9
    assert "part 'b' is not in the default mode '__DEFAULT__': add 'b: STATE' to '__DEFAULT__'" in issue.message


def test_cycles_are_refused() -> None:
    direct = edit("        b: active\n", "        b: active\n        sys: inactive\n",
                  edit("      b\n", "      b\n      sys\n"))
    issue = one_error(direct)
    assert issue.location.line == 1 and "sys -> sys" in issue.message
    indirect = BASE + dedent(
        """\
        top:
          ros__parameters:
            type: system
            modes:
              __DEFAULT__:
                sys: active
        """
    )
    indirect = edit("        b: active\n", "        b: active\n        top: inactive\n",
                    edit("      b\n", "      b\n      top\n", indirect))
    issue = one_error(indirect)
    assert "sys -> top -> sys" in issue.message and "remove one of these parts" in issue.message


def test_node_modes_cannot_hold_part_entries_and_vice_versa() -> None:
    issue = one_error(edit("          speed: 1.5\n", "          speed: 1.5\n        b: active\n"))
    assert issue.location.line == 24
    assert "'b' does not belong in a node mode" in issue.message and "type: system" in issue.message
    issue = one_error(edit("        a: active.QUICK\n", "        a: active.QUICK\n        ros__parameters: {x: 1}\n"))
    assert issue.location.line == 13 and "not parameters" in issue.message


def test_node_cannot_list_parts_and_system_cannot_match() -> None:
    issues = errors_of(edit("    type: node\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n          rate",
                            "    type: node\n    parts: a\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n"
                            "          rate",
                            edit("    type: system\n", "    type: system\n    match: {x: [0, 1]}\n")))
    assert [i.location.line for i in issues] == [4, 28]


def test_part_without_ros_parameters() -> None:
    issue = one_error(BASE + "c:\n  type: node\n")
    assert issue.location.line == 31
    assert "has no 'ros__parameters:' map" in issue.message
    issue = one_error(BASE + "c:\n  other:\n    x: 1\n")
    assert issue.location.line == 32
    issue = one_error(BASE + "c: {}\n")
    assert issue.location.line == 31


def test_invalid_part_names_and_duplicates() -> None:
    issue = one_error(BASE + "bad-name:\n  ros__parameters: {type: node}\n")
    assert issue.location.line == 31 and "not a valid ROS 2 node name" in issue.message
    twice = dedent(
        """\
        ns/n:
          ros__parameters:
            type: node
            modes: {__DEFAULT__: {ros__parameters: {x: 1}}}
        ns:
          n:
            ros__parameters:
              type: node
              modes: {__DEFAULT__: {ros__parameters: {x: 1}}}
        """
    )
    issue = one_error(twice)
    assert issue.location.line == 6 and "part 'ns/n' is defined twice (first at line 1)" in issue.message


def test_unknown_keys_are_warnings() -> None:
    model = load_model_text(edit("    type: system\n", "    type: system\n    mode: x\n    colour: red\n"))
    assert [(w.location.line, w.severity) for w in model.warnings] == [(4, Severity.WARNING), (5, Severity.WARNING)]
    assert "unknown key 'mode' is ignored (did you mean 'modes'?)" in model.warnings[0].message


def test_ambiguous_node_modes_are_a_warning_naming_both() -> None:
    model = load_model_text(edit("          speed: 1.5\n", "          speed: 0.5\n"))
    (warning,) = model.warnings
    assert warning.location.line == 21
    assert "modes '__DEFAULT__' and 'QUICK' have the same parameter values (speed=0.5, name='alpha')" in (
        warning.message)


def test_every_error_is_reported_together() -> None:
    text = edit("    type: system\n", "    type: sytem\n")
    text = edit("          speed: 1.5\n", "          speed: 1.5\n          wrong: 1.0\n", text)
    text = edit("          rate: 10\n", "          rate: 10\n          bad: &x 1\n", text)
    issues = errors_of(text)
    assert [i.location.line for i in issues] == [3, 24, 32]
    assert "ModelError" not in str(issues)
    with pytest.raises(ModelError) as caught:
        load_model_text(text, "m.yaml")
    assert str(caught.value).splitlines()[0].startswith("m.yaml:3: error: ")


def test_no_modes_key() -> None:
    issue = one_error(BASE + "c:\n  ros__parameters:\n    type: node\n")
    assert issue.location.line == 31 and "has no 'modes'" in issue.message
