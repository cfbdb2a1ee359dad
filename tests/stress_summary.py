"""pytest plugin for ``make stress``: print what the property tests' scenarios did, at the end.

Loaded with ``-p stress_summary`` (``tests`` on ``PYTHONPATH``), so that ``make test`` does not
print it. The numbers come from :data:`scenario.STATS`, which every scenario run adds to.
"""

from __future__ import annotations

from typing import Any


def pytest_terminal_summary(terminalreporter: Any) -> None:
    from scenario import STATS

    terminalreporter.section("stress summary")
    for line in STATS.summary().splitlines():
        terminalreporter.write_line(line)
