"""Remote parts (``type: remote``): a part another manager serves, a node to this one; and every
mistake in one answered with its line and what to write."""

from __future__ import annotations

import pytest

from sm_bt.model import ModelError, NodePart, SystemPart, load_model_text
from sm_bt.model.types import REMOTE_MODE, Remote

FLEET = """\
fleet:
  ros__parameters:
    type: system
    parts: [robot1, robot2]
    modes:
      __DEFAULT__:
        robot1: active
        robot2: active
      NIGHT:
        robot1: active.f_energy_saving_mode
        robot2: inactive
robot1:
  ros__parameters:
    type: remote
    manager: /robot1
    system: pilot
    modes: [__DEFAULT__, f_energy_saving_mode]
robot2:
  ros__parameters:
    type: remote
{robot2}
"""
ROBOT2 = "    modes: [__DEFAULT__, f_energy_saving_mode]\n"


def errors_of(text: str) -> list[str]:
    with pytest.raises(ModelError) as caught:
        load_model_text(text, "fleet.yaml")
    return [f"{issue.location.line}: {issue.message}" for issue in caught.value.issues]


def test_a_remote_part_is_a_node_whose_one_parameter_is_its_mode() -> None:
    model = load_model_text(FLEET.format(robot2=ROBOT2))
    robot1, robot2 = model.parts["robot1"], model.parts["robot2"]
    assert isinstance(robot1, NodePart) and isinstance(robot2, NodePart)
    assert robot1.remote == Remote("/robot1", "pilot") and robot1.remote.fqn == "/robot1/pilot"
    assert robot2.remote == Remote("", "robot2") and robot2.remote.fqn == "/robot2"  # the root, its own name
    assert list(robot1.modes) == ["__DEFAULT__", "f_energy_saving_mode"] and robot1.default_mode == "__DEFAULT__"
    assert {name: {p: s.value for p, s in mode.parameters.items()} for name, mode in robot1.modes.items()} == {
        "__DEFAULT__": {REMOTE_MODE: "__DEFAULT__"}, "f_energy_saving_mode": {REMOTE_MODE: "f_energy_saving_mode"}}
    assert robot1.modes["f_energy_saving_mode"].location.line == 17
    fleet = model.parts["fleet"]
    assert isinstance(fleet, SystemPart) and fleet.parts == ("robot1", "robot2")
    assert model.parts["fleet"].modes["NIGHT"].entries["robot1"].target.mode == "f_energy_saving_mode"  # type: ignore[union-attr]


def test_a_remote_part_is_served_by_sm_bt_manager_unless_it_says_the_reference() -> None:
    model = load_model_text(FLEET.format(robot2=ROBOT2 + "    served_by: reference\n"))
    assert model.parts["robot1"].remote.served_by == "sm_bt"  # type: ignore[union-attr]
    assert model.parts["robot2"].remote == Remote("", "robot2", "reference")  # type: ignore[union-attr]


def test_modes_may_be_listed_on_lines_and_a_default_named() -> None:
    model = load_model_text(FLEET.format(robot2="    defaultmode: DAY\n    modes:\n      DAY\n      __DEFAULT__\n"
                                                "      f_energy_saving_mode\n"))
    robot2 = model.parts["robot2"]
    assert list(robot2.modes) == ["DAY", "__DEFAULT__", "f_energy_saving_mode"] and robot2.default_mode == "DAY"


@pytest.mark.parametrize(("robot2", "expected"), [
    ("    modes: {__DEFAULT__: {ros__parameters: {x: 1}}}\n",
     "21: 'modes' of remote part 'robot2' lists the names of its modes, as its manager names them (e.g. "
     "[__DEFAULT__, DEGRADED]), not a map"),
    ("    modes: [__DEFAULT__, f_energy_saving_mode, __DEFAULT__]\n",
     "21: mode '__DEFAULT__' of remote part 'robot2' is listed twice (first at line 21): remove one"),
    ("    modes: [f_energy_saving_mode]\n",
     "21: part 'robot2' has no default mode: add a __DEFAULT__ mode or a 'defaultmode: NAME' key"),
    (ROBOT2 + "    manager: robot2\n",
     "22: manager 'robot2' of remote part 'robot2' is not a ROS 2 namespace: write it absolute, e.g. "
     "'/robot1', or leave it out for the root"),
    (ROBOT2 + "    system: 2pilot\n",
     "22: system '2pilot' of remote part 'robot2' is not a part name: use letters, digits and underscores, "
     "as in that manager's model"),
    (ROBOT2 + "    system: [a, b]\n", "22: 'system' of remote part 'robot2' must be a name, not a list"),
    (ROBOT2 + "    served_by: system_modes\n",
     "22: served_by 'system_modes' of remote part 'robot2' is not sm_bt or reference: 'reference' for "
     "micro-ROS/system_modes' mode_manager, else leave it out (sm-bt manager)"),
    (ROBOT2 + "    served_by: 3\n", "22: 'served_by' of remote part 'robot2' must be a name, not '3'"),
    (ROBOT2 + "    parts: [a]\n",
     "22: remote part 'robot2' cannot have 'parts': its manager holds its parts, parameters and rules; remove it"),
    (ROBOT2 + "    match: {x: {tolerance: 1}}\n",
     "22: remote part 'robot2' cannot have 'match': its manager holds its parts, parameters and rules; "
     "remove it"),
])
def test_mistakes_in_a_remote_part_are_told_with_their_line(robot2: str, expected: str) -> None:
    errors = errors_of(FLEET.format(robot2=robot2))
    assert expected in errors, errors


def test_the_remote_keys_on_another_part_and_a_misspelt_type_are_told() -> None:
    text = FLEET.format(robot2=ROBOT2).replace("type: remote\n    manager: /robot1",
                                               "type: Remote\n    manager: /robot1")
    assert "14: part 'robot1': type 'Remote' is not 'node', 'system' or 'remote': write 'remote' (lower-case)" \
        in errors_of(text)
    text = FLEET.format(robot2=ROBOT2).replace("    type: system\n", "    type: system\n    manager: /fleet\n")
    assert ("4: part 'fleet': 'manager' is for a part another manager serves: remove it, or write 'type: remote'"
            in errors_of(text))


def test_a_system_mode_naming_a_mode_the_remote_part_does_not_list_is_refused() -> None:
    errors = errors_of(FLEET.format(robot2=ROBOT2).replace("robot1: active.f_energy_saving_mode",
                                                            "robot1: active.f_energy_saving"))
    assert any(error.startswith("10: ") and "f_energy_saving" in error and "f_energy_saving_mode" in error
               for error in errors), errors
