"""Failures the manager's property tests found, kept as plain scenarios (issue 10).

Each test replays one minimal scenario (shrunk from what hypothesis found) through the same runner
and invariants as ``test_manager_properties.py`` (see ``scenario.py`` for I1-I10). The section
says which engine it was found on:

* **found on main 2ad460c**, the engine before the issue-10 rewrite: each of these fails there
  and passes on the rewrite;
* **found on the rewrite** (6615c26 .. ca95643), each fixed by the commit named in its section.
"""

from __future__ import annotations

import time

from scenario import (
    Cancel,
    ChangeMode,
    ChangeState,
    ChangeTo,
    Crash,
    FailNext,
    HangNext,
    ManagerOptions,
    RejectParameters,
    Restart,
    Scenario,
    Scheduled,
    SimOptions,
    TreeItem,
    Trigger,
    check,
)

# -- found on main 2ad460c ---------------------------------------------------------------------------


def test_configure_then_a_mode_at_the_same_instant() -> None:
    """Issue item 1, its own example: the mode request planned from the reported (unconfigured)
    state while the configure calls were in flight: "cannot configure while configuring" (I3, I4)."""
    check(Scenario(
        model="pilot",
        steps=(Scheduled(0.0, ChangeState(part="pilot", transition="configure")),),
        final=ChangeMode(part="pilot", mode="f_normal_mode"),
        final_delay=0.0,
    ))


def test_a_node_then_its_system_at_the_same_instant() -> None:
    """Item 1 across levels: a node request, then a system mode that drives the same node (I3, I4)."""
    check(Scenario(
        model="pilot",
        steps=(Scheduled(0.0, ChangeTo(part="amcl", target="active")),),
        final=ChangeMode(part="pilot", mode="f_performance_mode"),
        final_delay=0.0,
    ))


def test_a_system_then_one_of_its_nodes_at_the_same_instant() -> None:
    """Item 1 the other way round, with rules on (I3, I4)."""
    check(Scenario(
        model="pilot_rules",
        steps=(Scheduled(0.0, ChangeState(part="pilot", transition="configure")),),
        final=ChangeMode(part="laser_resender", mode="__DEFAULT__"),
        final_delay=0.0,
    ))


def test_recovery_gives_up_on_a_hung_node() -> None:
    """Item 3: amcl's configure never returns; each attempt timed out and aged out of the window,
    so recovery retried forever (I6: 4th, 5th, 6th restore; still in flight at the end)."""
    check(Scenario(
        model="nav2_like",
        manager=ManagerOptions(grace_period=0.0, recovery_window=30.0),
        steps=(
            Scheduled(0.0, HangNext(node="amcl", transition="configure")),
            Scheduled(0.0, ChangeTo(part="amcl", target="active")),
            Scheduled(185.0, RejectParameters(node="amcl", reason=None)),
        ),
        final=ChangeMode(part="planning", mode="__DEFAULT__"),
        expect_given_up="amcl",
    ))


def test_a_hung_node_given_up_is_reported_as_an_error() -> None:
    """Item 3: with short timeouts the restores went on, and the divergence stayed "grace", never
    an error that OnDivergence reports (I6)."""
    check(Scenario(
        model="nested",
        manager=ManagerOptions(grace_period=0.5, request_timeout=3.0, recovery_window=5.0),
        steps=(
            Scheduled(0.0, HangNext(node="arm", transition="configure")),
            Scheduled(0.0, ChangeTo(part="arm", target="active")),
            Scheduled(27.5, RejectParameters(node="arm", reason=None)),
        ),
        final=ChangeTo(part="drive", target="active.SLOW"),
        expect_given_up="arm",
    ))


def test_rules_cascade_from_localization_to_navigation() -> None:
    """Item 2 on the Nav2-like model: map_server fails, localization's rule degrades it, and
    navigation's rule (which reads localization's mode) must follow; it stayed an override (I8)."""
    check(Scenario(
        model="nav2_like",
        manager=ManagerOptions(grace_period=0.5),
        steps=(
            Scheduled(0.0, ChangeMode(part="navigation", mode="f_normal_mode")),
            Scheduled(5.0, Trigger(node="map_server", outcome="error")),
        ),
        final=ChangeMode(part="planning", mode="NORMAL"),
    ))


