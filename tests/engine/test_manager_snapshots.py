"""``ModeManager.status``/``snapshot``: one read model of every part, which the monitor, the
blackboard and ``/diagnostics`` render."""

from __future__ import annotations

from sm_bt.engine.events import Cause
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import PartKind
from sm_bt.sim import SimulatedSystem


def test_a_snapshot_holds_every_part_in_the_model_order_as_status_reads_it() -> None:
    pilot = SimulatedSystem("pilot")
    pilot.finish(pilot.manager.change_mode("pilot", "f_normal_mode"))
    snapshot = pilot.manager.snapshot()
    assert [s.part for s in snapshot] == list(pilot.model.parts)
    assert snapshot == [pilot.manager.status(part) for part in pilot.model.parts]
    system = pilot.manager.status("pilot")
    assert (system.kind, system.reachable, system.last_return) == (PartKind.SYSTEM, None, None)
    assert system.target == StateMode(State.ACTIVE, "f_normal_mode") and system.actual.is_(system.target)
    assert system.divergence is None and not system.gave_up
    node = pilot.manager.status("amcl")
    assert (node.kind, node.reachable, node.gone) == (PartKind.NODE, True, "")


def test_a_vanished_node_is_unreachable_with_its_reason_then_back_with_how_it_came_back() -> None:
    pilot = SimulatedSystem("pilot", grace_period=0.5)
    pilot.finish(pilot.manager.change_mode("pilot", "f_normal_mode"))
    pilot.vanish("amcl")
    pilot.run(0.1)
    gone = pilot.manager.status("amcl")
    assert gone.reachable is False and gone.gone
    assert pilot.manager.status("pilot").divergence is not None
    pilot.restart("amcl")
    pilot.run_until(lambda: pilot.manager.status("amcl").reachable is True)
    back = pilot.manager.status("amcl")
    assert back.last_return is not None and back.last_return.node == "amcl"
    assert back.last_return == pilot.manager.last_return("amcl")


def test_a_part_given_up_on_says_so() -> None:
    pilot = SimulatedSystem("pilot", grace_period=0.2, recovery_attempts=1)
    pilot.finish(pilot.manager.change_mode("pilot", "f_normal_mode"))
    pilot.fail("laser_resender")
    pilot.fail_next("laser_resender", Transition.CONFIGURE)  # recovery's one attempt fails
    pilot.run_until(lambda: pilot.manager.status("laser_resender").gave_up, timeout=120.0)
    status = pilot.manager.status("laser_resender")
    assert status.gave_up and status.divergence is not None and status.divergence.cause is Cause.FAULT


def test_an_observed_target_is_shown_and_diverged_from_but_asks_nothing_of_the_nodes() -> None:
    """What a watching manager does with another manager's targets (sm-bt monitor --ros)."""
    watcher = SimulatedSystem("pilot", grace_period=0.5, rules=False, recovery=False)
    calls = len(watcher.backend.events)
    watcher.manager.observe_target("amcl", StateMode(State.ACTIVE, "__DEFAULT__"))
    watcher.run(1.0)
    assert watcher.manager.requests() == []
    assert [e for e in watcher.backend.events[calls:] if e.kind.value == "request"] == []  # no call went out
    status = watcher.manager.status("amcl")
    assert status.target == StateMode(State.ACTIVE, "__DEFAULT__") and status.actual.state is State.UNCONFIGURED
    assert status.divergence is not None and status.divergence.cause is Cause.FAULT  # as the other manager sees it
    watcher.manager.observe_target("amcl", StateMode(State.UNCONFIGURED))
    assert watcher.manager.status("amcl").divergence is None
