"""A manager of managers on the simulated backend: a fleet whose remote parts are robots with managers
of their own (sm_bt.sim.remotes), on one virtual clock."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from test_sim_remote import FLEET

from sm_bt.engine.events import EventKind
from sm_bt.model import load_model_text
from sm_bt.model.states import State
from sm_bt.sim.remotes import NotAFleet, RemoteManagers, simulated_fleet
from sm_bt.sim.system import SimulatedSystem

ROBOTS = {"robot1": "pilot", "robot2": "pilot"}


def fleet_of_pilots(**options: Any) -> tuple[SimulatedSystem, dict[str, SimulatedSystem]]:
    return simulated_fleet(load_model_text(FLEET, "fleet.yaml"), ROBOTS, **options)


def requests(robot: SimulatedSystem) -> list[str]:
    """The requests a robot's manager received, in order."""
    return list({e.request.id: e.request.description for e in robot.events_of(EventKind.REQUEST)
                 if e.request is not None}.values())


def test_a_fleet_mode_becomes_each_robots_own_request_and_takes_as_long_as_the_slowest() -> None:
    alone = SimulatedSystem("pilot", transition_delay=0.3)
    request = alone.manager.change_mode("pilot", "__DEFAULT__")
    own = alone.run_until(lambda: request.done)
    fleet, robots = fleet_of_pilots(transition_delay=0.3)
    up = fleet.manager.change_mode("fleet", "__DEFAULT__")
    took = fleet.run_until(lambda: up.done)
    assert up.succeeded, up.reason
    assert own <= took <= 1.5 * own, (took, own)
    for robot in robots.values():  # each robot's manager did it, by a request of its own
        assert requests(robot) == ["change_mode pilot __DEFAULT__"]
    night = fleet.finish(fleet.manager.change_mode("fleet", "NIGHT"))
    assert night.succeeded, night.reason
    assert str(robots["robot1"].manager.actual("pilot")) == "active.f_energy_saving_mode"
    assert robots["robot2"].manager.actual("pilot").state is State.INACTIVE
    assert str(fleet.manager.actual("robot1")) == "active.f_energy_saving_mode"
    assert str(fleet.manager.actual("fleet")) == "active.NIGHT"


def test_a_robot_cut_off_is_unknown_the_fleets_rule_reacts_and_after_the_heal_the_fleet_is_consistent() -> None:
    fleet, robots = fleet_of_pilots()
    backend = fleet.backend
    assert isinstance(backend, RemoteManagers)
    assert fleet.finish(fleet.manager.change_mode("fleet", "__DEFAULT__")).succeeded
    backend.cut("robot1")
    fleet.run(0.01)
    assert fleet.manager.actual("robot1").state is State.UNKNOWN
    # A fleet request that needs the robot is refused as a whole: nothing reaches robot2 either.
    before = len(requests(robots["robot2"]))
    refused = fleet.manager.change_mode("fleet", "NIGHT")
    assert refused.done and refused.refused and "robot1" in refused.reason
    fleet.run(1.0)
    # The rule: robot1 lost -> EVACUATE, where robot1 is left as it is and robot2 degrades.
    fleet.run_until(lambda: str(fleet.manager.actual("fleet")) == "active.EVACUATE", timeout=10.0)
    assert requests(robots["robot2"])[before:] == ["change_mode pilot f_degraded_mode"]
    # Meanwhile robot1's own manager went on: someone on the robot switched it.
    assert robots["robot1"].finish(robots["robot1"].manager.change_mode("pilot", "f_degraded_mode")).succeeded
    seen = len(fleet.events)
    backend.heal("robot1")
    # Read afresh, not remembered; then its target (the fleet's __DEFAULT__ entry: EVACUATE left it
    # as it was) is restored, and the fleet and the robot agree.
    fleet.run_until(lambda: str(fleet.manager.actual("robot1")) == "active.__DEFAULT__", timeout=5.0)
    came_back = next(e for e in fleet.events[seen:] if e.kind is EventKind.ACTUAL and e.part == "robot1")
    assert str(came_back.actual) == "active.f_degraded_mode"
    assert any(e.kind is EventKind.REQUEST and e.request is not None and e.request.origin.value == "recovery"
               for e in fleet.events[seen:])
    assert str(robots["robot1"].manager.actual("pilot")) == "active.__DEFAULT__"
    back = fleet.finish(fleet.manager.change_mode("fleet", "__DEFAULT__"))
    assert back.succeeded, back.reason
    assert str(fleet.manager.actual("fleet")) == "active.__DEFAULT__"


