"""ROS 2 parameter-file (rcl) typing and refusals, as the model loader applies them."""

from __future__ import annotations

import math
import subprocess
import sys
from textwrap import dedent

import pytest

from sm_bt.model import ModelError, ModelIssue, load_model_text
from sm_bt.model.rcl_yaml import rcl_scalar

NODE = """\
n:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
"""  # parameters follow from line 7 on, indented by 10


def node_text(*param_lines: str) -> str:
    return NODE + "".join(f"          {line}\n" for line in param_lines)


def default_values(*param_lines: str) -> dict[str, object]:
    model = load_model_text(node_text(*param_lines))
    return model.parts["n"].modes["__DEFAULT__"].values()  # type: ignore[union-attr]


def errors_of(text: str) -> list[ModelIssue]:
    with pytest.raises(ModelError) as caught:
        load_model_text(text)
    return list(caught.value.issues)


@pytest.mark.parametrize("text", ["Y", "y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"])
def test_true_spellings(text: str) -> None:
    assert rcl_scalar(text) is True


@pytest.mark.parametrize("text", ["N", "n", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"])
def test_false_spellings(text: str) -> None:
    assert rcl_scalar(text) is False


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("0", 0),
        ("42", 42),
        ("-7", -7),
        ("+7", 7),
        ("0x7C", 124),  # strtoll base 0: hexadecimal
        ("0X7c", 124),
        ("010", 8),  # leading 0: octal
        ("-010", -8),
        ("9223372036854775807", 2**63 - 1),
        ("1e3", 1000.0),  # a double, not an int (and not a string as in PyYAML)
        ("1.", 1.0),
        (".5", 0.5),
        ("-2.5e-3", -0.0025),
        ("08", 8.0),  # not octal, so strtoll stops early; strtod reads it
        ("9223372036854775808", 9223372036854775808.0),  # int64 overflow: strtod takes it
        ("0x1p3", 8.0),  # strtod hexadecimal float
        ("inf", math.inf),
        ("-Infinity", -math.inf),
        (".inf", math.inf),
        (".Inf", math.inf),
        ("+.INF", math.inf),
        ("-.inf", -math.inf),
        ("-.Inf", -math.inf),
        ("PID", "PID"),
        ("yEs", "yEs"),  # not one of the bool spellings
        ("1_000", "1_000"),  # PyYAML would say 1000
        ("1e999", "1e999"),  # ERANGE: kept as text
        ("0x", "0x"),
        ("1e", "1e"),
        ("1.2.3", "1.2.3"),
        ("~", "~"),
        ("null", "null"),
    ],
)
def test_scalar_typing(text: str, expected: object) -> None:
    value = rcl_scalar(text)
    assert type(value) is type(expected)
    assert value == expected


@pytest.mark.parametrize("text", [".nan", ".NaN", ".NAN", "nan", "NaN"])
def test_nan_spellings(text: str) -> None:
    value = rcl_scalar(text)
    assert isinstance(value, float) and math.isnan(value)


@pytest.mark.parametrize("text", ["true", "1", "0x10", "1e3", ".inf"])
def test_quoted_scalars_are_strings(text: str) -> None:
    assert rcl_scalar(text, quoted=True) == text


def test_typing_in_a_model() -> None:
    values = default_values(
        "flag: yes",
        "count: 010",
        "mask: 0x7C",
        "gain: 1e3",
        "ratio: 1.",
        "limit: .inf",
        "quoted_int: '010'",
        "quoted_bool: \"on\"",
        "tagged: !!str 12",
        "name: PID",
    )
    assert values == {
        "flag": True,
        "count": 8,
        "mask": 124,
        "gain": 1000.0,
        "ratio": 1.0,
        "limit": math.inf,
        "quoted_int": "010",
        "quoted_bool": "on",
        "tagged": "12",
        "name": "PID",
    }
    assert type(values["gain"]) is float


def test_arrays_become_tuples_of_one_type() -> None:
    values = default_values(
        "ints: [1, 2, 0x10]",
        "doubles: [0.5, 1e3]",
        "bools: [yes, off]",
        "strings: [a, 'b', \"1\"]",
        "block:",
        "  - 1.5",
        "  - 2.5",
    )
    assert values == {
        "ints": (1, 2, 16),
        "doubles": (0.5, 1000.0),
        "bools": (True, False),
        "strings": ("a", "b", "1"),
        "block": (1.5, 2.5),
    }


def test_mixed_array_int_in_doubles_suggests_the_double() -> None:
    (issue,) = errors_of(node_text("gains: [0.5, 0]"))
    assert issue.location.line == 7
    assert "write 0.0 instead of 0" in issue.message


def test_mixed_array_other_cases() -> None:
    issues = errors_of(node_text("a: [1, 0.5]", "b: [x, 1]", "c: [true, 1]"))
    assert [i.location.line for i in issues] == [7, 8, 9]
    assert "write every item as a double" in issues[0].message
    assert 'quote it ("1")' in issues[1].message
    assert "same type" in issues[2].message


