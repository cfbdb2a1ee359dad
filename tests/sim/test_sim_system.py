"""SimulatedSystem, the public simulation kit: models by name, path or value; time by steps or event
by event; requests finished; faults by name; trees ticked as time passes; the pytest fixture."""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest
from model_files import MODELS, bundled
from py_trees.common import Status

from sm_bt.behaviours import ChangeMode, WaitForMode
from sm_bt.engine.events import EventKind
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.errors import ModelError
from sm_bt.sim import NotReached, SimBackend, SimulatedSystem

ROOT = Path(__file__).resolve().parents[2]
ROBOT = ROOT / "docs" / "examples" / "robot.yaml"


def test_a_model_by_bundled_name_by_path_or_as_a_model() -> None:
    by_name = SimulatedSystem("pilot")
    by_path = SimulatedSystem(str(ROBOT))
    by_path_object = SimulatedSystem(ROBOT)
    model = bundled("actuation")
    assert SimulatedSystem(model).model is model
    assert Path(by_name.model.path).name == "pilot.yaml"
    assert set(by_path.model.parts) == set(by_path_object.model.parts) == {"robot", "base", "lidar"}


def test_a_missing_or_invalid_model_says_so() -> None:
    with pytest.raises(ModelError, match="no_such_model: error: cannot read the model file"):
        SimulatedSystem("no_such_model")
    with pytest.raises(ModelError):
        SimulatedSystem(MODELS / "cli_bad.yaml")


def test_options_go_to_the_nodes_or_to_the_manager_by_name() -> None:
    system = SimulatedSystem(ROBOT, transition_delay=0.5, grace_period=3.0, initial_state="inactive")
    assert system.backend.transition_delay == 0.5
    assert system.manager.grace_period == 3.0
    assert system.backend.node("base").state.label == "inactive"
    with pytest.raises(TypeError, match="no_such_option"):
        SimulatedSystem(ROBOT, no_such_option=1)


def test_a_backend_of_ones_own_takes_no_backend_options() -> None:
    model = bundled("pilot")
    backend = SimBackend(model, transition_delay=0.0)
    assert SimulatedSystem(model, backend=backend).backend is backend
    with pytest.raises(TypeError, match="either backend= or options for one \\(transition_delay\\)"):
        SimulatedSystem(model, backend=backend, transition_delay=1.0)


def test_finish_lets_time_pass_until_the_request_is_done() -> None:
    robot = SimulatedSystem(ROBOT, transition_delay=0.25)
    request = robot.finish(robot.manager.change_mode("robot", "FAST"))
    assert request.succeeded, request.reason
    assert str(robot.manager.actual("robot")) == "active.FAST"
    assert 0.5 <= robot.now() <= 0.6  # configure, then activate, 0.25 s each (and the parameter set)


def test_finish_says_which_request_did_not_end_in_time() -> None:
    robot = SimulatedSystem(ROBOT, request_timeout=100.0)
    robot.hang_next("lidar", Transition.CONFIGURE)
    with pytest.raises(NotReached, match=r"change_mode robot FAST .*not done within 2 s of virtual time"):
        robot.finish(robot.manager.change_mode("robot", "FAST"), timeout=2.0)
    assert isinstance(NotReached(), AssertionError)


def test_run_until_by_steps_and_event_by_event() -> None:
    stepped = SimulatedSystem(ROBOT, transition_delay=0.123)
    stepped.manager.change_state("robot", "configure")
    took = stepped.run_until(lambda: str(stepped.manager.actual("robot")) == "inactive")
    assert took == pytest.approx(0.13)  # the next step of 0.01 after 0.123
    jumping = SimulatedSystem(ROBOT, transition_delay=0.123)
    jumping.manager.change_state("robot", "configure")
    took = jumping.run_until(lambda: str(jumping.manager.actual("robot")) == "inactive", step=None)
    assert took == pytest.approx(0.123)  # exactly when it happened
    with pytest.raises(NotReached, match="nothing left to happen"):
        jumping.run_until(lambda: False, step=None)
    with pytest.raises(NotReached, match=r"within 0\.5 s"):
        jumping.run_until(lambda: False, timeout=0.5)


