"""The MROS pilot mission, with its contingencies handled in the tree.

Patrol seven waypoints; when the battery runs low, recharge in energy-saving mode; repeat. The
tree reconfigures the robot only by asking for modes of the ``pilot`` system:

* start-up: configure, then ``f_normal_mode``
* laser failure (laser_resender leaves its target by itself) -> ``f_degraded_mode``
* laser scans healthy again while degraded -> ``f_normal_mode``
* battery low -> recharge while holding ``f_energy_saving_mode`` (or in degraded mode, which
  has no laser to spare); battery recovered -> the previous mode comes back

Set it up with ``tree.setup(manager=ModeManager(load_model(...pilot...), backend), world=World())``.
"""

from __future__ import annotations

from pathlib import Path

import py_trees
from py_trees.behaviour import Behaviour

from sm_bt.behaviours import (
    ChangeMode,
    ChangeState,
    ModeIs,
    ModesToBlackboard,
    hold_mode,
    switch_on_divergence,
)
from sm_bt.sim.world import PATROL
from sm_bt.trees.pilot_actions import (
    BATTERY_OK,
    LASER_SCANS_OK,
    BatteryToBlackboard,
    FlagIs,
    NavigateTo,
    Recharge,
    ScansToBlackboard,
)

#: The same mission in BehaviorTree.CPP-style XML (:func:`sm_bt.trees.mission_xml.load_tree`).
XML = Path(__file__).with_name("pilot.xml")

SYSTEM = "pilot"
NORMAL = "f_normal_mode"
DEGRADED = "f_degraded_mode"
ENERGY_SAVING = "f_energy_saving_mode"


def is_true(name: str, key: str, value: bool) -> Behaviour:
    """A blackboard check: SUCCESS when ``key`` holds ``value`` (:class:`FlagIs`)."""
    return FlagIs(name, key, value)


def gather() -> py_trees.composites.Sequence:
    """Data gathering, every tick: part states and modes, battery, laser scans."""
    return py_trees.composites.Sequence("Gather", memory=False, children=[
        ModesToBlackboard(),
        BatteryToBlackboard(),
        ScansToBlackboard(),
    ])


def go_and_recharge(suffix: str = "") -> Behaviour:
    return py_trees.composites.Sequence(f"Go and recharge{suffix}", memory=True, children=[
        NavigateTo(f"To recharge station{suffix}", "recharge_station"),
        Recharge(f"Recharge{suffix}"),
    ])


def recharge() -> Behaviour:
    """Battery low: recharge. In energy-saving mode unless degraded (the laser is broken)."""
    return py_trees.composites.Sequence("Recharging", memory=True, children=[
        is_true("Battery low?", BATTERY_OK, False),
        py_trees.composites.Selector("Recharge in a mode", memory=True, children=[
            py_trees.composites.Sequence("Recharge degraded", memory=True, children=[
                ModeIs("Degraded?", SYSTEM, DEGRADED),
                go_and_recharge(" (degraded)"),
            ]),
            hold_mode("Energy saving", SYSTEM, ENERGY_SAVING, go_and_recharge()),
        ]),
    ])


def patrolling() -> Behaviour:
    """Visit the seven waypoints in order."""
    return py_trees.composites.Sequence("Patrolling", memory=True, children=[
        NavigateTo(f"To {wp}", wp) for wp in PATROL
    ])


def patrol(cycles: int) -> Behaviour:
    """``cycles`` rounds of: recharge if the battery is low, else patrol."""
    either = py_trees.composites.Selector("Patrol or recharge", memory=False, children=[recharge(), patrolling()])
    return py_trees.decorators.Repeat("Patrol", child=either, num_success=cycles)


def contingencies() -> Behaviour:
    """Always RUNNING: watches for the laser contingencies and switches mode."""
    laser_back = py_trees.composites.Sequence("Laser back", memory=True, children=[
        ModeIs("Degraded?", SYSTEM, DEGRADED),
        is_true("Scans healthy?", LASER_SCANS_OK, True),
        ChangeMode(f"{NORMAL} again", SYSTEM, NORMAL),
    ])
    return py_trees.composites.Selector("Contingencies", memory=False, children=[
        switch_on_divergence("Laser lost", "laser_resender", SYSTEM, DEGRADED),
        laser_back,
        py_trees.behaviours.Running("Nominal"),
    ])


def create_root(cycles: int = 2) -> Behaviour:
    """The pilot mission: ``cycles`` rounds of patrol-or-recharge, then SUCCESS."""
    start_up = py_trees.composites.Sequence("Start-up", memory=True, children=[
        ChangeState("Configure", SYSTEM, "configure"),
        ChangeMode(NORMAL, SYSTEM, NORMAL),
    ])
    mission_body = patrol(cycles)
    # Done when the patrol is: the contingencies never succeed (a switch they make counts as
    # still watching), which XML can say too (py_trees' XML has no SuccessOnSelected).
    mission = py_trees.composites.Parallel(
        "Patrol with contingencies",
        policy=py_trees.common.ParallelPolicy.SuccessOnOne(),
        children=[py_trees.decorators.SuccessIsRunning("Keep watching", contingencies()), mission_body],
    )
    return py_trees.composites.Sequence("Pilot", memory=False, children=[
        gather(),
        py_trees.composites.Sequence("Mission", memory=True, children=[start_up, mission]),
    ])
