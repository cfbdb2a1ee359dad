"""The loader's extensions: __DONTCARE__ entries, match specs for inference, __order__ stages."""

from __future__ import annotations

import pytest

from sm_bt.model import (
    DEFAULT_MODE,
    DONT_CARE,
    Match,
    ModelError,
    ModelIssue,
    NodePart,
    State,
    StateMode,
    SystemPart,
    load_model_text,
)

SYSTEM = """\
sys:
  ros__parameters:
    type: system
    modes:
      __DEFAULT__:
        a: active
        b: inactive
        c: active
{default_extra}      OTHER:
        a: {other_a}
{other_extra}
a:
  ros__parameters:
    type: node
    modes: {{__DEFAULT__: {{ros__parameters: {{x: 1}}}}}}
b:
  ros__parameters:
    type: node
    modes: {{__DEFAULT__: {{ros__parameters: {{x: 1}}}}}}
c:
  ros__parameters:
    type: node
    modes: {{__DEFAULT__: {{ros__parameters: {{x: 1}}}}}}
"""


def system_text(default_extra: str = "", other_a: str = "inactive", other_extra: str = "") -> str:
    return SYSTEM.format(default_extra=default_extra, other_a=other_a, other_extra=other_extra)


def load_system(text: str) -> SystemPart:
    part = load_model_text(text).part("sys")
    assert isinstance(part, SystemPart)
    return part


def errors_of(text: str) -> list[ModelIssue]:
    with pytest.raises(ModelError) as caught:
        load_model_text(text)
    return list(caught.value.issues)


# --- don't care ---------------------------------------------------------------------------------


def test_dont_care_entry_has_no_target() -> None:
    sys_part = load_system(system_text(other_a=DONT_CARE))
    entry = sys_part.modes["OTHER"].entries["a"]
    assert entry.target is None and entry.dont_care and not entry.inherited
    assert sys_part.modes["OTHER"].entries["b"].target == StateMode(State.INACTIVE)


def test_dont_care_in_the_default_is_inherited() -> None:
    text = system_text().replace("        b: inactive\n", f"        b: {DONT_CARE}\n")
    entry = load_system(text).modes["OTHER"].entries["b"]
    assert entry.dont_care and entry.inherited


def test_dont_care_is_not_a_mode_name() -> None:
    (issue,) = errors_of(system_text(other_a=f"active.{DONT_CARE}"))
    assert issue.location.line == 10 and "has no mode '__DONTCARE__'" in issue.message


# --- switching order ----------------------------------------------------------------------------


def test_order_stages_and_unlisted_parts_last() -> None:
    text = system_text(other_extra='        __order__: ["c", "a, b"]\n')
    sys_part = load_system(text)
    assert sys_part.modes["OTHER"].stages == (("c",), ("a", "b"))
    assert sys_part.modes[DEFAULT_MODE].stages == (("a", "b", "c"),)
    text = system_text(other_extra='        __order__: ["b"]\n')
    assert load_system(text).modes["OTHER"].stages == (("b",), ("a", "c"))


def test_modes_without_order_inherit_the_default_order() -> None:
    text = system_text(default_extra="        __order__: [\"b, c\", a]\n")
    sys_part = load_system(text)
    assert sys_part.modes[DEFAULT_MODE].stages == (("b", "c"), ("a",))
    assert sys_part.modes["OTHER"].stages == (("b", "c"), ("a",))


def test_order_errors() -> None:
    issues = errors_of(system_text(other_extra='        __order__: ["a, d", "a", "b,"]\n'))
    assert [i.location.line for i in issues] == [11, 11, 11]
    messages = " | ".join(i.message for i in issues)
    assert "names 'd', which is not a part of 'sys'" in messages
    assert "lists 'a' twice" in messages
    assert "empty part name" in messages
    (issue,) = errors_of(system_text(other_extra="        __order__: a\n"))
    assert issue.location.line == 11 and "must be a list of stages" in issue.message


# --- match specs --------------------------------------------------------------------------------

NODE = """\
drive:
  ros__parameters:
    type: node
{part_match}    modes:
      __DEFAULT__:
        ros__parameters:
          speed: 0.5
          gain: 2
          mode_name: eco
          limits:
            low: 0.1
      FAST:
        ros__parameters:
          speed: 0.9
{fast_match}"""