def test_rules_cascade_in_a_generated_model() -> None:
    """Item 2, as the generator found it: n1 fails, s1's rule sends s1 to S2, and s0's rule for
    s1 in S2 never fired (I8)."""
    check(Scenario(
        model="generated",
        model_text=CASCADE_MODEL,
        steps=(
            Scheduled(0.0, ChangeMode(part="s0", mode="S3")),
            Scheduled(0.0, Trigger(node="n1", outcome="error")),
        ),
        final=ChangeTo(part="n1", target="active.__DEFAULT__"),
    ))


def test_hold_mode_ends_when_its_mode_is_lost_before_the_work_starts() -> None:
    """Item 4: the user re-targets the held system before hold_mode's work starts; its inner
    WaitForMode had no bound, so the subtree stayed RUNNING forever (I7)."""
    check(Scenario(
        model="actuation",
        sim=SimOptions(transition_delay=0.0),
        steps=(Scheduled(0.018, ChangeMode(part="actuation", mode="__DEFAULT__")),),
        tree=((TreeItem(kind="hold_mode", part="actuation", arg="MODERATE", timeout=9.8, ticks=3),),),
        final=ChangeMode(part="manipulator", mode="__DEFAULT__"),
    ))


# -- found on 53d623c, fixed in ca95643 -----------------------------------------------------------------


def test_a_node_cleaned_up_by_itself_after_a_preempted_configure_can_be_driven_again() -> None:
    """pilot __DEFAULT__ sends configure to pointcloud_to_laser; a laser_resender request preempts
    it (its scope does not hold that node) while the call is in flight; later the node cleans up by
    itself. From then on its driver waits "for its state report (still unconfigured)" forever:
    every request on it times out (I3; recovery's too)."""
    check(Scenario(
        model="pilot",
        steps=(
            Scheduled(0.0, ChangeMode(part="pilot", mode="__DEFAULT__")),
            Scheduled(0.0, ChangeMode(part="laser_resender", mode="__DEFAULT__")),
            Scheduled(1.0, Trigger(node="pointcloud_to_laser")),
        ),
        final=ChangeTo(part="pointcloud_to_laser", target="active"),
    ))


def test_a_rule_does_not_undo_what_the_user_asked_for() -> None:
    """n2 failed by itself (recovery off), so s1 diverges with a fault. The user then asks for n0
    in M1, which makes s1's rule r1 (n0 is active.M1) true: the rule fires and takes n0 back to
    inactive, against docs/manager.md's "never against what a user asked for" (I3)."""
    check(Scenario(
        model="generated",
        model_text=USER_CHANGE_MODEL,
        manager=ManagerOptions(grace_period=0.0, recovery=False),
        steps=(
            Scheduled(0.0, ChangeMode(part="s1", mode="__DEFAULT__")),
            Scheduled(1.0, Trigger(node="n2", outcome="error")),
        ),
        final=ChangeTo(part="n0", target="active.M1"),
    ))


# -- found on ca95643, fixed in a9cd1c3 -----------------------------------------------------------------


def test_a_parent_diverging_after_a_cascade_does_not_stay_in_grace() -> None:
    """Issue item 2, on the rewrite: n0 fails and comes back inactive, s1's rule sends s1 to S1,
    and s0 (target __DEFAULT__) then diverges with cause "grace" for good: no timer ends its grace
    period, so its rule for s1 in S1 never fires (200 s later it is still "grace"), unless some
    unrelated event makes the manager look again (I8)."""
    check(Scenario(
        model="generated",
        model_text=GRACE_MODEL,
        manager=ManagerOptions(grace_period=0.5, request_timeout=2.0, recovery_attempts=1, recovery=False),
        steps=(
            Scheduled(0.0, ChangeMode(part="s0", mode="__DEFAULT__")),
            Scheduled(0.5, Trigger(node="n0", outcome="error")),
            Scheduled(0.61, Trigger(node="n0")),
            Scheduled(0.61, Trigger(node="n2")),
        ),
        final=ChangeMode(part="s0", mode="__DEFAULT__"),
    ))


# -- found by make stress on 4b1e1d4 (answers before reports), fixed after it ------------------------------


