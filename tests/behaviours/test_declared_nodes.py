"""Node types declared in a tree file's ``<TreeNodesModel>`` (Groot2's palette): their ports are
checked like any node's, and declared Actions and Conditions sm_bt has no class for run as
stand-ins, so that a mission written for a robot's own nodes loads and runs."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import py_trees
import pytest
from model_files import bundled
from py_trees.common import Status
from py_trees.ports import get_ports_registry
from tree_helpers import fresh_blackboard

from sm_bt.sim import SimulatedSystem
from sm_bt.trees.mission_xml import TreeFileError, check_tree, load_tree

PILOT = bundled("pilot")

NAV = """<root main_tree_to_execute="MainTree" BTCPP_format="4">
  <BehaviorTree ID="MainTree">
    <Sequence name="Navigate">
      <ChangeMode part="pilot" mode="f_normal_mode" timeout="10"/>
      <IsBatteryOk min="0.5"/>
      <ComputePathToPose goal="{{goal}}" path="{{path}}" planner_id="GridBased"/>
      {follow}
    </Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="ComputePathToPose">
      <input_port name="goal"/>
      <output_port name="path"/>
      <input_port name="planner_id"/>
    </Action>
    <Action ID="FollowPath">
      <input_port name="path"/>
      <input_port name="controller_id"/>
    </Action>
    <Condition ID="IsBatteryOk"><input_port name="min"/></Condition>
    <Decorator ID="DistanceController"><input_port name="distance"/></Decorator>
    <Action ID="ModeIs"><input_port name="part"/></Action>
  </TreeNodesModel>
</root>
"""
FOLLOW = '<FollowPath path="{path}" controller_id="FollowPath"/>'


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def _write(tmp_path: Path, follow: str = FOLLOW) -> Path:
    path = tmp_path / "nav.xml"
    path.write_text(NAV.format(follow=follow))
    return path


def test_declared_actions_and_conditions_run_as_stand_ins_with_sm_bt_behaviours(tmp_path: Path) -> None:
    rig = SimulatedSystem(PILOT, recovery=False)
    root = load_tree(_write(tmp_path), manager=rig.manager)
    tree = rig.tree(root)
    rig.tick_until(tree, lambda: root.status is Status.SUCCESS)
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"  # the sm_bt node did its part
    names = {b.name: b for b in root.iterate()}
    declared_at = f"{tmp_path / 'nav.xml'}:16"
    assert names["FollowPath"].feedback_message == f"stand-in for Action FollowPath (declared at {declared_at})"
    assert names["IsBatteryOk"].feedback_message.startswith("stand-in for Condition IsBatteryOk")
    assert py_trees.blackboard.Blackboard.keys() == set()  # a stand-in's ports touch no key
    # The declaration holds for its file only (a stand-in class in py_trees' registry made every
    # later tree accept <FollowPath>).
    assert "FollowPath" not in get_ports_registry()


def test_a_declared_nodes_attributes_are_its_declared_ports(tmp_path: Path) -> None:
    issues = [str(issue) for issue in check_tree(_write(tmp_path, FOLLOW.replace("controller_id", "controler_id")),
                                                 PILOT)]
    assert issues == [f"{tmp_path / 'nav.xml'}:7: error: <FollowPath> has no attribute 'controler_id' (did you "
                      "mean 'controller_id'?) (attributes: controller_id, name, path)"]


def test_a_declared_decorator_needs_a_class_and_a_class_wins_over_a_declaration(tmp_path: Path) -> None:
    path = _write(tmp_path, FOLLOW + '<DistanceController distance="1.0"><AlwaysSuccess/></DistanceController>'
                                     '<ModeIs part="pilot" mode="f_normal_mode"/>')
    with pytest.raises(TreeFileError) as raised:
        load_tree(path, model=PILOT)
    # ModeIs is sm_bt's own (declared here as an Action with other ports): its class is used, no error.
    assert [str(issue) for issue in raised.value.issues] == [
        f"{path}:7: error: <DistanceController> is declared a Decorator ({path}:21): only declared Actions and "
        "Conditions run as stand-ins; a class for it is needed (registry=)"]
