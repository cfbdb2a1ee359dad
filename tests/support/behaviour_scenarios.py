"""Behaviour scenarios on the MROS pilot that run unchanged on every backend (see ``harness.py``).

Each scenario builds a real py_trees tree, sets it up with the harness's manager, ticks it while
time passes, and checks statuses, feedback and what the manager reports about the nodes. Only
what holds on real nodes is asserted: outcomes and end states, not tick counts or timings.
"""

from __future__ import annotations

from collections.abc import Callable

import py_trees
from harness import Harness, settle
from py_trees.common import Status

from sm_bt.behaviours import (
    ChangeMode,
    ChangeState,
    ModeIs,
    OnDivergence,
    StateIs,
    WaitForMode,
    hold_mode,
    switch_on_divergence,
)
from sm_bt.engine.events import Divergence
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State, StateMode

PILOT = "pilot"
NORMAL = "f_normal_mode"
DEGRADED = "f_degraded_mode"
ENERGY_SAVING = "f_energy_saving_mode"


def run_to_end(harness: Harness, root: py_trees.behaviour.Behaviour, limit: float = 10.0) -> Status:
    tree = harness.tree(root)
    harness.tick_until(tree, lambda: root.status is not Status.RUNNING, timeout=limit)
    return root.status


def sequence(name: str, *children: py_trees.behaviour.Behaviour) -> py_trees.composites.Sequence:
    return py_trees.composites.Sequence(name, memory=True, children=list(children))


def go_normal(harness: Harness) -> None:
    settle(harness, harness.manager.change_mode(PILOT, NORMAL))


# -- scenarios -------------------------------------------------------------------------------------


def change_mode_of_a_system(harness: Harness) -> None:
    change = ChangeMode("Normal", PILOT, NORMAL)
    root = sequence("Go normal", change, ModeIs("Normal?", PILOT, NORMAL))
    assert run_to_end(harness, root) is Status.SUCCESS, change.feedback_message
    assert change.feedback_message.startswith(f"pilot is active.{NORMAL} (")
    manager = harness.manager
    assert str(manager.actual("laser_resender")) == "active.__DEFAULT__"
    assert manager.actual("pointcloud_to_laser").state is State.INACTIVE
    assert manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.3
    assert manager.requests() == []


def change_state_of_a_system_step_by_step(harness: Harness) -> None:
    root = sequence("Bring up",
                    ChangeState("Configure", PILOT, "configure"),
                    StateIs("Inactive?", PILOT, "inactive"),
                    ChangeState("Activate", PILOT, Transition.ACTIVATE),
                    StateIs("Active?", PILOT, State.ACTIVE))
    assert run_to_end(harness, root) is Status.SUCCESS, root.feedback_message
    assert {harness.manager.actual(n).state for n in ("amcl", "controller_server", "laser_resender")} == \
        {State.INACTIVE}, "the default mode keeps every part inactive"


def wait_for_mode_sees_another_request_through(harness: Harness) -> None:
    wait = WaitForMode("Degraded?", PILOT, DEGRADED, timeout=8.0)
    root = py_trees.composites.Parallel("Switch and wait", policy=py_trees.common.ParallelPolicy.SuccessOnAll(),
                                        children=[wait, ChangeMode("Degraded", PILOT, DEGRADED)])
    assert run_to_end(harness, root) is Status.SUCCESS, wait.feedback_message
    manager = harness.manager
    assert manager.actual("laser_resender").state is State.UNCONFIGURED
    assert str(manager.actual("pointcloud_to_laser")) == "active.__DEFAULT__"
    assert str(manager.actual("controller_server")) == "active.DEGRADED"


def wait_for_mode_times_out(harness: Harness) -> None:
    go_normal(harness)
    wait = WaitForMode("Energy saving?", PILOT, ENERGY_SAVING, timeout=0.5)
    started = harness.now()
    assert run_to_end(harness, wait) is Status.FAILURE
    assert harness.now() - started >= 0.5
    assert "timed out" in wait.feedback_message or "0.5" in wait.feedback_message, wait.feedback_message


def a_failing_transition_fails_the_change(harness: Harness) -> None:
    harness.fail_next("laser_resender", Transition.ACTIVATE)
    change = ChangeMode("Normal", PILOT, NORMAL)
    assert run_to_end(harness, change) is Status.FAILURE
    assert "laser_resender" in change.feedback_message and "activate" in change.feedback_message, \
        change.feedback_message
    assert harness.manager.actual("laser_resender").state is State.INACTIVE


def a_rejected_parameter_set_fails_the_change(harness: Harness) -> None:
    go_normal(harness)
    harness.reject_parameters("controller_server", "speed limits are locked")
    change = ChangeMode("Fast", "controller_server", "FAST")
    assert run_to_end(harness, change) is Status.FAILURE
    assert "speed limits are locked" in change.feedback_message, change.feedback_message
    assert harness.manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.3


def on_divergence_reports_a_node_that_failed_by_itself(harness: Harness) -> None:
    go_normal(harness)
    check = OnDivergence("Laser diverges?", "laser_resender")
    tree = harness.tree(check)
    tree.tick()
    assert check.status is Status.FAILURE, "no divergence yet"
    harness.fail("laser_resender")
    harness.tick_until(tree, lambda: check.status is Status.SUCCESS, timeout=5.0)
    divergence = py_trees.blackboard.Blackboard.get("divergence")
    assert isinstance(divergence, Divergence)
    assert divergence.part == "laser_resender"
    assert divergence.target == StateMode(State.ACTIVE, "__DEFAULT__")
    assert divergence.actual.state is State.UNCONFIGURED


def switch_on_divergence_changes_the_system_mode(harness: Harness) -> None:
    go_normal(harness)
    contingencies = py_trees.composites.Selector("Contingencies", memory=False, children=[
        switch_on_divergence("Laser lost", "laser_resender", PILOT, DEGRADED),
        py_trees.behaviours.Running("Carry on"),
    ])
    tree = harness.tree(contingencies)
    harness.fail("laser_resender")
    harness.tick_until(tree, lambda: str(harness.manager.actual(PILOT)) == f"active.{DEGRADED}", timeout=8.0)
    assert harness.manager.target(PILOT) == StateMode(State.ACTIVE, DEGRADED)


def hold_mode_restores_the_previous_mode(harness: Harness) -> None:
    go_normal(harness)
    seen: list[str] = []

    class LookAtController(py_trees.behaviour.Behaviour):
        def update(self) -> Status:
            seen.append(str(harness.manager.actual("controller_server")))
            return Status.SUCCESS

    held = hold_mode("Save energy", PILOT, ENERGY_SAVING, LookAtController("Look"))
    assert run_to_end(harness, held) is Status.SUCCESS
    assert seen == ["active.SLOW"], "the work ran while the mode was held"
    harness.run_until(lambda: str(harness.manager.actual(PILOT)) == f"active.{NORMAL}")
    assert harness.manager.target(PILOT) == StateMode(State.ACTIVE, NORMAL)
    assert str(harness.manager.actual("controller_server")) == "active.__DEFAULT__"


SCENARIOS: list[Callable[[Harness], None]] = [
    change_mode_of_a_system,
    change_state_of_a_system_step_by_step,
    wait_for_mode_sees_another_request_through,
    wait_for_mode_times_out,
    a_failing_transition_fails_the_change,
    a_rejected_parameter_set_fails_the_change,
    on_divergence_reports_a_node_that_failed_by_itself,
    switch_on_divergence_changes_the_system_mode,
    hold_mode_restores_the_previous_mode,
]