def test_reports_of_a_transition_the_node_made_by_itself_do_not_mislead_the_driver() -> None:
    """lidar configures by itself (and fails) at the instant a request configures it; with the
    reports 30 ms behind the answers, the self-made transition's late "configuring" report ended
    the driver's wait for its own configure, and the stale "unconfigured" after it made the driver
    send configure again to an inactive node: refused (I3). (Shrunk by hand from a stress find.)"""
    check(Scenario(
        model="nested",
        manager=ManagerOptions(grace_period=0.1, recovery=False),
        sim=SimOptions(transition_delay=0.0, report_delay=0.03),
        steps=(Scheduled(1.0, Trigger(node="lidar", outcome="failure")),),
        final=ChangeTo(part="lidar", target="inactive"),
        final_delay=0.0,
    ))


def test_a_node_restarted_at_the_instant_of_a_request_may_be_refused_for_it() -> None:
    """The heal restarts controller_server at the instant of the final request, and its report is
    30 ms behind: the manager, which knows it only as vanished, refuses the request and names it.
    That is the honest answer (I3 now judges reachability as the manager can know it)."""
    check(Scenario(
        model="pilot_rules",
        manager=ManagerOptions(grace_period=0.0, request_timeout=13.0, recovery_window=30.0, rules=False),
        sim=SimOptions(vanish_after=3.0, report_delay=0.03),
        steps=(
            Scheduled(1.0, Crash(node="controller_server")),
            Scheduled(5.0, RejectParameters(node="laser_resender", reason=None)),  # known vanished by now
        ),
        final=ChangeMode(part="pilot", mode="f_normal_mode"),
        final_delay=0.0,
    ))


def test_a_transition_refused_because_the_node_moved_by_itself_is_planned_again() -> None:
    """lidar starts a transition by itself while the final request is made, and its reports are
    30 ms late: the cleanup planned from the stale "inactive" is refused ("cannot cleanup while
    shuttingdown"). A refusal means the report was out of date: the driver plans again from the
    next report instead of failing (I3). (Found by make stress.)"""
    check(Scenario(
        model="nested",
        manager=ManagerOptions(grace_period=0.5, request_timeout=20.0, recovery_attempts=1),
        sim=SimOptions(transition_delay=0.2, error_delay=0.0, parameter_delay=0.0,
                       initial_state=(("lidar", "inactive"),), report_delay=0.03),
        steps=(Scheduled(1.0, Trigger(node="lidar", choice=2, on_error="failure")),),
        final=ChangeTo(part="lidar", target="unconfigured"),
        final_delay=0.01,
    ))


def test_a_transition_refused_after_a_restart_not_yet_reported_is_planned_again() -> None:
    """drive restarts (unconfigured) at the instant of the final request, its report 5 ms late:
    the deactivate planned from the stale "active" is refused; the driver plans again from the
    restarted node's report (I3). (Found by make stress.)"""
    check(Scenario(
        model="nested",
        manager=ManagerOptions(grace_period=0.5, request_timeout=13.0, recovery_window=5.0, recovery=False),
        sim=SimOptions(transition_delay=0.01, error_delay=0.0, report_delay=0.005),
        steps=(
            Scheduled(0.0, ChangeMode(part="robot", mode="__DEFAULT__")),
            Scheduled(20.67, Restart(node="drive")),
        ),
        final=ChangeTo(part="base", target="unconfigured"),
        final_delay=0.0,
    ))


def test_the_nodes_a_preempting_request_does_not_drive_are_carried_on() -> None:
    """actuation -> MODERATE is preempted by a request for the manipulator alone while drive_base
    still comes up: drive_base was left short of MODERATE's target, which counted as a fault, and
    a rule of actuation took everything (the manipulator the user had just asked for included)
    down. The manager now carries on with drive_base (I3). (Found by the property tests.)"""
    check(Scenario(
        model="actuation",
        manager=ManagerOptions(grace_period=0.0, request_timeout=16.0, recovery_attempts=1, recovery=False),
        sim=SimOptions(transition_delay=1.0, slow=(("drive_base", 3.4), ("manipulator", 3.6))),
        steps=(Scheduled(1.0, ChangeTo(part="actuation", target="active.MODERATE")),),
        final=ChangeTo(part="manipulator", target="active.STRONG"),
        final_delay=0.01,
    ))


