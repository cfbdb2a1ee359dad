"""Mission trees from XML: what loads, and every mistake as an error with the file and line."""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import py_trees
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_files import bundled
from py_trees.common import Status
from tree_helpers import fresh_blackboard

from sm_bt.behaviours import ChangeMode, OnDivergence
from sm_bt.engine.lifecycle import Outcome, Transition
from sm_bt.sim import SimulatedSystem
from sm_bt.trees import pilot
from sm_bt.trees.mission_xml import MAX_DEPTH, TreeFileError, check_tree, load_tree

PILOT = bundled("pilot")


@pytest.fixture(autouse=True)
def blackboard() -> Iterator[None]:
    yield from fresh_blackboard()


def _tree(body: str, *, extra: str = "") -> str:
    return (f'<root main_tree_to_execute="Main">\n  <BehaviorTree ID="Main">\n{body}\n  </BehaviorTree>\n'
            f"{extra}</root>\n")


def _write(tmp_path: Path, text: str, name: str = "mission.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _errors(path: Path) -> list[str]:
    with pytest.raises(TreeFileError) as raised:
        load_tree(path, model=PILOT)
    return str(raised.value).splitlines()


# Each mistake on line 4 of the file (inside a Sequence on line 3).
MISTAKES = {
    "unknown node": ('<WaitForMod part="pilot" mode="f_normal_mode"/>', "unknown node <WaitForMod> (did you mean "
                                                                         "'WaitForMode'?)"),
    "unknown attribute": ('<ModeIs part="pilot" mdoe="f_normal_mode"/>',
                          "<ModeIs> has no attribute 'mdoe' (did you mean 'mode'?)"),
    "missing attribute": ('<ChangeMode part="pilot"/>', "<ChangeMode> needs mode"),
    "unknown part": ('<ChangeMode name="Go" part="pilto" mode="f_normal_mode"/>',
                     "<ChangeMode 'Go'>: unknown part 'pilto' (did you mean 'pilot'?) (parts: pilot,"),
    "unknown mode": ('<WaitForMode name="W" part="pilot" mode="f_nromal_mode"/>',
                     ("<WaitForMode 'W'>: pilot has no mode 'f_nromal_mode' (did you mean 'f_normal_mode'?) "
                      "(modes: __DEFAULT__,")),
    "unknown transition": ('<ChangeState name="C" part="pilot" transition="confgure"/>',
                           "<ChangeState 'C'>: cannot request transition 'confgure' (one of: configure,"),
    "bad timeout": ('<ChangeMode name="Go" part="pilot" mode="f_normal_mode" timeout="ten"/>',
                    "<ChangeMode 'Go'>: timeout must be a number of seconds, not 'ten'"),
    "negative timeout": ('<WaitForMode name="W" part="pilot" mode="f_normal_mode" timeout="-1"/>',
                         "<WaitForMode 'W'>: timeout must be positive, not -1"),
    "key on a fixed attribute": ('<ChangeMode part="pilot" mode="{next_mode}"/>',
                                 "mode='{next_mode}': only ports take blackboard keys"),
    "unknown subtree": ('<SubTree ID="Recharge"/>', "no tree 'Recharge'"),
    "bad decorator argument": ('<Repeat num_success="two"><Success/></Repeat>', "num_success='two' is not a whole"),
    "decorator without a child": ("<Inverter/>", "<Inverter> decorates exactly one child, not 0"),
    "hold of a bad mode": ('<HoldMode name="H" part="pilot" mode="f_bogus"><Success/></HoldMode>',
                           "<HoldMode 'H'>: pilot has no mode 'f_bogus'"),
    "hold of two children": ('<HoldMode name="H" part="pilot" mode="f_slow_mode"><Success/><Success/></HoldMode>',
                             "HoldMode holds its mode while exactly one child runs, not 2"),
    "bad port": ('<OnDivergence part="pilot" divergnce="{fault}"/>', "<OnDivergence> has no attribute 'divergnce'"),
    "malformed reference": ('<ChangeMode part="pilot" mode="f_slow_mode}"/>',
                            "mode='f_slow_mode}': a blackboard reference is a whole value, {key}"),
    "malformed port reference": ('<OnDivergence part="pilot" divergence="x{fault}"/>',
                                 "divergence='x{fault}': a blackboard reference is a whole value"),
    "bad parallel policy": ('<Parallel policy="success_on_selected"><Success/></Parallel>',
                            "policy must be one of success_on_all, success_on_one"),
}


@pytest.mark.parametrize("mistake", MISTAKES, ids=list(MISTAKES))
def test_a_mistake_is_an_error_with_file_and_line(tmp_path: Path, mistake: str) -> None:
    node, message = MISTAKES[mistake]
    path = _write(tmp_path, _tree(f'    <Sequence name="Mission">\n      {node}\n    </Sequence>'))
    errors = _errors(path)
    assert len(errors) == 1, errors
    assert errors[0].startswith(f"{path}:4: error: "), errors
    assert message in errors[0], errors


def test_every_mistake_is_reported_at_once(tmp_path: Path) -> None:
    body = "\n".join(f"      {node}" for node, _ in MISTAKES.values())
    path = _write(tmp_path, _tree(f'    <Sequence name="Mission" memory="maybe">\n{body}\n    </Sequence>'))
    errors = _errors(path)
    assert errors[0] == f"{path}:3: error: memory must be true or false, not 'maybe'"
    lines = [int(error.split(":")[1]) for error in errors[1:]]
    assert lines == list(range(4, 4 + len(MISTAKES)))


@pytest.mark.parametrize(("text", "line", "message"), [
    ('<root>\n  <BehaviorTree ID="Main">\n    <Sequence>\n  </BehaviorTree>\n</root>', 4,
     "not well-formed XML: mismatched tag (column 5)"),
    ("", 1, "not well-formed XML: no element found"),
    ('<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">]>\n<root/>', 2, "a DOCTYPE"),
    ('<root>\n  <Sequence/>\n</root>', 2, "<Sequence> at the top level: expected <BehaviorTree ID=...>"),
    ('<root main_tree_to_execute="Mian">\n  <BehaviorTree ID="Main"><Success/></BehaviorTree>\n</root>', 1,
     "no tree 'Mian' to execute (did you mean 'Main'?)"),
    ('<root>\n  <BehaviorTree ID="A"><Success/></BehaviorTree>\n  <BehaviorTree ID="B"><Success/></BehaviorTree>'
     '\n</root>', 1, "which tree is the main one? set main_tree_to_execute=\"ID\" (trees: A, B)"),
    ('<root>\n  <BehaviorTree ID="A"><Success/></BehaviorTree>\n  <BehaviorTree ID="A"><Failure/></BehaviorTree>'
     '\n</root>', 3, "tree 'A' is defined twice"),
    ('<root>\n  <BehaviorTree ID="A"><Success/><Failure/></BehaviorTree>\n</root>', 2,
     "must hold exactly one node, not 2"),
    ('<root>\n  <Import src="missing.xml"/>\n  <BehaviorTree ID="A"><Success/></BehaviorTree>\n</root>', 2,
     "cannot import missing.xml: no file"),
    ('<root>\n  <Include file="mission.xml"/>\n  <BehaviorTree ID="A"><Success/></BehaviorTree>\n</root>', 2,
     "mission.xml imports itself"),
])
def test_a_broken_file_is_an_error_with_its_line(tmp_path: Path, text: str, line: int, message: str) -> None:
    path = _write(tmp_path, text)
    errors = _errors(path)
    assert errors[0].startswith(f"{path}:{line}: error: "), errors
    assert message in errors[0], errors


def test_nesting_beyond_the_limit_is_refused_at_its_line(tmp_path: Path) -> None:
    depth = MAX_DEPTH + 50
    body = "<Sequence>" * depth + "<Success/>" + "</Sequence>" * depth
    path = _write(tmp_path, '<root>\n<BehaviorTree ID="A">\n' + body + "\n</BehaviorTree>\n</root>")
    assert _errors(path) == [f"{path}:3: error: nested more than {MAX_DEPTH} deep"]


def test_an_unreadable_file_is_an_error_naming_it(tmp_path: Path) -> None:
    assert check_tree(tmp_path / "nope.xml", PILOT)[0].message.startswith("cannot read it")


def test_an_error_in_an_imported_file_names_that_file(tmp_path: Path) -> None:
    _write(tmp_path, '<root>\n  <BehaviorTree ID="Sub">\n    <ModeIs part="pilot" mode="nope"/>\n'
                     "  </BehaviorTree>\n</root>", "sub.xml")
    main = _write(tmp_path, '<root main_tree_to_execute="Main">\n  <Import src="sub.xml"/>\n'
                            '  <BehaviorTree ID="Main"><SubTree ID="Sub"/></BehaviorTree>\n</root>')
    errors = _errors(main)
    assert errors == [f"{tmp_path / 'sub.xml'}:3: error: <ModeIs 'ModeIs'>: pilot has no mode 'nope' (modes: "
                      "__DEFAULT__, f_degraded_mode, f_energy_saving_mode, f_normal_mode, f_performance_mode, "
                      "f_slow_mode)"]


def test_the_shipped_pilot_xml_checks_clean_and_names_nodes_as_written() -> None:
    assert check_tree(pilot.XML, PILOT) == []
    root = load_tree(pilot.XML)
    names = [b.name for b in root.iterate()]
    assert "Laser lost" in names and "To wp_7" in names and "Hold f_energy_saving_mode" in names
    assert not [name for name in names if "." in name or ":" in name]


def test_a_loaded_tree_runs_with_its_manager_attached(tmp_path: Path) -> None:
    rig = SimulatedSystem(PILOT, recovery=False, grace_period=0.5)
    path = _write(tmp_path, _tree(
        '    <Sequence name="Mission">\n'
        '      <ChangeState name="Configure" part="pilot" transition="configure"/>\n'
        '      <ChangeMode name="Normal" part="pilot" mode="f_normal_mode" timeout="10"/>\n'
        '      <FailureIsRunning name="Until diverged">\n'
        '        <OnDivergence name="Diverged?" part="laser_resender" divergence="{fault}"/>\n'
        "      </FailureIsRunning>\n"
        "    </Sequence>"))
    root = load_tree(path, manager=rig.manager)
    tree = py_trees.trees.BehaviourTree(root)
    tree.setup()  # no manager= here: load_tree attached it
    rig.tick_until(tree, lambda: root.children[1].status is Status.SUCCESS)
    check = next(b for b in root.iterate() if isinstance(b, OnDivergence))
    assert check.blackboard.remappings == {"/divergence": "/fault"}
    rig.backend.trigger("laser_resender", Transition.DEACTIVATE, outcome=Outcome.ERROR)
    rig.tick_until(tree, lambda: root.status is Status.SUCCESS)
    assert py_trees.blackboard.Blackboard.get("/fault").part == "laser_resender"


def test_behaviortree_cpp_spellings_are_read(tmp_path: Path) -> None:
    path = _write(tmp_path, _tree(
        '    <ReactiveSequence name="R">\n'
        '      <Repeat num_cycles="3"><Success/></Repeat>\n'
        '      <Timeout msec="1500"><ReactiveFallback><Failure/><Running/></ReactiveFallback></Timeout>\n'
        "    </ReactiveSequence>"))
    root = load_tree(path)
    repeat, timeout = root.children
    assert isinstance(root, py_trees.composites.Sequence) and root.memory is False
    assert isinstance(repeat, py_trees.decorators.Repeat) and repeat.num_success == 3
    assert isinstance(timeout, py_trees.decorators.Timeout) and timeout.duration == pytest.approx(1.5)
    assert timeout.decorated.memory is False


def test_py_trees_own_parser_builds_sm_bt_behaviours(tmp_path: Path) -> None:
    from py_trees.parsers.behaviour_tree_xml import parse_behaviour_tree_xml

    path = _write(tmp_path, _tree('    <ChangeMode name="Go" part="pilot" mode="f_slow_mode" timeout="3"/>'))
    node = parse_behaviour_tree_xml(str(path))
    assert isinstance(node, ChangeMode) and (node.part, node.mode, node.timeout) == ("pilot", "f_slow_mode", 3.0)


@examples(150)
@given(data=st.data())
def test_a_mangled_pilot_xml_loads_or_is_an_error_never_a_crash(data: st.DataObject) -> None:
    text = bytearray(pilot.XML.read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(text) - 1))
        action = data.draw(st.sampled_from(["flip", "drop", "cut", "dup", "insert"]))
        if action == "insert":  # the characters XML and py_trees' references care about
            text[at:at] = data.draw(st.sampled_from([b"{", b"}", b"{x}", b"{}", b'"', b"<", b"&", b"/>"]))
        elif action == "flip":
            text[at] = data.draw(st.integers(0, 255))
        elif action == "drop":
            del text[at:at + data.draw(st.integers(1, 40))]
        elif action == "cut":
            del text[at:]
        else:
            text[at:at] = text[at:at + data.draw(st.integers(1, 200))]
        if not text:
            text = bytearray(b"<")
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "mangled.xml"
        path.write_bytes(bytes(text))
        try:
            load_tree(path, model=PILOT)
        except TreeFileError as error:
            assert error.issues and all(issue.line >= 0 for issue in error.issues)
            assert all(str(issue).startswith(str(path)) for issue in error.issues)


