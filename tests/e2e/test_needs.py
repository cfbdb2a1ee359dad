"""The requirement markers (tests/support/needs.py): without ROS 2 (or Chromium, or root) the tests
that need it are skipped with the reason and the fix, the rest runs; under ``make test`` they fail."""

from __future__ import annotations

import needs
import pytest

NO_ROS = "no rclpy"

SUITE = """
import pytest

@pytest.fixture
def node_processes():
    return None

@pytest.mark.ros
def test_marked():
    pass

def test_with_a_ros_fixture(node_processes):
    pass

@pytest.mark.browser
def test_in_a_browser():
    pass

def test_plain():
    pass
"""


@pytest.fixture
def without_ros(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(needs, "missing", lambda marker: NO_ROS if marker == "ros" else None)
    monkeypatch.setattr(needs, "ROS_PACKAGES", needs.ROS_PACKAGES | {"no_such_ros_package"})
    monkeypatch.delenv(needs.NEED_ALL, raising=False)


def test_without_ros_its_tests_are_skipped_with_the_reason_and_the_rest_runs(
        pytester: pytest.Pytester, without_ros: None) -> None:
    pytester.makepyfile(test_suite=SUITE, test_imports_ros="import no_such_ros_package\n\ndef test_x():\n    pass\n")
    result = pytester.runpytest_inprocess("-p", "needs", "-p", "no:sm_bt", "-rs")
    result.assert_outcomes(passed=2, skipped=3)  # the marked test, the fixture's, the module that imports ROS
    result.stdout.fnmatch_lines(["SKIPPED * needs ROS 2 (the ros extra and the interface packages): no rclpy; *"])
    assert "tools/ensure_interfaces.sh" in result.stdout.str()


def test_under_make_test_a_missing_requirement_fails_instead(
        pytester: pytest.Pytester, without_ros: None, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(needs.NEED_ALL, "1")
    pytester.makepyfile(test_suite=SUITE)
    result = pytester.runpytest_inprocess("-p", "needs", "-p", "no:sm_bt")
    result.assert_outcomes(passed=2, errors=2)
    result.stdout.fnmatch_lines(["*needs ROS 2 * (SM_BT_TESTS_NEED_ALL is set: nothing may be skipped)"])
    pytester.makepyfile(test_imports_ros="import no_such_ros_package\n\ndef test_x():\n    pass\n")
    result = pytester.runpytest_inprocess("-p", "needs", "-p", "no:sm_bt", "test_imports_ros.py")
    assert result.ret == pytest.ExitCode.INTERRUPTED  # a collection error stops the run
    result.stdout.fnmatch_lines(["*No module named 'no_such_ros_package'*"])


def test_what_is_missing_here_is_told_by_marker() -> None:
    for marker in needs.WHAT:
        why = needs.missing(marker)
        assert why is None or why.strip(), marker
    with pytest.raises(ValueError, match="unknown requirement marker"):
        needs.missing("gpu")