def test_a_node_whose_move_by_itself_is_reported_late_is_taken_back_to_its_goal() -> None:
    """laser_resender starts deactivating by itself at the instant a mode change begins; the
    manager still sees it active (reports 30 ms late), takes its step as reached, and then the
    report comes: the step failed the request. It now takes the node back to its goal (I3)."""
    check(Scenario(
        model="pilot",
        manager=ManagerOptions(grace_period=0.5, recovery=False),
        sim=SimOptions(report_delay=0.03, slow=(("laser_resender", 1.1),)),
        steps=(
            Scheduled(0.0, ChangeMode(part="pilot", mode="f_normal_mode")),
            Scheduled(10.0, Trigger(node="laser_resender")),
        ),
        final=ChangeMode(part="pilot", mode="f_performance_mode"),
        final_delay=0.01,
    ))


def test_a_refusal_answered_after_the_nodes_appearance_is_not_waited_on() -> None:
    """amcl restarts active, its appearance 5 ms late; a configure planned from its old state is
    refused, and the answer comes after the appearance: the driver waited for a further state
    report that never came (I3). (Found by the property tests.)"""
    check(Scenario(
        model="pilot",
        manager=ManagerOptions(grace_period=0.5, request_timeout=9.0, recovery=False),
        sim=SimOptions(transition_delay=0.0, parameter_delay=0.0, report_delay=0.005),
        steps=(
            Scheduled(0.0, Restart(node="amcl", state="active")),
            Scheduled(0.0, ChangeState(part="pilot", transition="configure")),
        ),
        final=ChangeMode(part="pilot", mode="f_slow_mode"),
        final_delay=0.01,
    ))


def test_a_finalized_node_restarted_at_the_instant_of_a_request_may_be_refused_for_it() -> None:
    """n1 is finalized; the heal restarts it at the instant of the final request, its report 30 ms
    late: the plan from "finalized" failed at once. The request is now refused up front, naming
    the node, as for a vanished one (I3 judges as the manager can know). (Found by make stress.)"""
    check(Scenario(
        model="actuation",
        manager=ManagerOptions(grace_period=0.5, recovery=False),
        sim=SimOptions(initial_state=(("manipulator", "finalized"),), report_delay=0.03),
        steps=(Scheduled(1.0, Crash(node="manipulator")),),
        final=ChangeMode(part="manipulator", mode="__DEFAULT__"),
        final_delay=0.0,
    ))


def test_a_budget_renewed_by_a_restart_counts_from_when_the_manager_learns_of_it() -> None:
    """laser_resender restarts twice at one instant, its appearances 5 ms late: each appearance
    renews its budget in the manager, so two restores are right; the invariant counted the
    renewal from the restart itself, before the manager could know (I6, a test-side fix)."""
    check(Scenario(
        model="pilot_rules",
        manager=ManagerOptions(grace_period=0.0, request_timeout=7.0, recovery_attempts=1, rules=False),
        sim=SimOptions(error_delay=0.0, parameter_delay=0.05, vanish_after=3.0,
                       initial_state=(("laser_resender", "inactive"), ("amcl", "unconfigured")),
                       late=(("controller_server", 1.9),), report_delay=0.005),
        steps=(
            Scheduled(0.05, Restart(node="laser_resender", state="active")),
            Scheduled(0.05, ChangeMode(part="pilot", mode="f_performance_mode")),
            Scheduled(0.05, Restart(node="laser_resender")),
        ),
        final=ChangeMode(part="controller_server", mode="FAST"),
        final_delay=0.1,
    ))


def test_a_hung_node_restarted_by_the_healing_renews_its_budget_before_the_manager_reacts() -> None:
    """amcl hangs in activating and recovery gives up on it; the healing restarts it, and the
    manager restores it from the appearance report (5 ms later) with a renewed budget. The
    invariant renewed the budget only after that report had been handled, and counted two restores
    (I6, a test-side fix, found by CI: the oracle now renews as the report reaches the manager)."""
    check(Scenario(
        model="pilot_rules",
        manager=ManagerOptions(grace_period=0.5, request_timeout=4.0, recovery_attempts=1),
        sim=SimOptions(transition_delay=0.0, error_delay=0.0, parameter_delay=0.0, vanish_after=3.0,
                       initial_state=(("amcl", "inactive"),), late=(("laser_resender", 5.2), ("amcl", 6.1)),
                       slow=(("controller_server", 3.7),), report_delay=0.005),
        steps=(
            Scheduled(30.0, ChangeMode(part="pilot", mode="__DEFAULT__")),
            Scheduled(67.0, Restart(node="controller_server", state="active")),
            Scheduled(67.0, RejectParameters(node="controller_server", reason=None)),
            Scheduled(67.025, ChangeState(part="laser_resender", transition="bogus")),
            Scheduled(67.025, ChangeState(part="pilot", transition="activate")),
            Scheduled(77.025, ChangeTo(part="amcl", target="active.__DEFAULT__", timeout=2.9)),
            Scheduled(77.025, HangNext(node="amcl", transition="activate")),
            Scheduled(77.025, ChangeTo(part="controller_server", target="active")),
            Scheduled(88.025, Trigger(node="amcl", outcome="failure", on_error="failure")),
        ),
        final=ChangeTo(part="controller_server", target="active.DEGRADED"),
        final_delay=0.1,
    ))


