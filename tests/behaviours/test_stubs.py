"""Stubs: what stand-ins do (sm_bt.trees.stubs), read with every mistake's line, and used by the
nodes a tree declares or only names."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from model_files import bundled
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.sim import SimulatedSystem
from sm_bt.trees.mission_xml import check_tree, load_tree
from sm_bt.trees.stubs import Stub, load_stubs

PILOT = bundled("pilot")
TREE = """<root main_tree_to_execute="M">
  <BehaviorTree ID="M">
    <Sequence name="Mission">
      <ChangeMode part="pilot" mode="f_normal_mode" timeout="10"/>
      <FollowPath path="{path}"/>
      <IsStuck/>
    </Sequence>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="FollowPath"><input_port name="path"/></Action>
  </TreeNodesModel>
</root>
"""


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def _files(tmp_path: Path, stubs: str) -> tuple[Path, Path]:
    (tmp_path / "tree.xml").write_text(TREE)
    (tmp_path / "stubs.yaml").write_text(stubs)
    return tmp_path / "tree.xml", tmp_path / "stubs.yaml"


def test_a_stubbed_run_follows_the_stubs_on_the_manager_clock(tmp_path: Path) -> None:
    tree_file, stubs_file = _files(tmp_path, "FollowPath: {status: running, for: 2.0, then: success}\n"
                                             "IsStuck: {status: failure}\n")
    stubs, issues = load_stubs(stubs_file)
    assert issues == [] and stubs["FollowPath"] == Stub(Status.RUNNING, 2.0, Status.SUCCESS, str(stubs_file), 1)
    rig = SimulatedSystem(PILOT, recovery=False)
    root = load_tree(tree_file, manager=rig.manager, stubs=stubs)
    tree = rig.tree(root)
    follow = next(b for b in root.iterate() if b.name == "FollowPath")
    trace = rig.tick_until(tree, lambda: root.status is not Status.RUNNING, watch=follow, step=0.1)
    assert root.status is Status.FAILURE  # IsStuck, only named in the tree and stubbed, fails
    assert follow.feedback_message == f"stand-in for FollowPath ({stubs_file}:1: RUNNING for 2 s, then SUCCESS)"
    began = next(tick.time for tick in trace if tick.status is Status.RUNNING)
    ended = next(tick.time for tick in trace if tick.status is Status.SUCCESS)
    assert 2.0 <= ended - began < 2.15  # its 2 seconds of the manager's (virtual) clock


def test_every_mistake_in_a_stubs_file_has_its_line(tmp_path: Path) -> None:
    path = tmp_path / "stubs.yaml"
    path.write_text("A: {status: sucess}\nB: {status: running, fro: 2}\nC: {status: running, for: -1}\n"
                    "D: {status: running, then: running}\nE: {for: 2}\nF: {status: success, for: 1}\n"
                    "G: success\nA: {status: failure}\n")
    _, issues = load_stubs(path)
    assert [(issue.line, issue.message) for issue in issues] == [
        (1, "A: status must be one of success, failure, running, not 'sucess'"),
        (2, "B: no field 'fro' (did you mean 'for'?) (fields: status, for, then)"),
        (3, "C: for is seconds (0 or more), not '-1'"),
        (4, "D: then must be one of success, failure, not 'running'"),
        (5, "E: give its status (success, failure or running)"),
        (6, "F: for and then go with status running"),
        (7, "G: give {status: success|failure|running[, for: SECONDS, then: success|failure]}"),
    ]
    path.write_text("A: {status: success}\nA: {status: failure}\n")
    assert [str(issue) for issue in load_stubs(path)[1]] == [f"{path}:2: error: A is stubbed twice (first at line 1)"]
    path.write_text("[1, 2")
    assert load_stubs(path)[1][0].message.startswith("not YAML or JSON: ")


def test_a_stub_for_no_node_or_for_one_sm_bt_has_is_an_error(tmp_path: Path) -> None:
    tree_file, stubs_file = _files(tmp_path, "IsStuck: {status: success}\nFollowPth: {status: success}\n"
                                             "ChangeMode: {status: success}\n")
    issues = [str(issue) for issue in check_tree(tree_file, PILOT, stubs=load_stubs(stubs_file)[0])]
    assert issues == [f"{stubs_file}:2: error: stub for FollowPth: FollowPth is no node of the tree",
                      f"{stubs_file}:3: error: stub for ChangeMode: ChangeMode is a node sm_bt has: a stub stands in "
                      "only for nodes it lacks"]
