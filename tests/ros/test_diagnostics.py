"""What each part's /diagnostics status says, from the manager's state (simulated backend: the
levels and words; test_ros_liveness checks them on the wire)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_files import bundled

from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.requests import Request
from sm_bt.ros.diagnostics import ERROR, OK, STALE, WARN, Paging, PartDiagnostic, part_diagnostic
from sm_bt.sim import SimulatedSystem


@dataclass(frozen=True)
class SlowLink:
    rtt: float | None = 0.45
    window: float = 2.6
    slow: bool = True


def status(rig: SimulatedSystem, part: str, last: Request | None = None, link: object = None) -> PartDiagnostic:
    with rig.manager.lock:
        return part_diagnostic(rig.manager, part, last, link)


def test_a_part_at_its_target_is_ok_with_its_values() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    request = rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    pilot = status(rig, "pilot", request)
    assert (pilot.level, pilot.message) == (OK, "active.f_normal_mode")
    assert pilot.value("target") == "active.f_normal_mode"
    assert pilot.value("last_request") == f"#{request.id} change_mode pilot f_normal_mode"
    assert (pilot.value("last_request_outcome"), pilot.value("last_request_by")) == ("succeeded", "user")
    assert "reachable" not in dict(pilot.values), "a system has no link of its own"
    assert status(rig, "amcl").value("reachable") == "true"


def test_a_request_in_flight_warns_with_its_progress() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    request = rig.manager.change_mode("pilot", "f_normal_mode")
    pilot = status(rig, "pilot", request)
    assert pilot.level == WARN and pilot.value("last_request_outcome") == "running"
    assert pilot.message.startswith(f"request #{request.id} change_mode pilot f_normal_mode: ")


def test_a_failed_request_is_an_error_until_the_part_is_at_its_target() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.finish(rig.manager.change_state("pilot", "configure"))
    rig.backend.fail_next("amcl", Transition.ACTIVATE)
    request = rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    pilot = status(rig, "pilot", request)
    assert pilot.level == ERROR and pilot.value("last_request_outcome") == "failed"
    assert "amcl" in pilot.value("last_request_reason")


def test_a_refused_request_warns_and_says_why() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    refused = rig.manager.change_state("pilot", "activate")  # unconfigured: not valid yet
    pilot = status(rig, "pilot", refused)
    assert pilot.level == WARN and pilot.value("last_request_outcome") == "refused"
    assert "transition activate is not valid in state unconfigured" in pilot.message


def test_an_unreachable_node_is_an_error_with_the_reason_and_an_unseen_one_is_stale() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, vanish_after=0.5,
                          late={"laser_resender": 100.0})
    rig.run(0.1)
    assert status(rig, "laser_resender").level == STALE
    rig.backend.crash("amcl")
    rig.run(1.0)
    amcl = status(rig, "amcl")
    assert amcl.level == ERROR and amcl.message.startswith("unreachable: no answer for 0.5 s")
    assert amcl.value("reachable") == "false"


def test_a_slow_link_warns_and_shows_its_round_trip() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.run(0.1)
    amcl = status(rig, "amcl", link=SlowLink())
    assert amcl.level == WARN and "slow link: answers in 450 ms" in amcl.message
    assert (amcl.value("round_trip_ms"), amcl.value("liveness_window_s")) == ("450.0", "2.60")
    assert status(rig, "amcl", link=SlowLink(rtt=0.002, window=0.8, slow=False)).level == OK


def test_a_fault_beyond_the_grace_period_is_an_error() -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False, grace_period=0.5)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    rig.backend.trigger("amcl", Transition.DEACTIVATE)
    rig.run(0.2)
    assert status(rig, "amcl").level == WARN, "within the grace period"
    rig.run(1.0)
    amcl = status(rig, "amcl")
    assert amcl.level == ERROR and amcl.message.startswith("target active"), amcl.message
    assert amcl.value("divergence").startswith("fault")


def test_a_node_back_from_out_of_reach_says_how_it_came_back(caplog: pytest.LogCaptureFixture) -> None:
    rig = SimulatedSystem(bundled("pilot"), rules=False, recovery=False)
    rig.finish(rig.manager.change_mode("pilot", "f_normal_mode"))
    assert status(rig, "amcl").value("last_return") == ""
    rig.backend.crash("amcl")
    rig.run_until(lambda: not rig.manager.observation("amcl").reachable)
    rig.run(3.0)
    with caplog.at_level(logging.INFO, logger="sm_bt.manager"):
        rig.backend.restart("amcl")
        rig.run(0.5)
    back = rig.manager.last_return("amcl")
    assert back is not None and back.changed and round(back.away, 1) == 3.0
    said = "unconfigured (back after 3.0 s; was active.__DEFAULT__)"
    assert status(rig, "amcl").value("last_return") == said
    assert f"node amcl appeared: {said}" in caplog.messages, caplog.messages
    # Back as it was: said so too.
    rig.finish(rig.manager.change_state("amcl", "configure"))
    rig.backend.crash("amcl")
    rig.run_until(lambda: not rig.manager.observation("amcl").reachable)
    rig.backend.restart("amcl", "inactive")
    rig.run(0.5)
    back = rig.manager.last_return("amcl")
    assert back is not None and not back.changed and back.describe().startswith("inactive (back after ")


# -- a model larger than a message ---------------------------------------------------------------


def flat(count: int) -> tuple[list[str], dict[str, tuple[str, ...]]]:
    nodes = [f"n{i:03d}" for i in range(count)]
    return ["robot", *nodes], {"robot": tuple(nodes)}


def test_a_model_within_the_limit_is_published_whole_every_period() -> None:
    parts, children = flat(9)
    paging = Paging(parts, children, limit=10)
    assert not paging.paged and paging.cycle == 1
    assert paging.periodic(["n003"]) == paging.periodic([]) == parts
    assert paging.burst({"n004", "robot"}, set()) == (["robot", "n004"], set())


def test_pages_carry_the_top_the_divergences_and_every_other_part_in_turn() -> None:
    parts, children = flat(100)
    paging = Paging(parts, children, limit=10)  # the top 2, up to 5 divergences, at least 3 more in turn
    assert paging.paged and paging.cycle == 33
    seen: set[str] = set()
    for period in range(paging.cycle):
        diverging = [f"n{i:03d}" for i in range(90, 100)] if period % 2 else ["n050"]
        message = paging.periodic(diverging)
        assert len(message) == 10 and message[:2] == ["robot", "n000"]
        assert set(diverging[:5]) <= set(message)  # the divergences from the top down, up to half of it
        seen.update(message)
    assert seen == set(parts)


def test_a_burst_larger_than_a_message_goes_out_over_several_urgent_ones_first() -> None:
    parts, children = flat(100)
    paging = Paging(parts, children, limit=10)
    changed = set(parts)
    now, left = paging.burst(changed, {"n099"})
    assert now == ["robot", "n000", "n001", "n002", "n003", "n004", "n005", "n006", "n007", "n099"]
    assert left == changed - set(now)
    sent = set(now)
    while left:
        now, left = paging.burst(left, set())
        assert len(now) <= 10 and not sent & set(now)
        sent.update(now)
    assert sent == set(parts)
    with pytest.raises(ValueError, match="at least two"):
        Paging(parts, children, limit=1)


@given(st.integers(2, 60), st.integers(2, 40), st.data())
@examples(200)
def test_every_part_is_published_within_the_cycle_whatever_diverges(count: int, limit: int,
                                                                      data: st.DataObject) -> None:
    """Whatever diverges each period, a message holds at most ``limit`` statuses, the top quarter
    and as many divergences as half of it allows (from the top down), and every part is in one of
    the messages of any ``cycle`` periods in a row."""
    parts, children = flat(count)
    paging = Paging(parts, children, limit=limit)
    seen: set[str] = set()
    for _ in range(paging.cycle):
        diverging = data.draw(st.sets(st.sampled_from(parts)))
        message = paging.periodic(diverging)
        assert len(message) <= limit and len(set(message)) == len(message)
        if paging.paged:
            top = parts[:limit // 4]
            wanted = sorted(set(diverging) - set(top), key=parts.index)[:limit // 2]
            assert set(top) | set(wanted) <= set(message)
        seen.update(message)
    assert seen == set(parts)