CASCADE_MODEL = """\
s0:
  ros__parameters:
    type: system
    parts:
      s1
    modes:
      __DEFAULT__:
        s1: active.S3
      S1:
        s1: active.__DEFAULT__
      S2:
        s1: active
      S3:
        s1: active.S3
    rules:
      r0:
        if_target: active.S1
        if_part: [n1, active.__DEFAULT__]
        new_target: active.S3
      cascade_parent:
        if_target: active.S3
        if_part: [s1, active.S2]
        new_target: active.S2

s1:
  ros__parameters:
    type: system
    parts:
      n0
      n1
    modes:
      __DEFAULT__:
        n0: inactive
        n1: active.__DEFAULT__
      S1:
        n1: unconfigured
      S2:
        n0: __DONTCARE__
      S3:
        __order__: ["n0"]
        n0: unconfigured
        n1: inactive
    rules:
      r0:
        if_target: active.S3
        if_part: [n0, active.__DEFAULT__]
        new_target: active.__DEFAULT__
      cascade_sub:
        if_target: active.S3
        if_part: [n1, unconfigured]
        new_target: active.S2

n0:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: 0.4

n1:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: "slow"
          p1: false
          p2: "laser"
"""

USER_CHANGE_MODEL = """\
s1:
  ros__parameters:
    type: system
    parts:
      n0
      n2
    modes:
      __DEFAULT__:
        n0: unconfigured
        n2: inactive
      S1:
        n0: inactive
        n2: active
    rules:
      r1:
        if_target: active.__DEFAULT__
        if_part: [n0, active.M1]
        new_target: active.S1

n0:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: 4
      M1:
        ros__parameters:
          p0: 80

n2:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: 0.8
"""

GRACE_MODEL = """\
s0:
  ros__parameters:
    type: system
    parts:
      s1
      s2
    modes:
      __DEFAULT__:
        __order__: ["s1"]
        s2: active
        s1: active.__DEFAULT__
      S1:
        __order__: ["s1"]
        s1: active
    rules:
      cascade_parent:
        if_target: active.__DEFAULT__
        if_part: [s1, active.S1]
        new_target: active.S1

s1:
  ros__parameters:
    type: system
    parts:
      n0
      n2
    modes:
      __DEFAULT__:
        __order__: ["n0"]
        n0: active
        n2: active
      S1:
        __order__: ["n0"]
        n0: active
    rules:
      cascade_sub:
        if_target: active.__DEFAULT__
        if_part: [n0, inactive]
        new_target: active.S1

s2:
  ros__parameters:
    type: system
    parts:
      n1
    modes:
      __DEFAULT__:
        n1: active
      S1:
        n1: active

n0:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: false

n1:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: false

n2:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: false
"""


# -- found by hypothesis for issue 27 (the stress profile), fixed with it ---------------------------------


