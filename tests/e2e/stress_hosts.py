"""``make stress``: the across-hosts harness (tests/support/hosts.py) cut and healed, seen as an operator
sees it: ``sm-bt`` run again and again on the brain side until it says the robot's nodes are unknown,
then back (tests/e2e/test_across_hosts.py checks the same verdicts on the manager's own lines and
/diagnostics, in ``make test``). Needs root."""

from __future__ import annotations

import time

import partitions
import pytest
from hosts import Hosts, two_hosts_fixture  # noqa: F401

pytestmark = [pytest.mark.ros, pytest.mark.netns]

#: The manager marks unreachable nodes unknown within this long of a cut (generous for now).
UNKNOWN_WITHIN = 5.0
#: After a heal, the manager (and the CLI) see the nodes' real state again within this long.
BACK_WITHIN = 10.0


def _poll(hosts: Hosts, argv: tuple[str, ...], wanted: str, since: float, within: float) -> tuple[float, list[str]]:
    """Run ``sm-bt ARGV`` on the brain side until its stdout is ``wanted``; the seconds from ``since`` when
    the answer came, and every answer (for the failure message). Fails when no call *started* within
    ``within`` s of ``since`` answered so (each call takes 0.7-3.5 s: rclpy's start and discovery, and
    more on a loaded machine: a call may take 6 s to find the manager before it counts as no answer)."""
    answers: list[str] = []
    while True:
        started = time.monotonic()
        if started - since > within:
            raise AssertionError(f"sm-bt {' '.join(argv)}: no {wanted!r} within {within} s; answers: {answers}")
        code, out, err = hosts.sm_bt(*argv, "--timeout", "6", timeout=20.0)
        answers.append(f"+{started - since:.2f} s: exit {code} {out.strip()!r} {err.strip()!r}")
        if code == 0 and out == wanted:
            return time.monotonic() - since, answers
        time.sleep(0.1)


def test_a_cut_link_makes_the_nodes_unknown_and_a_healed_one_brings_them_back(two_hosts: Hosts) -> None:
    hosts = two_hosts
    hosts.nodes("pilot")
    manager = hosts.manager("pilot")
    code, out, err = hosts.sm_bt("state", "set", "pilot", "configure", "--wait")
    assert code == 0, (out, err, manager.stderr)

    cut = hosts.cut()
    # amcl's mode as the manager infers it (`state get amcl` would ask amcl itself, which is unreachable).
    unknown_after, cut_answers = _poll(hosts, ("mode", "get", "amcl"), "amcl: unknown\n", cut, UNKNOWN_WITHIN)
    ping = hosts.ping(count=5, interval=0.05, wait=0.3)
    assert ping.received == 0, ping  # the link is cut
    assert manager.alive, manager.stderr

    healed = hosts.heal()
    back_after, heal_answers = _poll(hosts, ("state", "get", "pilot"), "pilot: inactive\n", healed, BACK_WITHIN)
    assert hosts.sm_bt("state", "get", "amcl") == (0, "amcl: inactive\n", "")
    assert hosts.sm_bt("mode", "get", "amcl")[1] != "amcl: unknown\n"
    print(f"unknown {unknown_after:.2f} s after the cut ({cut_answers}); inactive again {back_after:.2f} s after "
          f"the heal ({heal_answers})")


#: Abrupt turns of the link from plain to lossy (30 % of frames lost each way, the rest 0.2 s late).
TURNS, LOSS, DELAY = 30, 0.3, 0.2
NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")
#: The liveness window on a plain link (the manager's default).
LIVENESS = 0.9


def test_a_link_that_turns_lossy_at_once_is_seldom_taken_for_a_cut(two_hosts: Hosts) -> None:
    """Each turn comes once the manager's window is back at its plain-link width, so that the first
    lost answers come before it has adapted: its backup probes must get an answer through within
    0.9 s of the last. Counts the turns after which the manager took the nodes for gone."""
    hosts = two_hosts
    diagnostics = hosts.watch("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
    hosts.nodes("pilot", "--state", "inactive")
    manager = hosts.manager("pilot")

    def settled(since: float) -> None:
        """Every node reachable, behind a plain link's window, in a message after ``since``."""
        give_up = since + 30.0
        while True:
            seen = partitions.latest(diagnostics, since)
            if all(seen.get(node, {}).get("reachable") == "true"
                   and float(seen[node].get("liveness_window_s") or 99) <= LIVENESS + 0.01 for node in NODES):
                return
            assert time.monotonic() < give_up, f"not settled within 30 s: {seen}\n{manager.stderr}"
            time.sleep(0.1)

    taken = []
    for turn in range(TURNS):
        settled(time.monotonic())
        before = len(manager.lines("vanished"))
        hosts.lossy(LOSS, DELAY)
        time.sleep(2.0)  # past the first window, and a few probes over the bad link
        hosts.lossy(0.0, 0.0)
        if len(manager.lines("vanished")) > before:
            taken.append(turn)
    print(f"MEASURED a link turning lossy at once ({LOSS:.0%} loss, {DELAY * 1000:.0f} ms each way): taken for a cut "
          f"after {len(taken)} of {TURNS} turns {taken}; relay {hosts.relay_stats()}")
    assert len(taken) <= TURNS // 10, manager.lines("vanished")
