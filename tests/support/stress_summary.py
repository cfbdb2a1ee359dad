"""pytest plugin for ``make stress``: print what the property tests did, at the end.

Loaded with ``-p stress_summary`` (``tests`` on ``PYTHONPATH``), so that ``make test`` does not
print it. The numbers come from :data:`scenario.STATS`, which every scenario run adds to, and
:data:`model_fuzz.OUTCOMES`, which every fuzzed model file adds to.
"""

from __future__ import annotations

from typing import Any


def pytest_terminal_summary(terminalreporter: Any) -> None:
    from model_fuzz import summary
    from scenario import STATS

    terminalreporter.section("stress summary")
    scenarios = STATS.summary().splitlines() if STATS.scenarios else []
    for line in [*scenarios, *summary().splitlines()]:
        terminalreporter.write_line(line)