def test_nested_and_empty_arrays_are_refused() -> None:
    issues = errors_of(node_text("nested: [[1], [2]]", "maps: [{a: 1}]", "empty: []"))
    assert [i.location.line for i in issues] == [7, 7, 8, 9]
    assert "cannot hold lists" in issues[0].message
    assert "cannot hold maps" in issues[2].message
    assert "empty list" in issues[3].message


def test_empty_unquoted_value_is_refused_but_empty_quoted_is_a_string() -> None:
    (issue,) = errors_of(node_text("missing:", "fine: ''"))
    assert issue.location.line == 7
    assert issue.message.startswith("No value at line 7")
    assert default_values("fine: ''") == {"fine": ""}


def test_anchors_and_aliases_are_refused() -> None:
    issues = errors_of(node_text("a: &speed 0.5", "b: *speed"))
    assert [i.location.line for i in issues] == [7, 8]
    assert "anchor '&speed'" in issues[0].message
    assert "alias '*speed'" in issues[1].message
    assert all("do not support" in i.message for i in issues)


def test_duplicate_keys_are_refused() -> None:
    (issue,) = errors_of(node_text("a: 1", "a: 2"))
    assert issue.location.line == 8
    assert "duplicate key 'a' (first at line 7)" in issue.message


def test_dotted_and_nested_names_collide() -> None:
    (issue,) = errors_of(node_text("ns.a: 1", "ns:", "  a: 2"))
    assert issue.location.line == 9
    assert "'ns.a' is set twice" in issue.message


def test_yaml_syntax_error_has_its_line() -> None:
    text = dedent(
        """\
        n:
          ros__parameters:
            type: node
            modes: [a, b
        """
    )
    (issue,) = errors_of(text)
    assert issue.location.line == 4  # the end of the file: its last line (libyaml's mark is one below)
    assert "YAML syntax error" in issue.message


def test_bad_indentation_reports_the_line() -> None:
    (issue,) = errors_of("a:\n  b: 1\n c: 2\n")
    assert issue.location.line == 3


def test_two_documents_are_refused() -> None:
    (issue,) = errors_of(node_text("a: 1") + "---\nm:\n  ros__parameters: {type: node}\n")
    assert issue.location.line == 8
    assert "one YAML document" in issue.message


def test_empty_file_is_refused() -> None:
    (issue,) = errors_of("# nothing here\n")
    assert "holds no model" in issue.message


def test_top_level_must_be_a_map() -> None:
    (issue,) = errors_of("- a\n- b\n")
    assert issue.location.line == 1
    assert "map of part names" in issue.message


@pytest.mark.parametrize("char", ["\x00", "\x07", "\x1b"])
def test_a_control_character_is_an_error_at_its_line(char: str) -> None:
    (issue,) = errors_of(node_text("a: 1", f"b: x{char}y"))
    assert issue.location.line == 8
    assert "not allowed in YAML" in issue.message


@pytest.mark.parametrize("opening", ["[", "{a: ", "- "])
def test_nesting_deeper_than_any_model_is_refused_without_exhausting_the_stack(opening: str) -> None:
    """Checked in a child process: a crash of the parser (stack overflow) must fail the test, not
    pytest. 100,000 levels (1,500 in block style): the composer recursed (RecursionError at ~330),
    a C one would overflow."""
    if opening == "- ":  # block style: indentation grows with depth, so fewer levels
        text = "x:\n" + "".join(f"{'  ' * i}- \n" for i in range(1, 1500))
    else:
        text = "x: " + opening * 100_000 + "\n"
    script = ("import sys\nfrom sm_bt.model import ModelError, load_model_text\n"
              "try:\n    load_model_text(sys.stdin.read(), 'deep.yaml')\n"
              "except ModelError as error:\n    print(error)\n")
    done = subprocess.run([sys.executable, "-c", script], input=text, capture_output=True, text=True, timeout=120,
                          check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "error: the file nests more than 100 levels deep" in done.stdout, done.stdout[:500]
    assert "Traceback" not in done.stderr


def test_a_model_may_nest_as_deep_as_the_limit_allows() -> None:
    # A parameter nested 90 maps deep (a namespaced name, "deep.a.a...a") still loads: the limit
    # is far from anything a model needs.
    model = load_model_text(NODE + "          deep: " + "{a: " * 90 + "1" + "}" * 90 + "\n")
    assert model.parts["n"].modes["__DEFAULT__"].values()["deep" + ".a" * 90] == 1  # type: ignore[union-attr]


def test_same_type_agrees_with_the_type_names() -> None:
    from hypothesis import given
    from hypothesis import strategies as st

    from sm_bt.model.rcl_yaml import same_type, type_name

    scalars = st.one_of(st.booleans(), st.integers(), st.floats(allow_nan=False), st.text(max_size=3))
    values = st.one_of(scalars, st.lists(scalars, max_size=3).map(tuple))

    @given(values, values)
    def agrees(a: object, b: object) -> None:
        assert same_type(a, b) == (type_name(a) == type_name(b))  # type: ignore[arg-type]

    agrees()
    assert not same_type(True, 1) and not same_type(1, 1.0) and same_type((1, 2), (3,))
    assert not same_type((1,), (1.0,)) and not same_type((), (1,))