def test_events_are_recorded_unless_asked_not_to() -> None:
    recorded = SimulatedSystem(ROBOT)
    recorded.finish(recorded.manager.change_mode("robot", "FAST"))
    assert recorded.events_of(EventKind.REQUEST, "robot")
    assert all(event.part == "robot" for event in recorded.events_of(EventKind.REQUEST, "robot"))
    silent = SimulatedSystem(ROBOT, record=False)
    silent.finish(silent.manager.change_mode("robot", "FAST"))
    assert silent.events == []


def test_faults_by_name_reach_the_manager() -> None:
    robot = SimulatedSystem(ROBOT, vanish_after=1.0, recovery=False)
    robot.finish(robot.manager.change_mode("robot", "FAST"))
    robot.fail("lidar")
    robot.run(1.0)
    assert str(robot.manager.actual("lidar")) == "unconfigured"
    robot.vanish("base")
    assert not robot.manager.observation("base").reachable
    robot.restart("base", "inactive")
    assert robot.manager.observation("base").reachable
    robot.crash("base")
    robot.run(0.5)
    assert robot.manager.observation("base").reachable  # not gone yet: it only stopped answering
    robot.run(0.5)
    assert not robot.manager.observation("base").reachable


def test_armed_faults_fail_requests_and_can_be_disarmed() -> None:
    robot = SimulatedSystem(ROBOT, recovery=False)
    robot.fail_next("lidar", Transition.CONFIGURE)
    assert not robot.finish(robot.manager.change_state("robot", "configure")).succeeded
    robot.reject_parameters("base", "locked")
    robot.clear_faults("base")
    assert robot.finish(robot.manager.change_mode("robot", "FAST")).succeeded


def test_a_tree_is_set_up_with_the_manager_and_ticked_as_time_passes() -> None:
    py_trees.blackboard.Blackboard.clear()
    robot = SimulatedSystem(ROBOT, transition_delay=0.2)
    root = py_trees.composites.Sequence("go fast", memory=True, children=[
        ChangeMode("ask", part="robot", mode="FAST"), WaitForMode("confirmed", part="robot", mode="FAST")])
    tree = robot.tree(root)
    trace = robot.tick_until_done(tree, step=0.1)
    assert root.status is Status.SUCCESS
    assert trace[0].status is Status.RUNNING and trace[-1].status is Status.SUCCESS
    assert [tick.time for tick in trace] == pytest.approx([0.1 * i for i in range(len(trace))])
    ticks = robot.tick_for(tree, 0.5, step=0.1)
    assert len(ticks) == 6  # both ends
    with pytest.raises(NotReached, match="last tick of go fast"):
        robot.tick_until(tree, lambda: False, timeout=0.3)
    py_trees.blackboard.Blackboard.clear()


def test_closing_stops_the_manager_and_a_with_block_closes_it() -> None:
    with SimulatedSystem(ROBOT) as robot:
        pass
    request = robot.manager.change_mode("robot", "FAST")
    assert request.refused and request.reason == "the manager is closed"


def test_the_fixture_makes_systems_and_closes_them(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(f"""
        import py_trees

        def test_robot(simulated_system):
            robot = simulated_system({str(ROBOT)!r})
            assert robot.finish(robot.manager.change_mode("robot", "FAST")).succeeded
            py_trees.blackboard.Blackboard.set("left", True)
            test_robot.made = robot

        def test_after():
            assert test_robot.made.manager.change_mode("robot", "SLOW").refused  # closed
            assert not py_trees.blackboard.Blackboard.exists("left")
    """)
    pytester.runpytest_subprocess("-p", "no:cacheprovider").assert_outcomes(passed=2)