def test_models_and_robots_that_do_not_fit_are_told() -> None:
    model = load_model_text(FLEET, "fleet.yaml")
    fleet, robots = fleet_of_pilots()
    with pytest.raises(NotAFleet, match="the robots must be the remote parts, robot1 given, robot2 missing"):
        RemoteManagers(model, {"robot1": robots["robot1"]}, fleet.clock)
    with pytest.raises(NotAFleet, match=r"robot robot1: its model .* has no part 'pilot'"):
        simulated_fleet(model, {"robot1": "actuation", "robot2": "pilot"})
    with pytest.raises(NotAFleet, match="robot robot2: its system runs on another clock"):
        RemoteManagers(model, {"robot1": robots["robot1"], "robot2": SimulatedSystem("pilot")}, fleet.clock)
    renamed = load_model_text(FLEET.replace("f_degraded_mode]", "f_typo_mode]", 1), "fleet.yaml")
    with pytest.raises(NotAFleet, match=r"robot robot1: pilot of .* has no mode f_typo_mode"):
        simulated_fleet(renamed, ROBOTS)
    with pytest.raises(NotAFleet, match="amcl, controller_server, pointcloud_to_laser, laser_resender are nodes"):
        simulated_fleet("pilot", {})


_ACTIONS = st.lists(st.one_of(
    st.tuples(st.just("fleet"), st.sampled_from(("__DEFAULT__", "NIGHT", "EVACUATE"))),
    st.tuples(st.just("cut"), st.sampled_from(tuple(ROBOTS))),
    st.tuples(st.just("heal"), st.sampled_from(tuple(ROBOTS))),
    st.tuples(st.just("local"), st.sampled_from(tuple(ROBOTS)),
              st.sampled_from(("__DEFAULT__", "f_energy_saving_mode", "f_degraded_mode"))),
    st.tuples(st.just("wait"), st.sampled_from((0.0, 0.02, 0.1, 0.5, 2.5)))), min_size=1, max_size=12)


@examples(100, stress=10_000)
@given(_ACTIONS)
def test_partitions_and_requests_in_any_order_leave_the_fleet_consistent_with_its_robots(
        actions: list[tuple[Any, ...]]) -> None:
    """Whatever fleet requests, cuts, heals, robots' own changes and waits come in whatever order:
    a fleet request refused as a whole sends nothing to any robot, and once every robot is healed
    and the fleet settles, the fleet's view of each robot is what the robot's own manager infers."""
    fleet, robots = fleet_of_pilots(grace_period=0.5)
    backend = fleet.backend
    assert isinstance(backend, RemoteManagers)
    for action in actions:
        if action[0] == "fleet":
            before = {name: len(requests(robot)) for name, robot in robots.items()}
            request = fleet.manager.change_mode("fleet", action[1])
            if request.refused:
                assert {name: len(requests(robot)) for name, robot in robots.items()} == before
        elif action[0] == "cut":
            backend.cut(action[1])
        elif action[0] == "heal":
            backend.heal(action[1])
        elif action[0] == "local":
            robots[action[1]].manager.change_mode("pilot", action[2])
        else:
            fleet.run(action[1])
    for name in ROBOTS:
        backend.heal(name)
    fleet.run(30.0)  # requests end (timeouts included), recovery settles
    for name, robot in robots.items():
        assert fleet.manager.actual(name).state_mode == robot.manager.actual("pilot").state_mode, name
