"""ModeIs/StateIs, WaitForMode/WaitForState, and how every behaviour is set up with the manager."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import py_trees
import pytest
from harness import settle
from model_files import bundled
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.behaviours import (
    ChangeMode,
    ChangeState,
    HoldMode,
    ModeIs,
    ModesToBlackboard,
    NotSetUp,
    OnDivergence,
    Reconfigure,
    StateIs,
    WaitForMode,
    WaitForState,
)
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State
from sm_bt.reasoner import Reasoner
from sm_bt.sim import SimulatedSystem
from sm_bt.trees.pilot.designs import PILOT_DESIGNS, PILOT_OBJECTIVE

PILOT_PARTS = "pilot, amcl, controller_server, pointcloud_to_laser, laser_resender"


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.fixture
def rig() -> SimulatedSystem:
    return SimulatedSystem(bundled("pilot"), recovery=False)


def tick_once(behaviour: py_trees.behaviour.Behaviour, rig: SimulatedSystem) -> Status:
    tree = rig.tree(behaviour)
    tree.tick()
    return behaviour.status


# -- ModeIs / StateIs: one tick, never RUNNING --------------------------------------------------------


def test_mode_is_succeeds_when_the_part_is_in_the_mode(rig: SimulatedSystem) -> None:
    settle(rig, rig.manager.change_mode("pilot", "f_performance_mode"))
    check = ModeIs("Performance?", "pilot", "f_performance_mode")
    assert tick_once(check, rig) is Status.SUCCESS
    assert check.feedback_message == "pilot is active.f_performance_mode"


def test_mode_is_fails_with_what_the_part_is(rig: SimulatedSystem) -> None:
    settle(rig, rig.manager.change_mode("pilot", "f_normal_mode"))
    check = ModeIs("Performance?", "pilot", "f_performance_mode")
    assert tick_once(check, rig) is Status.FAILURE
    assert check.feedback_message == "pilot is active.f_normal_mode, not active.f_performance_mode"


def test_mode_is_does_not_wait_for_a_change_in_progress(rig: SimulatedSystem) -> None:
    request = rig.manager.change_mode("pilot", "f_normal_mode")
    check = ModeIs("Normal?", "pilot", "f_normal_mode")
    tree = rig.tree(check)
    tree.tick()
    assert check.status is Status.FAILURE
    assert check.feedback_message == ("pilot is activating (amcl is unconfigured, f_normal_mode wants "
                                      "active.__DEFAULT__), not active.f_normal_mode")
    rig.finish(request)
    tree.tick()
    assert check.status is Status.SUCCESS


def test_mode_is_accepts_the_default_mode_marker(rig: SimulatedSystem) -> None:
    settle(rig, rig.manager.change_state("amcl", "configure"))
    settle(rig, rig.manager.change_state("amcl", "activate"))
    check = ModeIs("Default?", "amcl", "__DEFAULT__")
    assert tick_once(check, rig) is Status.SUCCESS
    assert check.feedback_message == "amcl is active.__DEFAULT__"
    degraded = ModeIs("Degraded?", "amcl", "DEGRADED")
    assert tick_once(degraded, rig) is Status.FAILURE


def test_mode_is_explains_an_unknown_state(rig: SimulatedSystem) -> None:
    settle(rig, rig.manager.change_mode("controller_server", "FAST"))
    rig.backend.crash("controller_server")
    rig.run(1.5)
    check = ModeIs("Fast?", "controller_server", "FAST")
    assert tick_once(check, rig) is Status.FAILURE
    assert check.feedback_message == ("controller_server is unknown (no answer for 1.0 s (crashed?)), "
                                      "not active.FAST")


@pytest.mark.parametrize(("state", "expected"), [
    ("inactive", Status.SUCCESS), (State.INACTIVE, Status.SUCCESS), ("unconfigured", Status.FAILURE),
    (State.ACTIVE, Status.FAILURE),
])
def test_state_is(rig: SimulatedSystem, state: str | State, expected: Status) -> None:
    settle(rig, rig.manager.change_state("pilot", "configure"))
    check = StateIs("State?", "pilot", state)
    assert tick_once(check, rig) is expected
    label = state.label if isinstance(state, State) else state
    suffix = "" if expected is Status.SUCCESS else f", not {label}"
    assert check.feedback_message == f"pilot is inactive{suffix}"


def test_state_is_rejects_an_unknown_state_at_construction() -> None:
    with pytest.raises(ValueError, match="sleeping"):
        StateIs("State?", "pilot", "sleeping")


# -- WaitForMode / WaitForState -----------------------------------------------------------------------


def test_wait_for_mode_runs_until_the_part_gets_there(rig: SimulatedSystem) -> None:
    wait = WaitForMode("Wait normal", "pilot", "f_normal_mode")
    tree = rig.tree(wait)
    tree.tick()
    assert wait.status is Status.RUNNING
    assert wait.feedback_message == "waiting: pilot is unconfigured, not active.f_normal_mode"
    rig.run(5.0)
    tree.tick()
    assert wait.status is Status.RUNNING, "it only watches: nothing was requested"
    assert rig.manager.requests() == []

    rig.manager.change_mode("pilot", "f_normal_mode")
    trace = rig.tick_until_done(tree)
    assert {t.status for t in trace[:-1]} == {Status.RUNNING}
    assert trace[-1].status is Status.SUCCESS
    assert wait.feedback_message == "pilot is active.f_normal_mode"


def test_wait_for_mode_times_out_on_the_managers_clock(rig: SimulatedSystem) -> None:
    rig.clock.advance(3.0)  # the timeout counts from initialise, not from the clock's origin
    wait = WaitForMode("Wait normal", "pilot", "f_normal_mode", timeout=1.0)
    # Steps that are exact binary fractions: the tick at 4.0 s is exactly 1 s after the start.
    trace = rig.tick_until_done(rig.tree(wait), step=0.125)
    assert [t.status for t in trace] == [Status.RUNNING] * 8 + [Status.FAILURE]
    assert trace[-1].time == 4.0
    assert wait.feedback_message == "timed out after 1 s: pilot is unconfigured, not active.f_normal_mode"


def test_wait_for_mode_accepts_the_default_mode_marker(rig: SimulatedSystem) -> None:
    wait = WaitForMode("Wait default", "controller_server", "__DEFAULT__", timeout=5.0)
    tree = rig.tree(wait)
    rig.manager.change_mode("controller_server", "__DEFAULT__")
    trace = rig.tick_until_done(tree)
    assert trace[0].status is Status.RUNNING
    assert trace[-1].status is Status.SUCCESS
    assert wait.feedback_message == "controller_server is active.__DEFAULT__"


def test_wait_for_state_runs_then_succeeds(rig: SimulatedSystem) -> None:
    wait = WaitForState("Wait inactive", "amcl", "inactive", timeout=5.0)
    tree = rig.tree(wait)
    tree.tick()
    assert wait.status is Status.RUNNING
    rig.manager.change_state("amcl", "configure")
    trace = rig.tick_until_done(tree)
    assert trace[-1].status is Status.SUCCESS
    assert trace[-1].time == pytest.approx(0.05)
    assert wait.feedback_message == "amcl is inactive"


def test_wait_for_state_fails_after_its_timeout(rig: SimulatedSystem) -> None:
    rig.backend.hang_next("amcl", Transition.CONFIGURE)
    rig.manager.change_state("amcl", "configure")
    wait = WaitForState("Wait inactive", "amcl", State.INACTIVE, timeout=0.5)
    trace = rig.tick_until_done(rig.tree(wait), step=0.125)
    assert [t.status for t in trace] == [Status.RUNNING] * 4 + [Status.FAILURE]
    assert trace[-1].time == 0.5
    assert wait.feedback_message == "timed out after 0.5 s: amcl is configuring, not inactive"


def test_wait_timeout_must_be_positive() -> None:
    with pytest.raises(ValueError, match="timeout must be positive, not -1"):
        WaitForState("Wait", "amcl", "inactive", timeout=-1)


# -- setup --------------------------------------------------------------------------------------------


Factory = Callable[[], py_trees.behaviour.Behaviour]
NAMES = ["ChangeMode", "ChangeState", "ModeIs", "StateIs", "WaitForMode", "WaitForState", "OnDivergence",
         "ModesToBlackboard", "HoldMode", "Reconfigure"]


def factories(part: str, mode: str, names: list[str] = NAMES) -> list[Factory]:
    """Manager behaviours by class name, built inside the test (blackboard clients included)."""
    every: dict[str, Factory] = {
        "ChangeMode": lambda: ChangeMode("Change", part, mode),
        "ChangeState": lambda: ChangeState("Configure", part, "configure"),
        "ModeIs": lambda: ModeIs("Mode?", part, mode),
        "StateIs": lambda: StateIs("Active?", part, "active"),
        "WaitForMode": lambda: WaitForMode("Wait mode", part, mode),
        "WaitForState": lambda: WaitForState("Wait active", part, "active"),
        "OnDivergence": lambda: OnDivergence("Diverges?", part),
        "ModesToBlackboard": lambda: ModesToBlackboard(parts=["pilot", part]),
        "HoldMode": lambda: HoldMode("Hold", part, mode),
        "Reconfigure": lambda: Reconfigure("Reconfigure", Reasoner(part, PILOT_DESIGNS, PILOT_OBJECTIVE)),
    }
    return [every[name] for name in names]


@pytest.mark.parametrize("factory", factories("pilot", "f_normal_mode"), ids=NAMES)
def test_a_tree_set_up_without_a_manager_names_the_behaviour_and_the_fix_when_ticked(factory: Factory) -> None:
    """Setting up without a manager is allowed (py_trees_ros makes the node a runtime needs in
    ``setup``, so the manager comes after it); the first tick still without one says what to do."""
    behaviour = factory()
    tree = py_trees.trees.BehaviourTree(py_trees.composites.Sequence("Root", memory=True, children=[behaviour]))
    tree.setup()
    with pytest.raises(NotSetUp) as raised:
        tree.tick()
    message = str(raised.value)
    assert message.startswith(f"{behaviour.qualified_name}: no mode manager")
    assert "tree.setup(manager=" in message


@pytest.mark.parametrize("factory", factories("pilot", "f_normal_mode"), ids=NAMES)
def test_ticking_without_setup_raises_not_set_up(factory: Factory) -> None:
    tree = py_trees.trees.BehaviourTree(factory())
    with pytest.raises(NotSetUp, match=r"tree\.setup\(manager="):
        tree.tick()


def test_a_manager_of_the_wrong_type_is_a_type_error() -> None:
    tree = py_trees.trees.BehaviourTree(ModeIs("Normal?", "pilot", "f_normal_mode"))
    with pytest.raises(TypeError, match="manager= must be a ModeManager, not str"):
        tree.setup(manager="pilot")


@pytest.mark.parametrize("factory", factories("pilto", "f_normal_mode"), ids=NAMES)
def test_an_unknown_part_fails_at_setup_with_the_real_names(rig: SimulatedSystem, factory: Factory) -> None:
    behaviour = factory()
    tree = py_trees.trees.BehaviourTree(behaviour)
    with pytest.raises(ValueError) as raised:
        tree.setup(manager=rig.manager)
    assert str(raised.value) == (f"{behaviour.qualified_name}: unknown part 'pilto' (did you mean 'pilot'?) "
                                 f"(parts: {PILOT_PARTS})")


WITH_MODE = ["ChangeMode", "ModeIs", "WaitForMode", "HoldMode"]


@pytest.mark.parametrize("factory", factories("pilot", "f_turbo_mode", WITH_MODE), ids=WITH_MODE)
def test_an_unknown_mode_fails_at_setup_with_the_real_modes(rig: SimulatedSystem, factory: Factory) -> None:
    behaviour = factory()
    tree = py_trees.trees.BehaviourTree(behaviour)
    with pytest.raises(ValueError) as raised:
        tree.setup(manager=rig.manager)
    assert str(raised.value) == (
        f"{behaviour.qualified_name}: pilot has no mode 'f_turbo_mode' (did you mean 'f_slow_mode'?) "
        "(modes: __DEFAULT__, f_degraded_mode, "
        "f_energy_saving_mode, f_normal_mode, f_performance_mode, f_slow_mode)")


def test_setup_twice_is_harmless(rig: SimulatedSystem) -> None:
    check = ModeIs("Normal?", "pilot", "f_normal_mode")
    tree = rig.tree(check)
    tree.setup(manager=rig.manager)
    tree.tick()
    assert check.status is Status.FAILURE
