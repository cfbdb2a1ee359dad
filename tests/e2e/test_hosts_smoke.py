"""The across-hosts harness itself (tests/support/hosts.py): the robot's nodes in one network namespace, the mode
manager in another, a relay between them.

Checked: a mode change made from the brain side reaches the nodes on the robot side, and the events
come back across (with times comparable to the test's own clock); the relay's loss and delay are what
was asked for, and nothing when nothing was asked; after the teardown no namespace and no process of
the harness is left. A cut link seen by the CLI from the brain side is in ``make stress``
(tests/e2e/stress_hosts.py); ``make test`` cuts links in tests/e2e/test_across_hosts.py.
Needs root (the tests fail without it, they do not skip).
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

import pytest
from hosts import Hosts, namespaces, require_root, two_hosts_fixture  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.netns]

def test_a_mode_change_from_the_brain_side_reaches_the_robot_and_its_events_come_back(two_hosts: Hosts) -> None:
    hosts = two_hosts
    system_events = hosts.watch("/pilot/transition_event", "lifecycle_msgs/msg/TransitionEvent")
    node_events = hosts.watch("/amcl/transition_event", "lifecycle_msgs/msg/TransitionEvent")
    mode_events = hosts.watch("/pilot/mode_event", "system_modes_msgs/msg/ModeEvent")
    nodes = hosts.nodes("pilot")
    manager = hosts.manager("pilot")
    for process in (nodes, manager):  # `ip netns exec` and `env` exec'ed: the PID is the python process's
        assert process.pid is not None
        assert os.readlink(f"/proc/{process.pid}/exe") == os.path.realpath(sys.executable)
    # A watcher gets only what is published once it and the publisher have discovered each other: the
    # node's (on the robot side) and the manager's (whose many endpoints can take 2.5-3.5 s to discover).
    for watch in (node_events, system_events, mode_events):
        watch.wait_for_publishers(1, timeout=10.0)

    asked = time.monotonic()
    code, out, err = hosts.sm_bt("state", "set", "pilot", "configure", "--wait")
    answered = time.monotonic()
    assert (code, err) == (0, ""), (out, err, manager.stderr)
    assert out.startswith("pilot: inactive "), out
    assert hosts.sm_bt("state", "get", "amcl") == (0, "amcl: inactive\n", "")  # the node's own service, across
    assert hosts.sm_bt("state", "get", "pilot") == (0, "pilot: inactive\n", "")  # the manager's view

    # The events: the node's own (from the robot side) and the manager's, in the test's clock.
    stamp, _ = node_events.wait_for(lambda m: m["goal_state"]["label"] == "inactive", timeout=5.0)
    assert asked <= stamp <= answered
    stamp, _ = system_events.wait_for(lambda m: m["goal_state"]["label"] == "inactive", timeout=5.0)
    assert asked <= stamp <= answered
    assert not mode_events.messages  # inactive: no mode (mode_event says "active in this mode")

    asked = time.monotonic()
    code, out, err = hosts.sm_bt("mode", "set", "pilot", "f_normal_mode", "--wait")
    assert (code, err) == (0, ""), (out, err, manager.stderr)
    stamp, event = mode_events.wait_for(timeout=5.0)
    assert event["goal_mode"]["label"] == "f_normal_mode" and stamp >= asked, mode_events.messages
    assert hosts.sm_bt("state", "get", "amcl") == (0, "amcl: active\n", "")


def test_the_relay_delays_and_drops_as_asked_and_is_transparent_by_default(two_hosts: Hosts) -> None:
    hosts = two_hosts
    plain = hosts.ping(count=20, interval=0.02, wait=1.0)
    assert (plain.sent, plain.received) == (20, 20), plain
    assert statistics.median(plain.rtts) < 0.01 and plain.max < 0.1, plain.rtts

    hosts.lossy(0.3, 0.2)
    before = hosts.relay_stats()
    lossy = hosts.ping(count=40, interval=0.02, wait=1.0)
    after = hosts.relay_stats()
    assert lossy.rtts and lossy.min >= 0.35, lossy  # 0.2 s each way
    assert lossy.max < 0.6, lossy
    assert 0 < lossy.received < lossy.sent, lossy  # about half the round trips are lost: 1 - 0.7 ** 2
    assert after["dropped"] > before["dropped"]

    hosts.lossy(0, 0)
    again = hosts.ping(count=20, interval=0.02, wait=1.0)
    assert again.received == 20 and statistics.median(again.rtts) < 0.01, again


def test_closing_removes_the_namespaces_the_processes_and_the_temp_dir() -> None:
    require_root()
    hosts = Hosts()
    try:
        hosts.open()
        made = set(hosts.namespaces.values())
        assert made <= namespaces()
        hosts.nodes("pilot")
        hosts.watch("/amcl/transition_event", "lifecycle_msgs/msg/TransitionEvent")
        pids = hosts.pids
        assert len(pids) == 3  # relay, nodes, watcher
        assert all(Path(f"/proc/{pid}").exists() for pid in pids)
        directory = hosts.directory
        assert directory.is_dir()
    finally:
        hosts.close()
    assert not made & namespaces()
    assert not [pid for pid in pids if Path(f"/proc/{pid}").exists()]
    assert not directory.exists()
    assert hosts.close_seconds < 5.0