def node_text(part_match: str = "", fast_match: str = "") -> str:
    return NODE.format(part_match=part_match, fast_match=fast_match)


def load_node(text: str) -> NodePart:
    part = load_model_text(text).part("drive")
    assert isinstance(part, NodePart)
    return part


def test_part_level_match_applies_to_every_mode() -> None:
    text = node_text(part_match="    match:\n      speed: {tolerance: 0.05}\n      limits:\n        low: [0.0, 0.2]\n")
    drive = load_node(text)
    for mode in drive.modes.values():
        assert mode.parameters["speed"].match == Match(tolerance=0.05)
        assert mode.parameters["limits.low"].match == Match(minimum=0.0, maximum=0.2)
        assert mode.parameters["gain"].match == Match()
    fast = drive.modes["FAST"]
    assert fast.matches({"speed": 0.93, "gain": 2, "mode_name": "eco", "limits.low": 0.15})
    assert not fast.matches({"speed": 0.96, "gain": 2, "mode_name": "eco", "limits.low": 0.15})
    assert not fast.matches({"speed": 0.9, "gain": 2, "mode_name": "eco", "limits.low": 0.3})


def test_mode_level_match_overrides_per_parameter() -> None:
    text = node_text(part_match="    match:\n      speed: {tolerance: 0.05}\n      gain: {min: 1, max: 3}\n",
                     fast_match="        match:\n          speed: {min: 0.8, max: 1.0}\n")
    drive = load_node(text)
    assert drive.modes["FAST"].parameters["speed"].match == Match(minimum=0.8, maximum=1.0)
    assert drive.modes["FAST"].parameters["gain"].match == Match(minimum=1.0, maximum=3.0)
    assert drive.modes[DEFAULT_MODE].parameters["speed"].match == Match(tolerance=0.05)


def test_match_dotted_name_and_combined_fields() -> None:
    text = node_text(part_match="    match:\n      limits.low: {tolerance: 0.1, max: 0.15}\n")
    spec = load_node(text).modes[DEFAULT_MODE].parameters["limits.low"]
    assert spec.match == Match(tolerance=0.1, maximum=0.15)
    assert spec.matches(0.0) and not spec.matches(0.16)


@pytest.mark.parametrize(
    ("match_line", "message"),
    [
        ("      sped: {tolerance: 0.1}",
         "'sped', which is not a parameter of the default mode (did you mean 'speed'?)"),
        ("      mode_name: {tolerance: 0.1}", "needs a numeric parameter"),
        ("      speed: {tolerance: -0.1}", "write a finite number >= 0"),
        ("      speed: [1.0, 0.0]", "min 1.0 > max 0.0: swap them"),
        ("      speed: [0.0, 0.6]", "speed=0.9 (line 16) is outside its match range [0.0, 0.6]"),
        ("      speed: [0.0]", "must be two numbers"),
        ("      speed: {tolerance: x}", "must be a number"),
        ("      speed: 0.1", "write {tolerance: EPS}, [MIN, MAX] or {min: A, max: B}"),
    ],
)
def test_match_errors(match_line: str, message: str) -> None:
    issues = errors_of(node_text(part_match=f"    match:\n{match_line}\n"))
    assert len(issues) == 1, [str(i) for i in issues]
    assert issues[0].location.line == 5
    assert message in issues[0].message


def test_match_on_a_system_is_refused() -> None:
    text = system_text().replace("    type: system\n", "    type: system\n    match: {x: [0, 1]}\n")
    (issue,) = errors_of(text)
    assert issue.location.line == 4 and "cannot have 'match'" in issue.message


def test_overlapping_ranges_warn_disjoint_ranges_do_not() -> None:
    overlapping = node_text(part_match="    match:\n      speed: {tolerance: 0.25}\n",
                            fast_match="          gain: 2\n")
    warnings = load_model_text(overlapping).warnings
    assert len(warnings) == 1
    assert "modes '__DEFAULT__' and 'FAST' accept overlapping values" in warnings[0].message
    assert load_model_text(node_text(part_match="    match:\n      speed: {tolerance: 0.1}\n")).warnings == ()


def test_exact_value_inside_another_modes_range_warns() -> None:
    text = node_text(fast_match="        match:\n          speed: [0.4, 1.0]\n")
    (warning,) = load_model_text(text).warnings
    assert "accept overlapping values" in warning.message
