"""``reference_issues``: what the reference manager misreads in a model sm_bt loads, with its line."""

from __future__ import annotations

from pathlib import Path

import pytest

from sm_bt import bundled
from sm_bt.model import load_model_text
from sm_bt.model.reference_compat import reference_issues
from sm_bt.model.types import Severity

NODES = """
a:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters: {x: 1}
      FAST:
        ros__parameters: {x: 2}
b:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters: {x: 1}
"""


def findings(text: str) -> list[tuple[int, Severity, str]]:
    load_model_text(text, "m.yaml")  # the check is for models that load
    return [(issue.location.line, issue.severity, issue.message) for issue in reference_issues(text, "m.yaml")]


def system(modes: str) -> str:
    return "sys:\n  ros__parameters:\n    type: system\n    modes:\n" + modes + NODES


def test_a_model_of_the_reference_has_nothing_to_report() -> None:
    text = system("      __DEFAULT__:\n        a: active\n        b: inactive\n"
                  "      RUN:\n        a: active.FAST\n        b: active\n")
    assert findings(text) == []
    assert reference_issues(bundled.path("actuation").read_text(), "actuation.yaml") == []


def test_order_is_an_error_on_its_line() -> None:
    text = system("      __DEFAULT__:\n        a: active\n        b: active\n"
                  "      RUN:\n        a: active.FAST\n        __order__: [\"b\", \"a\"]\n")
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (10, Severity.ERROR)
    assert "takes __order__ for a part and crashes" in message


def test_dont_care_is_an_error_on_its_line() -> None:
    text = system("      __DEFAULT__:\n        a: active\n        b: active\n"
                  "      RUN:\n        a: active.FAST\n        b: __DONTCARE__\n")
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (10, Severity.ERROR)
    assert "reads __DONTCARE__ as the state 'unknown'" in message


def test_unconfigured_in_a_mode_is_a_warning_when_another_mode_configures_the_part() -> None:
    text = system("      __DEFAULT__:\n        a: active\n        b: active\n"
                  "      SAFE:\n        a: active\n        b: unconfigured\n")
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (10, Severity.WARNING)
    assert "never sends 'cleanup'" in message and "never reaches SAFE" in message
    # Unconfigured everywhere: the reference never needs a cleanup for it.
    assert findings(system("      __DEFAULT__:\n        a: active\n        b: unconfigured\n")) == []


def test_a_default_mode_that_is_not_first_is_an_error() -> None:
    text = system("      RUN:\n        a: active.FAST\n"
                  "      __DEFAULT__:\n        a: active\n        b: active\n")
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (5, Severity.ERROR)
    assert "needs __DEFAULT__ before the other modes" in message


def test_defaultmode_naming_another_mode_is_an_error() -> None:
    text = ("sys:\n  ros__parameters:\n    type: system\n    defaultmode: IDLE\n    modes:\n"
            "      IDLE:\n        a: active\n        b: active\n" + NODES)
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (4, Severity.ERROR)
    assert "rename mode 'IDLE' to __DEFAULT__" in message


def test_match_ranges_are_errors_where_written() -> None:
    text = NODES.replace("    modes:\n      __DEFAULT__:\n        ros__parameters: {x: 1}\n      FAST:",
                         "    match: {x: {tolerance: 0.5}}\n    modes:\n      __DEFAULT__:\n"
                         "        ros__parameters: {x: 1}\n      FAST:\n        match: {x: [1, 3]}")
    lines = [(line, severity) for line, severity, _ in findings(text)]
    assert lines == [(5, Severity.ERROR), (10, Severity.ERROR)]


def test_names_holding_rules_or_modes_are_misread() -> None:
    text = NODES.replace("{x: 1}\n      FAST:\n        ros__parameters: {x: 2}",
                         "{x: 1, safety_rules: {max: 1}}\n      FAST:\n        ros__parameters: {x: 2}", 1)
    [(line, severity, message)] = findings(text)
    assert severity is Severity.ERROR and line == 7
    assert "'modes.__DEFAULT__.ros__parameters.safety_rules.max'" in message
    rules = system("      __DEFAULT__:\n        a: active\n        b: active\n"
                   "    rules:\n      fix_modes:\n        if_target: active\n        if_part: [a, inactive]\n"
                   "        new_target: inactive\n")
    [(line, severity, message)] = findings(rules)
    assert (line, severity) == (9, Severity.ERROR)
    assert "makes up a mode" in message


def test_arrays_in_a_node_are_never_matched_by_the_reference() -> None:
    text = NODES.replace("ros__parameters: {x: 1}\n      FAST", "ros__parameters: {x: 1, v: [1, 2]}\n      FAST", 1)
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (7, Severity.WARNING)
    assert "never matches array parameters" in message


@pytest.mark.parametrize("name", ["pilot", "pilot_rules"])
def test_the_bundled_pilot_names_its_order_line(name: str) -> None:
    path = bundled.path(name)
    text = path.read_text()
    order_line = next(number for number, line in enumerate(text.splitlines(), 1) if "__order__:" in line)
    errors = [issue for issue in reference_issues(text, str(path)) if issue.severity is Severity.ERROR]
    assert [issue.location.line for issue in errors] == [order_line]
    assert Path(errors[0].location.file) == path


def test_a_remote_part_is_an_error_on_its_line() -> None:
    text = system("      __DEFAULT__:\n        a: active\n        b: active\n        robot: active\n") + (
        "robot:\n  ros__parameters:\n    type: remote\n    manager: /robot\n    modes: [__DEFAULT__]\n")
    [(line, severity, message)] = findings(text)
    assert (line, severity) == (24, Severity.ERROR)
    assert message == ("reference: robot: the reference has no remote parts (it takes any type but 'node' for a "
                       "system): a model with remote parts is for sm_bt only")