def test_a_rule_does_not_undo_what_a_user_asked_of_a_part_below_its_system() -> None:
    """n0 is off its target (recovery off), so s0's divergence is a fault; the user then asks for s2
    (all don't-care below it) directly. s0's rule r1, which only re-asserts s0's own target, fired
    and re-targeted s2 to what s0 wants of it, undoing the user's request as soon as it succeeded
    (I3). A rule whose new target would re-target a part a user asked for directly no longer fires
    (an override is left alone). Unshrunk, as the stress profile found it."""
    check(Scenario(
        model='generated',
        model_text='''\
# generated by tests/support/model_generator.py
---

s0:
  ros__parameters:
    type: system
    parts:
      s1
      s2
    modes:
      __DEFAULT__:
        __order__: ["s1"]
        s2: inactive
        s1: active.__DEFAULT__
      S1:
        s1: active
    rules:
      r0:
        if_target: active.__DEFAULT__
        if_part: [s1, active.S1]
        new_target: active.__DEFAULT__
      r1:
        if_target: active.__DEFAULT__
        if_part: [s1, active.__DEFAULT__]
        new_target: active.__DEFAULT__
      cascade_parent:
        if_target: active.__DEFAULT__
        if_part: [s1, active.S1]
        new_target: active.S1

s1:
  ros__parameters:
    type: system
    parts:
      s3
    modes:
      __DEFAULT__:
        s3: inactive
      S1:
        s3: unconfigured
    rules:
      r0:
        if_target: active.__DEFAULT__
        if_part: [n0, active.__DEFAULT__]
        new_target: active.__DEFAULT__
      cascade_sub:
        if_target: active.__DEFAULT__
        if_part: [n0, inactive]
        new_target: active.S1

s2:
  ros__parameters:
    type: system
    parts:
      s4
    modes:
      __DEFAULT__:
        s4: __DONTCARE__
      S1:
        s4: active

s3:
  ros__parameters:
    type: system
    parts:
      n0
    modes:
      __DEFAULT__:
        n0: active
      S1:
        n0: inactive

s4:
  ros__parameters:
    type: system
    parts:
      n1
    modes:
      __DEFAULT__:
        n1: active.__DEFAULT__
      S1:
        n1: active.__DEFAULT__

n0:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: 0.5
          p1: 0.75
      M1:
        ros__parameters:
          p0: 1.75
          p1: 0.0

n1:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: false
''',
        manager=ManagerOptions(grace_period=0.0, request_timeout=2.0, recovery=False),
        sim=SimOptions(),
        steps=(
            Scheduled(0.0, ChangeMode(part='s0', mode='__DEFAULT__')),
            Scheduled(0.5, Trigger(node='n0', choice=1)),
        ),
        final=ChangeTo(part='s2', target='active'),
    ))


def test_a_node_restarted_from_finalized_at_the_instant_of_a_request_may_fail_it_naming_it() -> None:
    """The healing restarts pointcloud_to_laser (finalized) at the instant of the final request, and
    the reports are 30 ms behind: the manager hears of the old, finalized process first and fails the
    request naming it. That is what it could know; I3 accepts either outcome for such a node."""
    check(Scenario(
        model="pilot_rules",
        manager=ManagerOptions(grace_period=0.0, request_timeout=18.0, recovery_window=30.0, rules=False,
                               recovery=False),
        sim=SimOptions(transition_delay=0.0, parameter_delay=0.0,
                       initial_state=(("pointcloud_to_laser", "finalized"), ("amcl", "unconfigured"),
                                      ("controller_server", "unconfigured")),
                       late=(("laser_resender", 5.5),), plain=("laser_resender",), report_delay=0.03),
        steps=(Scheduled(0.02, RejectParameters(node="amcl", reason="rejected by the test")),),
        final=ChangeMode(part="pilot", mode="f_degraded_mode"),
        final_delay=0.0,
    ))


def test_a_request_confirmed_from_what_the_manager_knows_before_late_news_is_a_success() -> None:
    """amcl shuts itself down (and ends finalized) just before the final request; its reports are
    30 ms late, so the manager still knows it active.__DEFAULT__ and confirms the request at once.
    The harness had expected a failure (the node "cannot be had"); I3 accepts either outcome for a
    node the manager knows in another state than it is. (Shrunk by hand from a stress find.)"""
    check(Scenario(
        model="pilot",
        manager=ManagerOptions(rules=False, recovery=False),
        sim=SimOptions(transition_delay=0.01, report_delay=0.03, initial_state=(("amcl", "active"),)),
        steps=(Scheduled(1.0, Trigger(node="amcl", choice=1, outcome="failure")),),
        final=ChangeTo(part="amcl", target="active.__DEFAULT__"),
        final_delay=0.01,
    ))


