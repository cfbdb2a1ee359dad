"""BehaviorTree.CPP's and Nav2's control and decorator nodes (sm_bt.trees.bt_cpp_nodes), one by one,
as their documentation describes them: children are scripted leaves, time a fake clock."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import py_trees
import pytest
from model_files import bundled
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.sim import SimulatedSystem
from sm_bt.trees import bt_cpp_nodes
from sm_bt.trees.bt_cpp_nodes import (
    Delay,
    ForceFailure,
    ForceSuccess,
    IfThenElse,
    KeepRunningUntilFailure,
    PipelineSequence,
    RateController,
    RecoveryNode,
    RetryUntilSuccessful,
    RoundRobin,
    WhileDoElse,
)
from sm_bt.trees.mission_xml import check_tree, load_tree

S, F, R = Status.SUCCESS, Status.FAILURE, Status.RUNNING


class Scripted(py_trees.behaviour.Behaviour):
    """Returns its script's statuses one tick after another (the last one for ever); counts its
    ticks and the times it was stopped while running (halted)."""

    def __init__(self, name: str, *script: Status) -> None:
        super().__init__(name)
        self.script = list(script)
        self.ticks = 0
        self.halted = 0

    def update(self) -> Status:
        status = self.script[min(self.ticks, len(self.script) - 1)]
        self.ticks += 1
        return status

    def terminate(self, new_status: Status) -> None:
        if new_status == Status.INVALID and self.status == Status.RUNNING:
            self.halted += 1


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def ticks(node: py_trees.behaviour.Behaviour, count: int) -> list[Status]:
    seen = []
    for _ in range(count):
        node.tick_once()
        seen.append(node.status)
    return seen


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(bt_cpp_nodes.time, "monotonic", fake)
    return fake


# -- controls ---------------------------------------------------------------------------------------


def test_recovery_node_recovers_and_tries_the_work_again_up_to_its_retries() -> None:
    work, recovery = Scripted("work", F, F, S), Scripted("recovery", S)
    node = RecoveryNode("Recover", number_of_retries=2, children=[work, recovery])
    assert ticks(node, 1) == [S]  # work fails, recovery succeeds, work fails, recovery, work succeeds
    assert (work.ticks, recovery.ticks) == (3, 2)

    work, recovery = Scripted("work", F), Scripted("recovery", S)
    node = RecoveryNode("Recover", number_of_retries=1, children=[work, recovery])
    assert ticks(node, 1) == [F] and (work.ticks, recovery.ticks) == (2, 1)  # retries used up

    work, recovery = Scripted("work", F), Scripted("recovery", R, F)
    node = RecoveryNode("Recover", number_of_retries=3, children=[work, recovery])
    assert ticks(node, 2) == [R, F]  # the recovery runs, then fails: FAILURE
    assert work.ticks == 1  # the work was not asked again while the recovery ran

    with pytest.raises(ValueError, match="two children"):
        RecoveryNode("Recover", children=[Scripted("only", S)])


def test_pipeline_sequence_keeps_earlier_children_running_while_later_ones_tick() -> None:
    first, second, third = Scripted("first", S, R, R), Scripted("second", R, S), Scripted("third", S)
    node = PipelineSequence("Pipeline", children=[first, second, third])
    assert ticks(node, 2) == [R, S]
    assert (first.ticks, second.ticks, third.ticks) == (2, 2, 1)  # third ran while first was RUNNING
    assert first.halted == 1  # still running when the pipeline ended: halted

    first, second = Scripted("first", R), Scripted("second", S)
    node = PipelineSequence("Pipeline", children=[first, second])
    assert ticks(node, 2) == [R, R] and second.ticks == 0  # the furthest child runs: nothing after it

    first, second = Scripted("first", S, F), Scripted("second", R)
    node = PipelineSequence("Pipeline", children=[first, second])
    assert ticks(node, 2) == [R, F] and second.halted == 1  # a failure ends it and halts the rest


def test_round_robin_moves_on_after_each_end_and_fails_when_all_failed_in_turn() -> None:
    a, b, c = Scripted("a", F), Scripted("b", S), Scripted("c", R, S)
    node = RoundRobin("Round", children=[a, b, c])
    assert ticks(node, 1) == [S] and (a.ticks, b.ticks, c.ticks) == (1, 1, 0)  # a failed, b succeeded
    assert ticks(node, 2) == [R, S] and c.ticks == 2  # then c's turn
    assert ticks(node, 1) == [S] and (a.ticks, b.ticks) == (2, 2)  # round again: a fails, b succeeds

    a, b = Scripted("a", F), Scripted("b", R, F)
    node = RoundRobin("Round", children=[a, b])
    assert ticks(node, 2) == [R, F] and a.ticks == 1  # b failed after a had: every child failed in turn


def test_if_then_else_chooses_once_and_runs_the_branch_to_its_end() -> None:
    condition, then, otherwise = Scripted("if", S, F), Scripted("then", R, S), Scripted("else", S)
    node = IfThenElse("If", children=[condition, then, otherwise])
    assert ticks(node, 2) == [R, S] and condition.ticks == 1 and otherwise.ticks == 0
    assert ticks(node, 1) == [S] and otherwise.ticks == 1  # a new run asks the condition again: FAILURE

    node = IfThenElse("If", children=[Scripted("if", F), Scripted("then", S)])
    assert ticks(node, 1) == [F]  # no else: FAILURE
    with pytest.raises(ValueError, match="2 or 3 children"):
        IfThenElse("If", children=[Scripted("if", S)])


def test_while_do_else_asks_the_condition_every_tick_and_halts_the_branch_it_leaves() -> None:
    condition, do, otherwise = Scripted("while", S, S, F), Scripted("do", R), Scripted("else", R)
    node = WhileDoElse("While", children=[condition, do, otherwise])
    assert ticks(node, 3) == [R, R, R]
    assert condition.ticks == 3 and do.ticks == 2 and otherwise.ticks == 1
    assert do.halted == 1  # the condition turned: the running branch was halted

    node = WhileDoElse("While", children=[Scripted("while", F), Scripted("do", S)])
    assert ticks(node, 1) == [F]


# -- decorators -------------------------------------------------------------------------------------


@pytest.mark.parametrize(("cls", "script", "expected"), [
    (ForceSuccess, [R, F], [R, S]), (ForceSuccess, [S], [S]),
    (ForceFailure, [R, S], [R, F]), (ForceFailure, [F], [F]),
    (KeepRunningUntilFailure, [S, R, S, F], [R, R, R, F]),
    (py_trees.decorators.Inverter, [R, S], [R, F]), (py_trees.decorators.Inverter, [F], [S]),
])
def test_force_and_keep_running_decorators(cls: type, script: list[Status], expected: list[Status]) -> None:
    child = Scripted("child", *script)
    assert ticks(cls("Decorated", child=child), len(expected)) == expected
    assert child.ticks == len(expected)


def test_retry_until_successful_ticks_again_in_the_same_tick_up_to_its_attempts() -> None:
    child = Scripted("child", F, F, S)
    assert ticks(RetryUntilSuccessful("Retry", child=child, num_attempts=3), 1) == [S] and child.ticks == 3
    child = Scripted("child", F)
    assert ticks(RetryUntilSuccessful("Retry", child=child, num_attempts=2), 1) == [F] and child.ticks == 2
    child = Scripted("child", R, S)
    assert ticks(RetryUntilSuccessful("Retry", child=child, num_attempts="4"), 2) == [R, S]  # as XML gives it
    with pytest.raises(ValueError, match="num_attempts must be a whole number"):
        RetryUntilSuccessful("Retry", child=child, num_attempts="many")


def test_delay_waits_without_ticking_the_child(clock: FakeClock) -> None:
    child = Scripted("child", S)
    node = Delay("Delay", child=child, delay_msec=500)
    assert ticks(node, 1) == [R] and child.ticks == 0
    clock.now = 0.4
    assert ticks(node, 1) == [R] and child.ticks == 0
    clock.now = 0.5
    assert ticks(node, 1) == [S] and child.ticks == 1


def test_rate_controller_ticks_the_child_at_most_hz_times_a_second(clock: FakeClock) -> None:
    child = Scripted("child", S)
    node = RateController("Rate", child=child, hz=2.0)
    assert ticks(node, 1) == [S] and child.ticks == 1  # the first tick ticks it
    clock.now = 0.2
    assert ticks(node, 1) == [R] and child.ticks == 1  # within the period: RUNNING, not ticked
    clock.now = 0.5
    assert ticks(node, 1) == [S] and child.ticks == 2
    running = Scripted("child", R, R, S)
    node = RateController("Rate", child=running, hz=1.0)
    assert ticks(node, 3) == [R, R, S] and running.ticks == 3  # a running child is ticked every tick


# -- in tree files ----------------------------------------------------------------------------------

NAV = """<root main_tree_to_execute="MainTree" BTCPP_format="4">
  <!-- sm_bt model: pilot -->
  <BehaviorTree ID="MainTree">
    <RecoveryNode number_of_retries="2" name="NavigateRecovery">
      <PipelineSequence name="NavigateWithReplanning">
        <RateController hz="1.0">
          <ComputePathToPose goal="{goal}" path="{path}"/>
        </RateController>
        <ChangeMode part="pilot" mode="f_normal_mode" timeout="10"/>
        <ForceSuccess><FollowPath path="{path}"/></ForceSuccess>
      </PipelineSequence>
      <RoundRobin name="Recoveries">
        <RetryUntilSuccessful num_attempts="2"><AlwaysSuccess/></RetryUntilSuccessful>
        <Delay delay_msec="0"><AlwaysSuccess/></Delay>
      </RoundRobin>
    </RecoveryNode>
  </BehaviorTree>
  <TreeNodesModel>
    <Action ID="ComputePathToPose"><input_port name="goal"/><output_port name="path"/></Action>
    <Action ID="FollowPath"><input_port name="path"/></Action>
  </TreeNodesModel>
