"""How behaviours reach the manager: their own ``manager=``, ``attach_manager`` on a subtree,
``setup(manager=...)``; including where ``setup`` gets no keyword arguments (py_trees'
``setup_with_descendants()``, hosts that do not forward them) and subtrees inserted while the
tree runs."""

from __future__ import annotations

from collections.abc import Iterator

import py_trees
import pytest
from model_files import bundled
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.behaviours import ChangeMode, ModeIs, ModesToBlackboard, NotSetUp, OnDivergence, attach_manager, hold_mode
from sm_bt.model.states import State
from sm_bt.sim import SimulatedSystem


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


@pytest.fixture
def rig() -> SimulatedSystem:
    return SimulatedSystem(bundled("pilot"), recovery=False)


class _NoKwargsTree(py_trees.trees.BehaviourTree):
    """A host whose ``setup`` takes no keyword arguments for the behaviours (py_trees_ros 2.2)."""

    def setup(self, timeout: float = py_trees.common.Duration.INFINITE, visitor: object = None) -> None:  # type: ignore[override]
        super().setup(timeout=timeout)


def test_a_behaviour_given_its_manager_needs_no_setup_kwargs(rig: SimulatedSystem) -> None:
    tree = _NoKwargsTree(ChangeMode("Normal", "pilot", "f_normal_mode", manager=rig.manager))
    tree.setup()
    trace = rig.tick_until(tree, lambda: tree.root.status is Status.SUCCESS)
    assert trace[0].status is Status.RUNNING
    assert rig.manager.actual("pilot").state is State.ACTIVE


def test_a_manager_attached_after_setup_serves_the_whole_tree(rig: SimulatedSystem) -> None:
    """py_trees_ros' order: the tree is set up first (that makes its node), the runtime on that node
    comes next, and only then its manager can be attached; the first tick finds and checks it."""
    root = py_trees.composites.Sequence("Mission", memory=True, children=[
        ModesToBlackboard(), ChangeMode("Normal", "pilot", "f_normal_mode"),
        ModeIs("Normal?", "pilot", "f_normal_mode")])
    tree = _NoKwargsTree(root)
    tree.setup()
    attach_manager(root, rig.manager)
    rig.tick_until(tree, lambda: root.status is Status.SUCCESS)
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"
    tree.tick()  # the blackboard holds every part of the model, although setup could not name them
    assert str(py_trees.blackboard.Blackboard.get("/system_modes/pilot")) == \
        "active.f_normal_mode (target active.f_normal_mode)"
    assert len(root.children[0].blackboard.write) == len(rig.manager.model.parts)


def test_a_typo_in_a_tree_set_up_before_its_manager_fails_at_the_first_tick(rig: SimulatedSystem) -> None:
    root = ChangeMode("Normal", "pilot", "f_nromal_mode")
    tree = _NoKwargsTree(root)
    tree.setup()
    attach_manager(root, rig.manager)
    with pytest.raises(ValueError, match="f_normal_mode"):
        tree.tick()


def test_attach_manager_reaches_every_behaviour_of_the_subtree_through_setup_with_descendants(
        rig: SimulatedSystem) -> None:
    root = py_trees.composites.Sequence("Mission", memory=True, children=[
        ChangeMode("Normal", "pilot", "f_normal_mode"),
        ModeIs("Normal?", "pilot", "f_normal_mode"),
    ])
    assert attach_manager(root, rig.manager) is root
    root.setup_with_descendants()
    tree = py_trees.trees.BehaviourTree(root)
    rig.tick_until(tree, lambda: root.status is Status.SUCCESS)
    assert [child.status for child in root.children] == [Status.SUCCESS, Status.SUCCESS]


def test_a_subtree_inserted_while_the_tree_runs_finds_the_manager_without_setup(rig: SimulatedSystem) -> None:
    root = py_trees.composites.Sequence("Mission", memory=False, children=[
        py_trees.behaviours.Success("Warm up"),
    ])
    tree = _NoKwargsTree(attach_manager(root, rig.manager))
    tree.setup()
    tree.tick()
    inserted = hold_mode("Survey", "pilot", "f_degraded_mode", py_trees.behaviours.Running("Scan"))
    tree.insert_subtree(inserted, root.id, 1)  # never set up: the manager is found through the parents
    rig.tick_until(tree, lambda: rig.manager.actual("pilot").mode == "f_degraded_mode")
    assert inserted.status is Status.RUNNING


def test_an_own_manager_wins_over_an_attached_one_which_wins_over_setup(rig: SimulatedSystem) -> None:
    other, third = SimulatedSystem(bundled("pilot"), recovery=False), SimulatedSystem(bundled("pilot"), recovery=False)
    own = ModeIs("Own", "pilot", "f_normal_mode", manager=other.manager)
    attached = ModeIs("Attached", "pilot", "f_normal_mode")
    subtree = attach_manager(py_trees.composites.Sequence("Sub", memory=False, children=[own, attached]),
                             rig.manager)
    plain = ModeIs("Plain", "pilot", "f_normal_mode")
    tree = py_trees.trees.BehaviourTree(py_trees.composites.Parallel(
        "Root", policy=py_trees.common.ParallelPolicy.SuccessOnAll(), children=[subtree, plain]))
    tree.setup(manager=third.manager)
    assert (own.manager, attached.manager, plain.manager) == (other.manager, rig.manager, third.manager)


def test_without_any_manager_the_error_says_the_three_ways() -> None:
    behaviour = OnDivergence("Diverges?", "pilot")
    behaviour.setup_with_descendants()
    with pytest.raises(NotSetUp) as raised:
        behaviour.tick_once()
    message = str(raised.value)
    for way in ("attach_manager(root, manager)", "tree.setup(manager=manager)", "manager= argument"):
        assert way in message


def test_an_attached_manager_of_the_wrong_type_is_refused_at_once() -> None:
    with pytest.raises(TypeError, match="manager= must be a ModeManager, not str"):
        attach_manager(py_trees.behaviours.Success("Root"), "pilot")  # type: ignore[arg-type]


def test_an_unknown_mode_found_late_is_the_usual_error_at_the_first_tick(rig: SimulatedSystem) -> None:
    root = attach_manager(py_trees.composites.Sequence("Mission", memory=True, children=[]), rig.manager)
    tree = py_trees.trees.BehaviourTree(root)
    tree.setup()
    tree.insert_subtree(ModeIs("Typo?", "pilot", "f_nromal_mode"), root.id, 0)
    with pytest.raises(ValueError, match=r"pilot has no mode 'f_nromal_mode' \(did you mean 'f_normal_mode'\?\) "
                                         r"\(modes: .*f_normal_mode"):
        tree.tick()
