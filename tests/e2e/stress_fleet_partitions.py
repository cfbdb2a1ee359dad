"""``make stress``: partition/heal cycles between a fleet's manager and a robot's, at random moments
(tests/support/fleet_partitions.py), each followed by the invariants. ``SM_BT_PARTITION_CYCLES`` and
``SM_BT_PARTITION_SEED`` set how many and which (a failure prints its seed: run it again with that
seed to replay the same choices)."""

from __future__ import annotations

import os
import random
from pathlib import Path

import pytest
from fleet_partitions import run
from hosts import Hosts, two_hosts_fixture  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.netns]

CYCLES = int(os.environ.get("SM_BT_PARTITION_CYCLES", "30"))


def test_fleet_partition_and_heal_cycles_keep_the_invariants(two_hosts: Hosts, tmp_path: Path) -> None:
    seed = int(os.environ.get("SM_BT_PARTITION_SEED", "") or random.SystemRandom().randrange(1 << 30))
    record = run(two_hosts, CYCLES, seed, tmp_path)
    settle = sorted(record.settle_times[1:])  # the first is the bring-up's
    print(f"STRESS fleet partitions: {CYCLES} cycles, seed {seed}: every invariant held; {record.refused} requests "
          f"refused while cut; consistent after a heal in {settle[0]:.2f}-{settle[-1]:.2f} s "
          f"(median {settle[len(settle) // 2]:.2f} s)")
