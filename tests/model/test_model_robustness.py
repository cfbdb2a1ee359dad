"""Damaged files never escape as raw exceptions: they load, or raise ModelError with located issues."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from sm_bt.model import ModelError, load_model_text

FIXTURES = [Path(__file__).parents[1] / "models" / name
            for name in ("loader_rules.yaml", "loader_defaultmode.yaml", "loader_namespaced.yaml",
                         "loader_nested.yaml")]
# Values that break the model in different layers: YAML syntax, rcl typing, structure, states.
REPLACEMENTS = ("", "[", "{}", "*a", "ACTIVE.X", "[1, 0.5]", "{a: [b]}")


def mutations(text: str) -> Iterator[tuple[str, str]]:
    lines = text.splitlines(keepends=True)
    for index, line in enumerate(lines):
        before, after = lines[:index], lines[index + 1:]
        yield f"delete line {index + 1}", "".join(before + after)
        yield f"dedent line {index + 1}", "".join([*before, line[2:] if line.startswith("  ") else line, *after])
        if ":" in line:
            key = line.split(":", 1)[0]
            for value in REPLACEMENTS:
                yield f"line {index + 1} value {value!r}", "".join([*before, f"{key}: {value}\n", *after])


@pytest.mark.parametrize("path", FIXTURES, ids=[p.name for p in FIXTURES])
def test_mutated_fixtures_load_or_raise_model_error(path: Path) -> None:
    line_count = path.read_text().count("\n")
    for label, text in mutations(path.read_text()):
        try:
            load_model_text(text, "mutated.yaml", strict=False)
        except ModelError as error:
            assert error.issues, label
            for issue in error.issues:
                assert 0 <= issue.location.line <= line_count + 1, (label, str(issue))
                assert issue.message, label


# -- regressions of hostile and huge model files (each once a crash or a quadratic cost) ----------


def _nested_systems(depth: int) -> str:
    out = []
    for index in range(depth):
        inner = f"s{index + 1}" if index + 1 < depth else "leaf"
        out.append(f"s{index}:\n  ros__parameters:\n    type: system\n    parts:\n      {inner}\n"
                   f"    modes:\n      __DEFAULT__:\n        {inner}: active\n")
    out.append("leaf:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n"
               "        ros__parameters:\n          x: 1\n")
    return "".join(out)


def test_regression_a_thousand_systems_one_inside_the_other_load_and_run() -> None:
    """The cycle check recursed once per level: RecursionError at about 1,000."""
    from sm_bt.sim import SimulatedSystem

    model = load_model_text(_nested_systems(3000), "deep.yaml")
    assert model.ancestors("leaf")[-1] == "s0" and len(model.ancestors("leaf")) == 3000
    system = SimulatedSystem(model, record=False)
    request = system.finish(system.manager.change_state("s0", "configure"))
    assert request.succeeded, request.reason


def test_regression_a_cycle_deep_in_the_hierarchy_is_still_reported_once() -> None:
    text = _nested_systems(1500).replace("      leaf\n", "      s700\n", 1).replace("        leaf: active\n",
                                                                                  "        s700: active\n", 1)
    with pytest.raises(ModelError) as raised:
        load_model_text(text, "cycle.yaml")
    cycles = [issue for issue in raised.value.issues if "contains itself" in issue.message]
    assert len(cycles) == 1
    assert cycles[0].message.startswith("system 's700' contains itself through its parts: s700 -> s701 -> s702 -> "
                                        "s703 -> ... 795 more ... -> s1499 -> s700: remove one of these parts")


def test_regression_a_thousand_identical_modes_are_one_warning() -> None:
    """Every pair was compared and warned about: 500,500 warnings and seconds for 1,000 modes."""
    modes = "".join(f"      M{index}:\n        ros__parameters:\n          x: 1\n" for index in range(1000))
    text = ("n:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n        ros__parameters:\n"
            "          x: 1\n" + modes)
    (warning,) = load_model_text(text, "same.yaml").warnings
    assert warning.location.line == 8  # the second of the group
    assert warning.message.startswith("node 'n': modes '__DEFAULT__', 'M0', 'M1', 'M2' and 997 more have the same "
                                      "parameter values (x=1)")


def test_regression_a_file_that_is_not_utf8_names_the_line_and_column(tmp_path: Path) -> None:
    from sm_bt.model import load_model

    path = tmp_path / "latin1.yaml"
    path.write_bytes(b"a:\n  ros__parameters:\n    type: node\n    # caf\xe9\n")
    with pytest.raises(ModelError) as raised:
        load_model(path)
    assert str(raised.value) == f"{path}:4: error: byte 0xe9 at column 10 is not UTF-8: save the file as UTF-8 text"


@pytest.mark.parametrize("text", ["*a\n", "&a x\n", "--- *a\n"])
def test_regression_alias_and_anchor_only_documents_name_line_one(text: str) -> None:
    with pytest.raises(ModelError) as raised:
        load_model_text(text, "a.yaml")
    assert raised.value.issues and all(issue.location.line >= 1 for issue in raised.value.issues)


# -- found by the fuzz tests (test_model_fuzz.py), smallest inputs ---------------------------------------


@pytest.mark.parametrize(("text", "line"), [("[\n", 1), ("a: [\n\n", 2), ("  [  # a comment, no line break", 1),
                                            ("a: [\r\rb", 3)])
def test_regression_a_syntax_error_at_the_end_of_the_file_is_on_its_last_line(text: str, line: int) -> None:
    """libyaml marks the end of the stream one line below a final line break: line 2 of a 1-line file."""
    with pytest.raises(ModelError) as raised:
        load_model_text(text, "end.yaml")
    (issue,) = raised.value.issues
    assert issue.location.line == line, str(issue)


def test_regression_a_forbidden_character_after_non_ascii_text_is_on_its_own_line() -> None:
    """libyaml's position counts UTF-8 bytes; it was used as a character index (line 4 of 3)."""
    with pytest.raises(ModelError) as raised:
        load_model_text("é: 1\né: 2\na: \x7f\n", "del.yaml")
    assert str(raised.value) == ("del.yaml:3: error: character 127 is not allowed in YAML (control characters and "
                                 "invalid code points): remove it")