def test_regression_a_cut_reference_in_a_decorator_is_an_error_not_a_crash(tmp_path: Path) -> None:
    """Found by the fuzz test: four bytes dropped from trees/pilot/pilot.xml left num_success="les}",
    which py_trees' parser raised ValueError on."""
    text = pilot.XML.read_bytes()
    at = text.index(b"{cycles}")
    path = tmp_path / "cut.xml"
    path.write_bytes(text[:at] + text[at + 4:])
    errors = _errors(path)
    line = text[:at].count(b"\n") + 1
    assert errors == [f"{path}:{line}: error: num_success='les}}': a blackboard reference is a whole value, {{key}}"]


def test_every_unknown_node_is_listed_with_its_line_in_one_run(tmp_path: Path) -> None:
    """A Nav2 tree: its nodes nest, and those below an unknown one were never looked at (only the
    outer node was reported); a known node below them is still checked against the model."""
    path = tmp_path / "nav.xml"
    path.write_text('<root main_tree_to_execute="MainTree">\n  <BehaviorTree ID="MainTree">\n'
                    '    <GoalUpdater>\n      <SpeedController>\n'
                    '        <ComputePathToPose goal="{goal}" path="{path}"/>\n'
                    '        <ModeIs part="pilto" mode="f_normal_mode"/>\n'
                    '      </SpeedController>\n      <FollowPath path="{path}"/>\n'
                    '    </GoalUpdater>\n  </BehaviorTree>\n</root>\n')
    errors = _errors(path)
    assert [(error.split(":")[1], error.split("<")[1].split(">")[0].split(" ")[0]) for error in errors] == [
        ("3", "GoalUpdater"), ("4", "SpeedController"), ("5", "ComputePathToPose"), ("6", "ModeIs"),
        ("8", "FollowPath")], errors
    assert "unknown part 'pilto'" in errors[3]
