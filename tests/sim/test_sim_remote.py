"""A fleet whose robots are remote parts, on the simulated backend: the engine drives them as it
drives nodes (their one parameter is their mode), so fleet modes, a robot lost and the fleet's
rule, and a robot back all work as for local parts."""

from __future__ import annotations

from sm_bt.engine.events import EventKind
from sm_bt.model import load_model_text
from sm_bt.model.states import State
from sm_bt.model.types import REMOTE_MODE
from sm_bt.sim.system import SimulatedSystem

FLEET = """\
fleet:
  ros__parameters:
    type: system
    parts: [robot1, robot2]
    modes:
      __DEFAULT__:
        robot1: active
        robot2: active
      NIGHT:
        robot1: active.f_energy_saving_mode
        robot2: inactive
      EVACUATE:
        robot1: __DONTCARE__
        robot2: active.f_degraded_mode
    rules:
      robot1_lost:
        if_target: active.__DEFAULT__
        if_part: [robot1, unknown]
        new_target: active.EVACUATE
robot1:
  ros__parameters:
    type: remote
    manager: /robot1
    system: pilot
    modes: [__DEFAULT__, f_energy_saving_mode, f_degraded_mode]
robot2:
  ros__parameters:
    type: remote
    manager: /robot2
    system: pilot
    modes: [__DEFAULT__, f_energy_saving_mode, f_degraded_mode]
"""


def test_fleet_modes_reach_each_robot_and_a_lost_robot_fires_the_fleets_rule() -> None:
    fleet = SimulatedSystem(load_model_text(FLEET, "fleet.yaml"))
    try:
        manager = fleet.manager
        assert fleet.finish(manager.change_mode("fleet", "__DEFAULT__")).succeeded
        assert str(manager.actual("fleet")) == "active.__DEFAULT__"
        night = fleet.finish(manager.change_mode("fleet", "NIGHT"))
        assert night.succeeded, night.reason
        assert str(manager.actual("robot1")) == "active.f_energy_saving_mode"
        assert manager.observation("robot1").parameters == {REMOTE_MODE: "f_energy_saving_mode"}
        assert manager.actual("robot2").state is State.INACTIVE
        assert fleet.finish(manager.change_mode("fleet", "__DEFAULT__")).succeeded

        fleet.vanish("robot1")
        assert manager.actual("robot1").state is State.UNKNOWN
        fleet.run_until(lambda: bool(fleet.events_of(EventKind.RULE, "fleet")), timeout=10.0)
        fleet.run_until(lambda: str(manager.actual("fleet")) == "active.EVACUATE", timeout=10.0)
        assert str(manager.actual("robot2")) == "active.f_degraded_mode"

        fleet.restart("robot1", State.ACTIVE)
        fleet.run_until(lambda: manager.actual("robot1").state is not State.UNKNOWN, timeout=10.0)
        back = fleet.finish(manager.change_mode("fleet", "__DEFAULT__"))
        assert back.succeeded, back.reason
        assert str(manager.actual("robot1")) == "active.__DEFAULT__"
    finally:
        fleet.close()
