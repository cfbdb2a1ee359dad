"""The manager and the robot's nodes on two hosts (network namespaces, tests/support/hosts.py): cuts, lossy
links and heals, seen the way an operator sees them (the manager's log, /diagnostics, the system's
transition_event). Needs root; each test builds and removes its own namespaces."""

from __future__ import annotations

import random
import re
import threading
import time
from typing import Any

import partitions
import pytest
from hosts import Hosts, two_hosts_fixture  # noqa: F401
from ros_processes import Starved

from sm_bt.ros.diagnostics import ERROR

pytestmark = [pytest.mark.ros, pytest.mark.netns]

#: The manager's liveness window on a good link (RosBackend's default): detection within a second,
#: plus as long as a process stood still meanwhile (a machine loaded by the whole suite: 1.21 s once).
DETECTION = 1.0
LIVENESS = 0.9
#: The manager's own reason for a node it cannot reach.
UNREACHABLE = re.compile(r"node (\w+) vanished: no answer from /\1 for (?:0\.9|1\.0) s \(node exited, or network "
                         r"unreachable\)")
NODES = ("amcl", "controller_server", "pointcloud_to_laser", "laser_resender")
#: The bad link of the lossy test: each frame lost with this probability, the others delayed (each way).
LOSS, DELAY = 0.3, 0.2
#: The pilot's bring-up to its normal mode over it is confirmed within this long (DDS retransmits
#: what is lost, every 0.1 s with the harness's profile).
LOSSY_CHANGE = 5.0


def status(message: dict[str, Any], part: str) -> dict[str, Any] | None:
    return next((s for s in message["status"] if s["hardware_id"] == part), None)


def values(status: dict[str, Any]) -> dict[str, str]:
    return {pair["key"]: pair["value"] for pair in status["values"]}


def actual(message: dict[str, Any], part: str) -> str | None:
    """The part's actual state/mode in a /diagnostics message, if the message has the part."""
    found = status(message, part)
    return None if found is None else values(found)["actual"]


def level(status: dict[str, Any]) -> int:
    raw = status["level"]
    return int(raw[0] if isinstance(raw, list) else raw)


def reachable(part: str, wanted: bool = True) -> Any:
    def check(message: dict[str, Any]) -> bool:
        found = status(message, part)
        return found is not None and values(found).get("reachable") == ("true" if wanted else "false")
    return check


def wait_for_lines(manager: Any, count: int, *words: str, timeout: float = 2.0) -> list[str]:
    """The manager's log lines with ``words``, once there are ``count`` of them (or ``timeout`` passed)."""
    give_up = time.monotonic() + timeout
    while len(found := manager.lines(*words)) < count and time.monotonic() < give_up:
        time.sleep(0.05)
    return found


def start(hosts: Hosts, *node_args: str, manager_args: tuple[str, ...] = ()) -> tuple[Any, Any, Any]:
    """Nodes, manager, and a /diagnostics watcher on the brain side, every node reached."""
    diagnostics = hosts.watch("/diagnostics", "diagnostic_msgs/msg/DiagnosticArray")
    nodes = hosts.nodes("pilot", *node_args)
    manager = hosts.manager("pilot", *manager_args)
    for node in NODES:
        diagnostics.wait_for(reachable(node), timeout=20.0)
    return nodes, manager, diagnostics


def test_an_idle_cut_is_told_within_a_second_with_the_honest_reason_and_healed(two_hosts: Hosts) -> None:
    hosts = two_hosts
    events = hosts.watch("/pilot/transition_event", "lifecycle_msgs/msg/TransitionEvent")
    _, manager, diagnostics = start(hosts, "--state", "inactive")
    events.wait_for_publishers(1, timeout=10.0)
    time.sleep(1.0)
    with Starved() as starved:
        cut = hosts.cut()
        told, _ = events.wait_for(lambda m: m["goal_state"]["label"] == "unknown", timeout=5.0, since=cut)
    assert told - cut <= DETECTION + starved.worst, (
        f"pilot unknown {told - cut:.2f} s after the cut (a process here stood still for {starved.worst:.2f} s)")
    vanished = wait_for_lines(manager, len(NODES), "vanished")  # the first makes the pilot unknown
    assert sorted(m.group(1) for line in vanished if (m := UNREACHABLE.search(line))) == sorted(NODES), vanished
    assert not manager.lines("process gone")
    _, message = diagnostics.wait_for(reachable("amcl", False), timeout=2.0, since=cut)
    amcl = status(message, "amcl")
    assert amcl is not None and level(amcl) == ERROR and amcl["message"].startswith("unreachable: no answer from /amcl")
    time.sleep(2.0)
    healed = hosts.heal()
    back, _ = events.wait_for(lambda m: m["goal_state"]["label"] == "inactive", timeout=15.0, since=healed)
    print(f"MEASURED idle cut: told {told - cut:.2f} s after the cut; re-acquired {back - healed:.2f} s after the heal")
    assert manager.lines("appeared: inactive")


