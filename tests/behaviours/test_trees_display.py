"""What people see of the shipped trees in dot graphs (``py_trees.display.dot_tree``, what
``py-trees-render`` and ``--dot-graph`` draw): one box per behaviour, no box drawn into another."""

from __future__ import annotations

from collections.abc import Callable

import py_trees
import pytest

from sm_bt.behaviours import hold_mode, switch_on_divergence
from sm_bt.trees import pilot
from sm_bt.trees.pilot import metacontrol as pilot_metacontrol

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning:pydot")  # its parser's pyparsing calls

SHIPPED: dict[str, Callable[[], py_trees.behaviour.Behaviour]] = {
    "pilot": pilot.create_root,
    "metacontrol": pilot_metacontrol.create_root,
}


def _unquoted(name: str) -> str:
    return name[1:-1] if len(name) >= 2 and name[0] == name[-1] == '"' else name


@pytest.mark.parametrize("factory", SHIPPED.values(), ids=SHIPPED.keys())
def test_every_behaviour_is_its_own_box_and_every_edge_joins_two(
        factory: Callable[[], py_trees.behaviour.Behaviour]) -> None:
    root = factory()
    behaviours = list(root.iterate())
    graph = py_trees.display.dot_tree(root)
    source = graph.to_string()
    reparsed = py_trees.display.pydot.graph_from_dot_data(source)[0]  # what graphviz reads back
    nodes = [_unquoted(node.get_name()) for node in reparsed.get_nodes()
             if node.get_name() not in ("node", "edge", "graph")]
    assert len(set(nodes)) == len(behaviours), "two behaviours drawn as one box"
    edges = [(_unquoted(edge.get_source()), _unquoted(edge.get_destination())) for edge in reparsed.get_edges()]
    assert len(edges) == len(behaviours) - 1
    # a name with ':' is written as node:port, so its edge would end on its parent's box
    assert {end for edge in edges for end in edge} <= set(nodes)
    assert all(source != destination for source, destination in edges)
    assert not [b.name for b in behaviours if ":" in b.name]


def test_generated_names_lead_with_the_mode_and_hold_no_colon() -> None:
    held = hold_mode("Survey", "pilot", "f_degraded_mode", py_trees.behaviours.Success("Scan"))
    switch = switch_on_divergence("Laser lost", "laser_resender", "pilot", "f_degraded_mode")
    names = [b.name for b in list(held.iterate()) + list(switch.iterate())]
    assert names == ["Hold f_degraded_mode", "f_degraded_mode reached?", "Scan", "f_degraded_mode work", "Survey",
                     "laser_resender diverged?", "f_degraded_mode on divergence", "Laser lost"]


def test_each_sm_bt_leaf_names_its_part_and_mode_in_its_detail() -> None:
    from sm_bt.behaviours import ManagerBehaviour, ModesToBlackboard

    leaves = [b for b in pilot.create_root().iterate()
              if isinstance(b, ManagerBehaviour) and not isinstance(b, ModesToBlackboard)
              and type(b).__module__.startswith("sm_bt.behaviours")]
    assert leaves
    details = {b.name: b.detail for b in leaves}
    assert details["f_normal_mode"] == "pilot f_normal_mode"
    assert details["Configure"] == "pilot configure"
    assert details["Degraded?"] == "pilot active.f_degraded_mode"
    assert details["laser_resender diverged?"] == "laser_resender"
    assert details["Hold f_energy_saving_mode"] == "pilot f_energy_saving_mode"
    assert all(details.values())