def test_a_continuation_succeeds_only_once_the_nodes_it_carries_on_with_are_at_their_targets() -> None:
    """Issue 27, item 4: a continuation of a preempted request was reported succeeded as soon as its
    plan was done, while amcl (one of its nodes, crashed and back) was still configuring, off its
    target (I10). Its success now waits for its nodes' actuals (found by the stress profile on the
    old rule)."""
    check(Scenario(
        model="pilot",
        manager=ManagerOptions(grace_period=0.1, request_timeout=3.0, recovery_attempts=2, recovery_window=5.0,
                               rules=False, recovery=False),
        sim=SimOptions(error_delay=0.2, parameter_delay=0.0,
                       initial_state=(("amcl", "active"), ("controller_server", "active")),
                       late=(("amcl", 8.5), ("pointcloud_to_laser", 4.8))),
        steps=(
            Scheduled(0.02, Trigger(node="amcl", choice=1, outcome="failure")),
            Scheduled(0.03, Trigger(node="amcl", outcome="failure")),
            Scheduled(0.13, Restart(node="laser_resender", state="inactive")),
            Scheduled(35.13, Crash(node="laser_resender")),
            Scheduled(35.13, Crash(node="amcl")),
            Scheduled(35.14, ChangeMode(part="pilot", mode="f_performance_mode")),
            Scheduled(35.14, ChangeState(part="pilot", transition="activate")),
            Scheduled(35.14, ChangeMode(part="controller_server", mode="__DEFAULT__")),
            Scheduled(35.15, HangNext(node="amcl", transition="activate")),
            Scheduled(35.15, ChangeMode(part="laser_resender", mode="__DEFAULT__")),
        ),
        final=ChangeMode(part="laser_resender", mode="__DEFAULT__"),
        final_delay=0.01,
    ))


def test_a_held_mode_whose_previous_target_was_finalized_is_not_put_back() -> None:
    """Found by make test on a fresh clone once the manager raised for a target that is not one to
    ask for: HoldMode on pilot, whose target was finalized (shut down at the start), asked for
    finalized back when it ended, and the RequestError broke the tree's tick. It leaves the part
    as it is instead. (Unshrunk, as hypothesis found it.)"""
    check(Scenario(
        model="pilot_rules",
        manager=ManagerOptions(grace_period=0.5, request_timeout=20.0, recovery_attempts=1, recovery_window=10.0),
        sim=SimOptions(transition_delay=0.05, error_delay=1.0, parameter_delay=0.0, vanish_after=3.0,
                       late=(("pointcloud_to_laser", 6.6), ("controller_server", 3.9)), plain=("laser_resender",),
                       slow=(("pointcloud_to_laser", 0.7), ("controller_server", 4.5))),
        steps=(
            Scheduled(0.0, ChangeState(part="pilot", transition="shutdown")),
            Scheduled(0.0, ChangeMode(part="laser_resender", mode="TYPO")),
            Scheduled(16.0, ChangeMode(part="amcl", mode="TYPO", timeout=13.0)),
            Scheduled(51.0, ChangeMode(part="pointcloud_to_laser", mode="__DEFAULT__")),
        ),
        tree=(
            (TreeItem(kind="wait_for_mode", part="controller_server", arg="__DEFAULT__", timeout=0.5, ticks=0),
             TreeItem(kind="change_mode", part="controller_server", arg="SLOW", timeout=0.5, ticks=0),
             TreeItem(kind="change_mode", part="controller_server", arg="__DEFAULT__", timeout=0.5, ticks=0)),
            (TreeItem(kind="change_mode", part="controller_server", arg="DEGRADED", timeout=0.5, ticks=0),),
            (TreeItem(kind="hold_mode", part="pilot", arg="f_energy_saving_mode", timeout=0.5, ticks=0),),
        ),
        final=ChangeMode(part="laser_resender", mode="__DEFAULT__"),
        final_delay=1.0,
    ))


# -- found by make test on 2026-11-27 (the session's start, 1b05178) ----------------------------------


