"""``make stress``: many partition/heal cycles at random moments (tests/support/partitions.py), each
followed by the invariants. ``SM_BT_PARTITION_CYCLES`` and ``SM_BT_PARTITION_SEED`` set how many and
which (a failure prints its seed: run it again with that seed to replay the same choices)."""

from __future__ import annotations

import os
import random

import pytest
from hosts import Hosts, two_hosts_fixture  # noqa: F401
from partitions import run

pytestmark = [pytest.mark.ros, pytest.mark.netns]

CYCLES = int(os.environ.get("SM_BT_PARTITION_CYCLES", "30"))


def test_partition_and_heal_cycles_keep_the_invariants(two_hosts: Hosts) -> None:
    seed = int(os.environ.get("SM_BT_PARTITION_SEED", "") or random.SystemRandom().randrange(1 << 30))
    record = run(two_hosts, CYCLES, seed)
    settle = sorted(record.settle_times)
    print(f"STRESS partitions: {CYCLES} cycles, seed {seed}: every invariant held; {record.refused} requests "
          f"refused while cut; settled after a heal in {settle[0]:.2f}-{settle[-1]:.2f} s "
          f"(median {settle[len(settle) // 2]:.2f} s)")