def test_a_cut_during_a_change_fails_it_within_a_second_on_diagnostics(two_hosts: Hosts) -> None:
    hosts = two_hosts
    amcl_events = hosts.watch("/amcl/transition_event", "lifecycle_msgs/msg/TransitionEvent")
    # amcl takes 2 s per transition, in a process of its own: the cut falls inside the change.
    # (A process whose every node is inside a long transition of the manager's cannot answer, busy or
    # cut: the manager waits for that call's own timeout. Its neighbours' silence tells at once.)
    hosts.nodes("pilot", "--only", "amcl", "--transition-delay", "2.0")
    _, manager, diagnostics = start(hosts, "--only", "controller_server,pointcloud_to_laser,laser_resender")
    amcl_events.wait_for_publishers(1, timeout=10.0)
    result: list[tuple[int, str, str]] = []
    change = threading.Thread(target=lambda: result.append(
        hosts.sm_bt("mode", "set", "pilot", "f_normal_mode", "--wait", "--timeout", "15")))
    change.start()
    try:
        # The change has begun on the robot: cut now.
        amcl_events.wait_for(lambda m: m["goal_state"]["label"] == "configuring", timeout=20.0)
        # ... and the neighbours' own steps have been answered. Cut while the manager still waits for
        # every node of both processes, and it rightly waits for a call's timeout (busy or cut: under
        # load, once, the neighbours' answers had not come back when amcl's event did).
        diagnostics.wait_for(lambda m: (actual(m, "controller_server") or "").startswith("active")
                             and actual(m, "pointcloud_to_laser") == "inactive", timeout=10.0)
        with Starved() as starved:
            cut = hosts.cut()
            try:
                failed_at, message = diagnostics.wait_for(
                    lambda m: (s := status(m, "pilot")) is not None and values(s)["last_request_outcome"] == "failed",
                    timeout=12.0, since=cut)
            except AssertionError as error:
                raise AssertionError(f"{error}\nthe manager's log:\n{manager.stderr}") from None
    finally:
        change.join(30.0)
    pilot = status(message, "pilot")
    assert pilot is not None and level(pilot) == ERROR
    assert failed_at - cut <= DETECTION + starved.worst, (
        f"failed {failed_at - cut:.2f} s after the cut (a process here stood still for {starved.worst:.2f} s)\n"
        f"{manager.stderr}")
    assert re.search(r"no answer from /\w+ for (?:0\.9|1\.0) s", values(pilot)["last_request_reason"]), values(pilot)
    print(f"MEASURED cut mid-change: failure on /diagnostics {failed_at - cut:.2f} s after the cut")
    # The waiting command heard the failure on /diagnostics too, rather than waiting out its 15 s.
    assert result and result[0][0] != 0 and "the manager says request" in result[0][2], result


def test_a_change_refused_during_a_cut_changes_nothing_after_the_heal(two_hosts: Hosts) -> None:
    hosts = two_hosts
    amcl_events = hosts.watch("/amcl/transition_event", "lifecycle_msgs/msg/TransitionEvent")
    _, manager, diagnostics = start(hosts, "--state", "inactive", manager_args=("--grace-period", "0.5"))
    cut = hosts.cut()
    diagnostics.wait_for(reachable("amcl", False), timeout=3.0, since=cut)
    code, _, err = hosts.sm_bt("mode", "set", "pilot", "f_normal_mode")
    assert code != 0 and "refused" in err, err
    assert manager.lines("refused", "f_normal_mode")
    healed = hosts.heal()
    diagnostics.wait_for(reachable("amcl"), timeout=15.0, since=healed)
    time.sleep(3.0)  # grace period and recovery would have acted by now
    assert not [m for _, m in amcl_events.messages if m["goal_state"]["label"] in ("activating", "active")]
    assert not manager.lines("started", "f_normal_mode"), manager.lines("started")
    assert hosts.sm_bt("state", "get", "amcl")[1] == "amcl: inactive\n"


