"""The MROS pilot mission, with its contingencies handled in the tree.

Patrol seven waypoints, ``cycles`` rounds; whenever the battery runs low, recharge in
energy-saving mode and carry on where the round was (a recharge is not a round). The tree
reconfigures the robot only by asking for modes of the ``pilot`` system:

* start-up: configure, then ``f_normal_mode``
* laser failure (laser_resender leaves its target by itself) -> ``f_degraded_mode``
* laser scans healthy again while degraded -> ``f_normal_mode``
* battery below 0.5 -> recharge while holding ``f_energy_saving_mode`` (or in degraded mode,
  which has no laser to spare); recharged -> the previous mode comes back

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
from sm_bt.engine.holds import PRIORITIES
from sm_bt.trees.pilot.actions import (
    BATTERY_LEVEL,
    LASER_SCANS_OK,
    BatteryToBlackboard,
    CompleteRound,
    FlagIs,
    LevelAtLeast,
    NavigateTo,
    Recharge,
    ScansToBlackboard,
    Visited,
)
from sm_bt.trees.pilot.world import PATROL

#: The same mission in BehaviorTree.CPP-style XML (:func:`sm_bt.trees.mission_xml.load_tree`).
XML = Path(__file__).with_name("pilot.xml")

SYSTEM = "pilot"
NORMAL = "f_normal_mode"
DEGRADED = "f_degraded_mode"
ENERGY_SAVING = "f_energy_saving_mode"
#: Below this battery level the robot recharges before it drives on.
BATTERY_LOW = 0.5


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
    """Recharge: in energy-saving mode, unless degraded (the laser is broken)."""
    return py_trees.composites.Selector("Recharging", memory=True, children=[
        py_trees.composites.Sequence("Recharge degraded", memory=True, children=[
            ModeIs("Degraded?", SYSTEM, DEGRADED),
            go_and_recharge(" (degraded)"),
        ]),
        hold_mode("Energy saving", SYSTEM, ENERGY_SAVING, go_and_recharge()),
    ])


def recharge_if_allowed() -> Behaviour:
    """Recharge in energy-saving mode if the manager allows it, else as the pilot is: with the
    model's laser rule (``pilot_rules``) the rule holds degraded mode while the laser is down, and
    the tree need not know (the manager refuses the change, naming the rule)."""
    return py_trees.composites.Selector("Recharging", memory=True, children=[
        hold_mode("Energy saving", SYSTEM, ENERGY_SAVING, go_and_recharge()),
        go_and_recharge(" (as is)"),
    ])


def patrol_round(recharging: Behaviour) -> Behaviour:
    """One round of the seven waypoints, with ``recharging`` first whenever the battery is low.

    Memoryless, so the battery is checked at every tick; each leg is skipped once visited in
    this round, so that after a recharge the round goes on where it was (py_trees' idiom of a
    condition before its action)."""
    legs = [py_trees.composites.Selector(wp, memory=False, children=[
        Visited(f"Visited {wp}?", wp),
        NavigateTo(f"To {wp}", wp),
    ]) for wp in PATROL]
    return py_trees.composites.Sequence("Patrol round", memory=False, children=[
        py_trees.composites.Selector("Battery", memory=False, children=[
            LevelAtLeast("Battery OK?", BATTERY_LEVEL, BATTERY_LOW),
            recharging,
        ]),
        *legs,
        CompleteRound("Round complete"),
    ])


def patrol(cycles: int, recharging: Behaviour | None = None) -> Behaviour:
    """``cycles`` patrol rounds (:func:`patrol_round`); ``recharging`` defaults to :func:`recharge`."""
    return py_trees.decorators.Repeat("Patrol", child=patrol_round(recharging or recharge()), num_success=cycles)


def contingencies() -> Behaviour:
    """Always RUNNING: watches for the laser contingencies and switches mode."""
    return py_trees.composites.Selector("Contingencies", memory=False, children=[
        switch_on_divergence("Laser lost", "laser_resender", SYSTEM, DEGRADED),
        laser_back(),
        py_trees.behaviours.Running("Nominal"),
    ])


def laser_back() -> Behaviour:
    """Scans healthy again while degraded -> normal mode, at the rules' priority: the tree sees the
    laser work again, which ends a laser rule's hold of degraded mode (nothing else tells the
    manager that the laser works)."""
    return py_trees.composites.Sequence("Laser back", memory=True, children=[
        ModeIs("Degraded?", SYSTEM, DEGRADED),
        is_true("Scans healthy?", LASER_SCANS_OK, True),
        ChangeMode(f"{NORMAL} again", SYSTEM, NORMAL, priority=PRIORITIES["rule"]),
    ])


def create_root(cycles: int = 2, *, rules: bool = False) -> Behaviour:
    """The pilot mission: ``cycles`` patrol rounds (recharging as needed), then SUCCESS. With
    ``rules``, for the model with the laser rule (``pilot_rules``): the manager switches to
    degraded mode and holds it, so the tree only watches for the laser coming back and recharges
    in energy-saving mode when the manager allows it."""
    start_up = py_trees.composites.Sequence("Start-up", memory=True, children=[
        ChangeState("Configure", SYSTEM, "configure"),
        ChangeMode(NORMAL, SYSTEM, NORMAL),
    ])
    mission_body = patrol(cycles, recharge_if_allowed() if rules else None)
    watching = (py_trees.composites.Selector("Contingencies", memory=False, children=[
        laser_back(), py_trees.behaviours.Running("Nominal")]) if rules else contingencies())
    # Done when the patrol is: the contingencies never succeed (a switch they make counts as
    # still watching), which XML can say too (py_trees' XML has no SuccessOnSelected).
    mission = py_trees.composites.Parallel(
        "Patrol with contingencies",
        policy=py_trees.common.ParallelPolicy.SuccessOnOne(),
        children=[py_trees.decorators.SuccessIsRunning("Keep watching", watching), mission_body],
    )
    return py_trees.composites.Sequence("Pilot", memory=False, children=[
        gather(),
        py_trees.composites.Sequence("Mission", memory=True, children=[start_up, mission]),
    ])