def test_a_final_request_made_before_the_news_of_a_restart_may_fail_naming_the_node() -> None:
    """The healing restarted a crashed node just as its old process was found gone; the final
    request was made before either report came (report_delay), and the old process's end failed it,
    naming the node. The manager could not know its calls had reached the new process: the
    invariant I3 counted the node as reachable and flagged the failure."""
    check(Scenario(
        model="nav2_like",
        manager=ManagerOptions(grace_period=1.0, request_timeout=13.0, recovery_window=10.0, recovery=False),
        sim=SimOptions(transition_delay=0.0, error_delay=0.0, vanish_after=0.5,
                       slow=(("bt_navigator", 2.6), ("controller_server", 1.5)), report_delay=0.03),
        steps=(
            Scheduled(0.0, Trigger(node="controller_server", choice=1, outcome="failure")),
            Scheduled(0.0, Crash(node="planner_server")),
            Scheduled(0.05, ChangeTo(part="navigation", target="active.f_normal_mode")),
            Scheduled(0.05, ChangeMode(part="navigation", mode="f_performance_mode")),
            Scheduled(0.05, ChangeMode(part="planner_server", mode="ASTAR")),
        ),
        tree=((TreeItem(kind="wait_for_mode", part="navigation", arg="f_normal_mode", timeout=0.5),),),
        final=ChangeMode(part="navigation", mode="f_energy_saving_mode"),
        final_delay=0.01,
    ))


# -- found by make stress on 2026-11-27 (c083f7f), also at 0687ff3 ---------------------------------------

GENERATED_ONE_NODE = """\
s0:
  ros__parameters:
    type: system
    parts:
      n0
    modes:
      __DEFAULT__:
        n0: inactive
      S1:
        n0: active.__DEFAULT__
      S2:
        n0: unconfigured
      S3:
        n0: active.M1
    rules:
      r0:
        if_target: active.__DEFAULT__
        if_part: [n0, inactive]
        new_target: active.S3

n0:
  ros__parameters:
    type: node
    modes:
      __DEFAULT__:
        ros__parameters:
          p0: 15
      M1:
        ros__parameters:
          p0: 72
"""


def test_two_restarts_at_one_instant_renew_the_budget_twice() -> None:
    """A node restarted twice at the same instant appears twice; each new process makes its
    recovery budget whole (docs/manager.md, "Giving up"), so recovery restores it once after each.
    The invariant I6 renewed the budget once per restarted node, not once per restart, and flagged
    the second restore."""
    check(Scenario(
        model="generated",
        model_text=GENERATED_ONE_NODE,
        manager=ManagerOptions(grace_period=0.0, request_timeout=9.0, recovery_attempts=1, recovery_window=10.0,
                               rules=False, recovery=True),
        sim=SimOptions(transition_delay=0.05, error_delay=0.0, parameter_delay=0.05, vanish_after=1.0,
                       late=(("n0", 8.6),), report_delay=0.03),
        steps=(
            Scheduled(0.0, ChangeState(part="ghost", transition="configure")),
            Scheduled(0.0, FailNext(node="n0", transition="cleanup", outcome="failure", on_error="failure")),
            Scheduled(1.87, ChangeTo(part="s0", target="active.TYPO")),
            Scheduled(11.87, ChangeMode(part="s0", mode="__DEFAULT__")),
            Scheduled(13.38, HangNext(node="n0", transition="cleanup")),
            Scheduled(16.28, ChangeTo(part="ghost", target="active.TYPO")),
            Scheduled(16.28, Restart(node="n0", state="active")),
            Scheduled(16.28, HangNext(node="n0", transition="deactivate")),
            Scheduled(16.28, Restart(node="n0", state="active")),
            Scheduled(18.88, Cancel(request=5)),
            Scheduled(18.88, Trigger(node="n0", choice=0, outcome="success", on_error="success")),
            Scheduled(18.905, ChangeTo(part="s0", target="finalized")),
        ),
        final=ChangeMode(part="s0", mode="__DEFAULT__"),
        final_delay=0.1,
    ))


def test_a_done_callback_added_while_another_thread_ends_the_request_is_called_once() -> None:
    """An application adds a callback while the manager's executor finishes the request: it was
    checked as not done, then appended to the list the end had already taken (never called)."""
    import threading

    from sm_bt.engine.requests import Origin, Request
    from sm_bt.model.states import State, StateMode

    request = Request("robot", StateMode(State.ACTIVE, "FAST"), "change_mode robot FAST", Origin.USER, 0.0)
    in_append, calls = threading.Event(), []

    class SlowList(list):  # type: ignore[type-arg]
        def append(self, item: object) -> None:
            in_append.set()
            time.sleep(0.05)  # the other thread ends the request meanwhile, if it can
            super().append(item)

    request._callbacks = SlowList()
    ender = threading.Thread(target=lambda: (in_append.wait(5), request._finish(True, "", 1.0)))
    ender.start()
    request.add_done_callback(calls.append)
    ender.join(5)
    assert request.done and calls == [request]
