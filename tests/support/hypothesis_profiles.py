"""Hypothesis profiles for the manager's property tests (imported by them, not by conftest).

* ``default`` (``make test``): a few hundred scenarios in all, no deadline (a scenario's wall time
  depends on the machine, not on the code under test), examples saved under ``build/hypothesis``
  (ignored by git; a fresh CI clone starts empty, so the database cannot make CI flaky).
* ``stress`` (``make stress``, ``SM_BT_HYPOTHESIS_PROFILE=stress``): at least 10,000 scenarios.
* ``shrink`` (``SM_BT_HYPOTHESIS_PROFILE=shrink``): as ``default``, and a failure is shrunk to a
  minimal scenario (the others stop at the first failure, which they print as Python).

Each property test asks :func:`examples` for its share, so that the profiles scale every test
together.
"""

from __future__ import annotations

import os
from pathlib import Path

from hypothesis import HealthCheck, Phase, settings
from hypothesis.database import DirectoryBasedExampleDatabase

PROFILE_VARIABLE = "SM_BT_HYPOTHESIS_PROFILE"
DATABASE = Path(__file__).resolve().parents[2] / "build" / "hypothesis"

#: How many examples the stress profile runs for each one of the default profile.
STRESS_FACTOR = 25

_BASE = settings(
    deadline=None,
    database=DirectoryBasedExampleDatabase(DATABASE),
    # Scenarios are big by design (a model, options, a list of timed actions).
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much],
    print_blob=True,
)
# Shrinking a failure takes minutes; in `make test` the failing scenario is printed as Python
# unshrunk (and saved in the database). Run the `shrink` profile to get the minimal one, and keep
# it as a plain test in test_manager_regressions.py.
_NO_SHRINK = [Phase.explicit, Phase.reuse, Phase.generate, Phase.target]
settings.register_profile("default", _BASE, max_examples=100, phases=_NO_SHRINK)
settings.register_profile("shrink", _BASE, max_examples=100)
settings.register_profile("stress", _BASE, max_examples=100 * STRESS_FACTOR, phases=_NO_SHRINK)
PROFILE = os.environ.get(PROFILE_VARIABLE, "default")
settings.load_profile(PROFILE)


def examples(default: int, *, stress: int | None = None) -> settings:
    """Settings for a property test that runs ``default`` examples in the default profile and
    ``stress`` (default: ``STRESS_FACTOR`` times as many) in the stress profile."""
    if PROFILE != "stress":
        return settings(max_examples=default)
    return settings(max_examples=stress if stress is not None else default * STRESS_FACTOR)