</root>
"""


def test_a_nav2_style_tree_loads_checks_and_runs_with_sm_bt_behaviours(tmp_path: Path) -> None:
    path = tmp_path / "nav.xml"
    path.write_text(NAV)
    rig = SimulatedSystem(bundled("pilot"), recovery=False)
    assert check_tree(path, rig.model) == []
    root = load_tree(path, manager=rig.manager)
    assert type(root).__name__ == "RecoveryNode" and root.name == "NavigateRecovery"
    tree = rig.tree(root)
    rig.tick_until(tree, lambda: root.status is Status.SUCCESS)
    assert str(rig.manager.actual("pilot")) == "active.f_normal_mode"


def test_a_bad_attribute_of_a_bt_cpp_node_is_an_error_with_its_line(tmp_path: Path) -> None:
    path = tmp_path / "nav.xml"
    path.write_text(NAV.replace('number_of_retries="2"', 'number_of_retries="two"').replace('hz="1.0"', 'hz="0"'))
    assert [str(issue) for issue in check_tree(path, bundled("pilot"))] == [
        f"{path}:4: error: <RecoveryNode 'NavigateRecovery'>: number_of_retries must be a whole number, not 'two'",
        f"{path}:6: error: <RateController 'RateController'>: hz must be more than 0, not 0.0"]


def test_an_inverter_in_xml_is_py_trees_inverter_around_its_child(tmp_path: Path) -> None:
    path = tmp_path / "inverted.xml"
    path.write_text('<root main_tree_to_execute="M"><BehaviorTree ID="M">'
                    '<Inverter name="Not"><Work/></Inverter></BehaviorTree></root>')
    from sm_bt.trees.stubs import Stub

    root = load_tree(path, stubs={"Work": Stub(R, 1.0, F)})
    assert isinstance(root, py_trees.decorators.Inverter) and root.name == "Not"
    tree = py_trees.trees.BehaviourTree(root)
    clock = FakeClock()
    tree.setup(clock=type("C", (), {"now": staticmethod(clock)})())
    tree.tick()
    assert root.status is R
    clock.now = 1.5
    tree.tick()
    assert root.status is S  # the stand-in failed after its second of RUNNING


def test_delay_and_rate_controller_keep_the_trees_clock_a_virtual_one_too(tmp_path: Path) -> None:
    """A run on simulated nodes passes its virtual clock: a Delay of 2 s ends after 2 s of it
    (regression: it waited 2 s of the wall clock, while the virtual one ran on for hours)."""
    path = tmp_path / "delayed.xml"
    path.write_text('<root main_tree_to_execute="M"><BehaviorTree ID="M">'
                    '<Delay delay_msec="2000"><AlwaysSuccess/></Delay></BehaviorTree></root>')
    rig = SimulatedSystem(bundled("pilot"))
    root = load_tree(path, manager=rig.manager)
    ticks = rig.tick_until_done(rig.tree(root), step=0.1, timeout=5.0)
    assert ticks[-1].status is S and 2.0 <= ticks[-1].time <= 2.1
