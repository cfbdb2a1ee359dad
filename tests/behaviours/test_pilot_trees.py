"""The MROS pilot mission trees, step by step, on simulated nodes in the simulated world."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator

import py_trees
import pytest
from model_files import bundled
from py_trees.common import Status

from sm_bt.engine.events import Event
from sm_bt.model.types import Model
from sm_bt.sim import SimulatedSystem
from sm_bt.trees import pilot
from sm_bt.trees.mission_xml import load_tree
from sm_bt.trees.pilot import metacontrol as pilot_metacontrol
from sm_bt.trees.pilot.actions import NavigateTo, Recharge
from sm_bt.trees.pilot.world import PATROL, LaserDevice, World

TREES: dict[str, Callable[[int], py_trees.behaviour.Behaviour]] = {
    "pilot": lambda cycles: pilot.create_root(cycles),
    "pilot_xml": lambda cycles: load_tree(pilot.XML, inputs={"cycles": cycles}),
    "metacontrol": lambda cycles: pilot_metacontrol.create_root(cycles),
}
DEGRADED_AMCL = {"transform_tolerance": 2.5, **{f"alpha{i}": 0.05 for i in range(1, 6)}}
CONTROLLER = {
    "DEFAULT": (0.3, 0.3, 1.25, 0.2),
    "SLOW": (0.1, 0.1, 0.5, 0.2),
    "DEGRADED": (0.1, 0.1, 0.5, 2.5),
}


@pytest.fixture(autouse=True)
def clean_blackboard() -> Iterator[None]:
    py_trees.blackboard.Blackboard.clear()
    yield
    py_trees.blackboard.Blackboard.clear()


class Mission:
    """A pilot tree ticked every 0.1 s of virtual time against simulated nodes."""

    def __init__(self, tree: str, cycles: int = 3, model: Model | None = None, time_scale: float = 1.0) -> None:
        self.system = SimulatedSystem(model or bundled("pilot"), transition_delay=0.2, parameter_delay=0.05,
                                      request_timeout=10.0, grace_period=1.0, recovery_attempts=1)
        self.backend, self.clock, self.manager = self.system.backend, self.system.clock, self.system.manager
        self.world = World(time_scale=time_scale)
        self.laser = LaserDevice(self.world, self.backend)
        self.root = TREES[tree](cycles)
        self.tree = self.system.tree(self.root, world=self.world)

    def tick(self) -> None:
        self.tree.tick()
        self.clock.advance(0.1)
        self.laser.update()

    def until(self, condition: Callable[[], bool], limit: float = 300.0) -> float:
        start = self.clock.now()
        while not condition():
            assert self.clock.now() - start < limit, f"not reached within {limit} s; pilot is {self.pilot}"
            assert self.root.status is not Status.FAILURE, py_trees.display.unicode_tree(self.root, show_status=True)
            self.tick()
        return self.clock.now() - start

    @property
    def pilot(self) -> str:
        return str(self.manager.actual("pilot"))

    def state(self, node: str) -> str:
        return self.backend.node(node).state.label

    def parameters(self, node: str) -> dict[str, object]:
        return dict(self.backend.node(node).parameters)

    def controller(self) -> tuple[object, ...]:
        p = self.parameters("controller_server")
        return tuple(p[f"FollowPath.{k}"] for k in ("max_vel_x", "max_speed_xy", "max_vel_theta",
                                                       "transform_tolerance"))

    def navigating_to(self) -> list[str]:
        return [b.waypoint for b in self.root.iterate()
                if isinstance(b, NavigateTo) and b.status is Status.RUNNING]


@pytest.mark.parametrize("tree", sorted(TREES))
def test_start_up_into_normal_mode(tree: str) -> None:
    mission = Mission(tree)
    mission.until(lambda: mission.pilot == "active.f_normal_mode", limit=5.0)
    assert mission.state("laser_resender") == "active" and mission.state("pointcloud_to_laser") == "inactive"
    assert mission.controller() == CONTROLLER["DEFAULT"]
    mission.until(lambda: mission.world.odometer > 0.5, limit=5.0)
    assert mission.navigating_to() == ["wp_1"]


@pytest.mark.parametrize("tree", sorted(TREES))
def test_laser_failure_degrades_and_repair_restores_normal(tree: str) -> None:
    mission = Mission(tree)
    mission.until(lambda: mission.world.odometer > 2.0)
    mission.laser.break_laser()
    took = mission.until(lambda: mission.pilot == "active.f_degraded_mode", limit=10.0)
    # Recovery tries once (the laser fails again), gives up, and the tree switches.
    assert mission.laser.failures == 2 and mission.manager.failed() == [] and took < 5.0
    assert mission.state("laser_resender") == "unconfigured"
    assert mission.state("pointcloud_to_laser") == "active"
    amcl = mission.parameters("amcl")
    assert {k: amcl[k] for k in DEGRADED_AMCL} == DEGRADED_AMCL
    assert mission.controller() == CONTROLLER["DEGRADED"]
    # The robot keeps going, slower, on the virtual laser.
    before = mission.world.odometer
    mission.until(lambda: mission.clock.now() > 30.0)
    assert 0.5 < mission.world.odometer - before < 0.1 * 30
    mission.laser.repair()
    mission.until(lambda: mission.pilot == "active.f_normal_mode", limit=5.0)
    assert mission.state("laser_resender") == "active" and mission.state("pointcloud_to_laser") == "inactive"
    assert mission.controller() == CONTROLLER["DEFAULT"]


@pytest.mark.parametrize("tree", sorted(TREES))
def test_battery_low_energy_saving_recharge_and_back_to_normal(tree: str) -> None:
    mission = Mission(tree)
    mission.until(lambda: mission.pilot == "active.f_normal_mode")
    mission.until(lambda: mission.world.battery < 0.5)
    resume_at = next_waypoint(mission)
    mission.until(lambda: mission.pilot == "active.f_energy_saving_mode", limit=2.0)
    assert mission.controller() == CONTROLLER["SLOW"]
    mission.until(lambda: mission.navigating_to() == ["recharge_station"], limit=2.0)
    mission.until(lambda: mission.world.battery == 1.0)
    assert mission.world.distance_to("recharge_station") < 1e-6
    mission.until(lambda: mission.pilot == "active.f_normal_mode", limit=2.0)
    assert mission.controller() == CONTROLLER["DEFAULT"]
    # The round goes on where it was: a recharge neither restarts nor ends it.
    assert resume_at != "wp_1"
    mission.until(lambda: mission.navigating_to() == [resume_at], limit=2.0)
    assert mission.world.rounds == 0


def next_waypoint(mission: Mission) -> str:
    """The first waypoint of the round not visited yet."""
    return next(wp for wp in PATROL if wp not in mission.world.visited)


@pytest.mark.parametrize("tree", sorted(TREES))
def test_battery_low_while_degraded_recharges_without_the_laser(tree: str) -> None:
    mission = Mission(tree)
    mission.until(lambda: mission.pilot == "active.f_normal_mode")
    mission.laser.break_laser()
    mission.until(lambda: mission.pilot == "active.f_degraded_mode", limit=10.0)
    mission.world.battery = 0.49
    resume_at = next_waypoint(mission)
    mission.until(lambda: mission.navigating_to() == ["recharge_station"], limit=2.0)
    # Energy saving needs the laser: the robot recharges in degraded mode.
    assert mission.pilot == "active.f_degraded_mode"
    mission.until(lambda: mission.world.battery == 1.0)
    mission.until(lambda: mission.navigating_to() == [resume_at], limit=2.0)
    assert mission.pilot == "active.f_degraded_mode"


@pytest.mark.parametrize("tree", sorted(TREES))
def test_mission_completes_its_cycles(tree: str) -> None:
    mission = Mission(tree, cycles=1)
    mission.world.battery, mission.world.drain_per_metre = 1.0, 0.01  # enough for a whole patrol
    mission.until(lambda: mission.root.status is Status.SUCCESS, limit=200.0)
    assert mission.world.position == mission.world.waypoints["wp_7"]
    assert mission.pilot == "active.f_normal_mode"


def test_metacontrol_explains_its_choices() -> None:
    mission = Mission("metacontrol")
    reconfigure = next(b for b in mission.root.iterate() if b.name == "Reconfigure")

    def explained(text: str) -> Callable[[], bool]:
        return lambda: reconfigure.status is Status.SUCCESS and text in reconfigure.feedback_message

    mission.until(explained("all components OK: f_normal_mode has the best performance"), limit=5.0)
    assert "-> pilot is active.f_normal_mode" in reconfigure.feedback_message
    mission.laser.break_laser()
    mission.until(explained("laser_resender failed: f_degraded_mode is the only realisable design"), limit=10.0)
    mission.laser.repair()
    mission.until(explained("all components OK"), limit=5.0)
    mission.world.battery = 0.45
    mission.until(explained("battery failed: f_energy_saving_mode is the only realisable design"), limit=5.0)
    assert mission.pilot == "active.f_energy_saving_mode"


@pytest.mark.parametrize("tree", sorted(TREES))
def test_trees_render_with_py_trees_display(tree: str) -> None:
    root = TREES[tree](2)
    text = py_trees.display.unicode_tree(root)
    assert "Patrol round" in text and "To wp_7" in text
    dot = py_trees.display.dot_tree(root).to_string()
    assert "digraph" in dot and "wp_7" in dot
    assert "Recharg" in py_trees.display.xhtml_tree(root)


def test_tree_setup_without_world_is_a_clear_error() -> None:
    system = SimulatedSystem(bundled("pilot"))
    expected = r"no world: the pilot's actions drive a simulated robot, so its trees run in `sm-bt demo`.*" \
               r"tree.setup\(manager=manager, world=World\(\)\)"
    with pytest.raises(RuntimeError, match=expected):
        system.tree(pilot.create_root())


def test_a_faster_world_drives_and_recharges_in_less_clock_time() -> None:
    # The ROS demo's world runs --speed times faster than the manager's wall clock.
    def first_waypoint_and_recharge(scale: float) -> tuple[float, float]:
        mission = Mission("pilot", cycles=1, time_scale=scale)
        mission.until(lambda: mission.pilot == "active.f_normal_mode")
        driven = mission.until(lambda: mission.world.odometer > 0 and "wp_1" not in mission.navigating_to())
        mission.world.battery = 0.1  # low: the tree goes to recharge
        mission.until(lambda: any(isinstance(b, Recharge) and b.status is Status.RUNNING
                                  for b in mission.root.iterate()))
        charging = mission.until(lambda: mission.world.battery == 1.0)
        return driven, charging

    slow_drive, slow_charge = first_waypoint_and_recharge(1.0)
    fast_drive, fast_charge = first_waypoint_and_recharge(10.0)
    assert fast_drive < slow_drive / 5
    assert slow_charge == pytest.approx(10.0, abs=0.25)
    assert fast_charge == pytest.approx(1.0, abs=0.25)


@pytest.mark.parametrize("scale", [0.0, -1.0, float("inf"), float("nan")])
def test_a_world_time_scale_must_be_a_finite_positive_number(scale: float) -> None:
    with pytest.raises(ValueError, match="time_scale must be a finite number > 0"):
        World(time_scale=scale)


def _story(tree: str) -> list[tuple[float, str, str, str]]:
    """Every event of the manager over one scripted mission: normal, the laser fails and is
    repaired, the battery runs low, the patrol completes."""
    mission = Mission(tree, cycles=1)
    story: list[tuple[float, str, str, str]] = []
    mission.manager.subscribe(lambda event: story.append(_told(mission.clock.now(), event)))
    mission.until(lambda: mission.world.odometer > 2.0)
    mission.laser.break_laser()
    mission.until(lambda: mission.pilot == "active.f_degraded_mode", limit=10.0)
    mission.until(lambda: mission.clock.now() > 20.0)
    mission.laser.repair()
    mission.until(lambda: mission.pilot == "active.f_normal_mode", limit=5.0)
    mission.world.battery = 0.49
    mission.until(lambda: mission.world.battery == 1.0)
    mission.world.drain_per_metre = 0.0
    mission.until(lambda: mission.root.status is Status.SUCCESS, limit=300.0)
    return story


def _told(now: float, event: Event) -> tuple[float, str, str, str]:
    # request numbers count every request made in the process
    return (round(now, 3), event.kind.value, event.part, re.sub(r"#\d+", "#", str(event)))


def test_the_xml_mission_tells_the_same_story_as_the_python_one() -> None:
    python, xml = _story("pilot"), _story("pilot_xml")
    assert len(python) > 50  # modes changed, a rule fired, recovery and a hold happened
    kinds = {kind for _, kind, _, _ in python}
    assert {"target", "actual", "divergence", "request"} <= kinds
    assert xml == python