@pytest.mark.long
def test_a_lossy_link_is_slow_not_gone_and_changes_complete(two_hosts: Hosts) -> None:
    hosts = two_hosts
    _, manager, diagnostics = start(hosts, "--state", "inactive")
    hosts.lossy(LOSS, DELAY)
    time.sleep(5.0)  # idle on the bad link while the window adapts to it
    # Its first lost answers come before the window has adapted: the backup probes usually get one
    # through in time, not always (in CI once; make stress counts how often). Nodes taken for gone then
    # are taken back at their next answers, over the bad link, and from then on they are slow, not gone.
    at_the_turn, since = manager.lines("vanished"), time.monotonic()
    for node in NODES:
        diagnostics.wait_for(reachable(node), timeout=20.0, since=since)
    took = []
    for mode in ("f_normal_mode", "f_degraded_mode"):
        code, _, err = hosts.sm_bt("mode", "set", "pilot", mode, "--wait", "--timeout", "20")
        assert code == 0, f"{mode}: {err}\n{manager.stderr}"
        done = manager.lines("change_mode pilot", mode, "succeeded")
        assert done, manager.stderr
        took.append(float(re.findall(r"succeeded in ([\d.]+) s", done[-1])[0]))
    print(f"MEASURED lossy link ({LOSS:.0%} loss, {DELAY * 1000:.0f} ms each way): changes confirmed in "
          f"{', '.join(f'{t:.2f}' for t in took)} s; taken for a cut at the turn: {bool(at_the_turn)}; "
          f"relay {hosts.relay_stats()}")
    # The switch to degraded takes five ordered steps, each a round trip of 0.4 s or more (a lost
    # datagram costs about another): it completes, its time is reported, not bounded.
    assert took[0] <= LOSSY_CHANGE, took
    assert manager.lines("vanished") == at_the_turn, manager.stderr
    assert hosts.relay_stats()["dropped"] > 0
    # The manager's view names the link as it is: slow (not gone), with the round trip it measures
    # (at least the relay's 2 x DELAY; its estimate converges as probes go on) behind a wider window.
    floor = 2 * DELAY * 1000

    def link_seen(message: Any) -> bool:
        amcl = status(message, "amcl") or {}
        seen = values(amcl) if amcl else {}
        return ("slow link" in amcl.get("message", "") and seen.get("reachable") == "true"
                and float(seen.get("round_trip_ms") or 0) >= floor
                and float(seen.get("liveness_window_s") or 0) > LIVENESS)

    _, message = diagnostics.wait_for(link_seen, timeout=10.0)
    amcl = status(message, "amcl")
    assert amcl is not None
    print(f"MEASURED lossy link: amcl round trip {values(amcl)['round_trip_ms']} ms, liveness window "
          f"{values(amcl)['liveness_window_s']} s")


def test_nodes_restarted_behind_a_cut_come_back_said_so_and_are_restored(two_hosts: Hosts) -> None:
    hosts = two_hosts
    nodes, manager, diagnostics = start(hosts, "--state", "inactive")
    code, _, err = hosts.sm_bt("mode", "set", "pilot", "f_normal_mode", "--wait", "--timeout", "15")
    assert code == 0, err
    # Cut on the manager's side: the robot's own link stays up. (A process started while its own
    # machine's interface has no link is not reachable from elsewhere until it restarts: Fast DDS
    # chooses its interfaces when it starts.)
    cut = hosts.cut(side="brain")
    diagnostics.wait_for(reachable("amcl", False), timeout=3.0, since=cut)
    nodes.stop()
    hosts.nodes("pilot")  # a fresh process: every node unconfigured
    healed = hosts.heal()
    back, message = diagnostics.wait_for(reachable("amcl"), timeout=15.0, since=healed)
    amcl = status(message, "amcl")
    assert amcl is not None
    assert re.fullmatch(r"unconfigured \(back after [\d.]+ s; was active\.__DEFAULT__\)", values(amcl)["last_return"])
    restored, _ = diagnostics.wait_for(
        lambda m: (s := status(m, "pilot")) is not None and level(s) == 0 and s["message"] == "active.f_normal_mode",
        timeout=10.0, since=back)
    print(f"MEASURED restarted behind a cut: back {back - healed:.2f} s after the heal, pilot restored "
          f"{restored - healed:.2f} s after it")
    for node in NODES:
        assert len(manager.lines(f"restoring {node} to")) == 1, manager.lines("restor")  # once, not again later
        assert len(manager.lines(f"restore {node} to", "succeeded")) == 1, manager.lines("restor")
        assert manager.lines(f"node {node} appeared: unconfigured (back after")
    assert hosts.sm_bt("state", "get", "amcl")[1] == "amcl: active\n"


@pytest.mark.long
def test_partition_and_heal_cycles_keep_the_invariants(two_hosts: Hosts) -> None:
    # One cycle here (make stress runs thirty, tests/e2e/stress_partitions.py), with a seed of its own each run.
    seed = random.SystemRandom().randrange(1 << 30)
    record = partitions.run(two_hosts, 1, seed)
    print(f"MEASURED partition cycles (seed {seed}): settled {', '.join(f'{t:.2f}' for t in record.settle_times)} "
          "s after each heal")
