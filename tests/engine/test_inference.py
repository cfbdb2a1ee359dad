"""Bottom-up inference, driven directly (no manager, no backend)."""

from __future__ import annotations

from pathlib import Path

import pytest

from sm_bt.engine.inference import Inference
from sm_bt.model.loader import load_model
from sm_bt.model.states import State, StateMode

MODELS = Path(__file__).parents[1] / "models"
A, I, U = State.ACTIVE, State.INACTIVE, State.UNCONFIGURED  # noqa: E741
DEFAULT = {"foo": 0.1, "bar": "WARN"}


def active(mode: str | None = None) -> StateMode:
    return StateMode(A, mode)


@pytest.fixture
def inf() -> Inference:
    return Inference(load_model(MODELS / "two_nodes.yaml"))


def test_reference_inference_sequence(inf: Inference) -> None:
    inf.set_target("system", active("__DEFAULT__"))
    inf.node_appeared("part0", I, DEFAULT)
    inf.node_appeared("part1", A, DEFAULT)
    assert inf.actual("system").state_mode == active("__DEFAULT__")

    inf.node_parameters("part1", {"foo": 0.2, "bar": "DBG"})
    assert inf.actual("part1").state_mode == active("AAA")

    inf.node_state("part0", A)
    inf.node_parameters("part0", {"bar": "DBG"})
    assert inf.actual("part0").state_mode == active("FOO")
    # Both parts now match AA, which is not the target: the system is on its way.
    assert inf.actual("system").state_mode == StateMode(State.ACTIVATING, "AA")


def test_node_without_parameters_has_no_mode_and_says_why(inf: Inference) -> None:
    inf.node_appeared("part0", A, {})
    actual = inf.actual("part0")
    assert (actual.state, actual.mode) == (A, None)
    assert "foo unset" in actual.reason
    inf.node_parameters("part0", DEFAULT)
    assert inf.actual("part0").mode == "__DEFAULT__"


def test_mode_is_only_inferred_while_active(inf: Inference) -> None:
    inf.node_appeared("part0", I, {"foo": 0.2, "bar": "ERR"})
    assert inf.actual("part0").state_mode == StateMode(I)
    assert inf.actual("part0").mode is None
    inf.node_state("part0", A)
    assert inf.actual("part0").mode == "BAR"


def test_values_are_compared_with_their_type(inf: Inference) -> None:
    inf.node_appeared("part1", A, {"foo": 0.9, "bar": "ERR"})
    assert inf.actual("part1").mode == "BBB"
    inf.node_parameters("part1", {"foo": 1})  # an int is not the double 0.9, nor anything else
    assert inf.actual("part1").mode is None


def test_reported_and_inferred_flags(inf: Inference) -> None:
    inf.node_appeared("part1", A, DEFAULT)
    node = inf.actual("part1")
    assert (node.state_inferred, node.mode_inferred) == (False, True)
    inf.node_appeared("part0", A, DEFAULT, lifecycle=False)
    assert inf.actual("part0").state_inferred is True
    system = inf.actual("system")
    assert (system.state_inferred, system.mode_inferred) == (True, True)


def test_never_seen_part_makes_the_system_unknown_with_a_reason(inf: Inference) -> None:
    inf.set_target("system", active("AA"))
    inf.node_appeared("part1", A, {"foo": 0.2, "bar": "DBG"})
    actual = inf.actual("system")
    assert actual.state is State.UNKNOWN
    assert "part0: never seen" in actual.reason


def test_vanished_node_is_unknown_with_the_backend_reason(inf: Inference) -> None:
    inf.node_appeared("part0", A, DEFAULT)
    inf.node_vanished("part0", "no answer for 1 s")
    assert inf.actual("part0").state is State.UNKNOWN
    assert inf.actual("part0").reason == "no answer for 1 s"
    inf.node_appeared("part0", I, DEFAULT)
    assert inf.actual("part0").state is I


def test_errorprocessing_propagates(inf: Inference) -> None:
    inf.set_target("system", active("AA"))
    inf.node_appeared("part0", State.ERRORPROCESSING, DEFAULT)
    inf.node_appeared("part1", A, DEFAULT)
    assert inf.actual("system").state is State.ERRORPROCESSING
    assert "part0" in inf.actual("system").reason


def test_inactive_target(inf: Inference) -> None:
    inf.set_target("system", StateMode(I))
    inf.node_appeared("part0", I, DEFAULT)
    inf.node_appeared("part1", A, DEFAULT)
    assert inf.actual("system").state is State.DEACTIVATING
    inf.node_state("part1", I)
    assert inf.actual("system").state_mode == StateMode(I)
    # Coming up from unconfigured is configuring, not "deactivating" as the reference says.
    inf.node_state("part0", U)
    assert inf.actual("system").state is State.CONFIGURING


def test_other_state_targets(inf: Inference) -> None:
    inf.node_appeared("part0", I, DEFAULT)
    inf.node_appeared("part1", U, DEFAULT)
    inf.set_target("system", StateMode(U))
    assert inf.actual("system").state is State.CLEANINGUP
    inf.node_state("part0", U)
    assert inf.actual("system").state is U
    inf.set_target("system", StateMode(State.FINALIZED))
    assert inf.actual("system").state is State.SHUTTINGDOWN


def test_untargeted_system(inf: Inference) -> None:
    inf.node_appeared("part0", I, DEFAULT)
    inf.node_appeared("part1", I, DEFAULT)
    assert inf.actual("system").state_mode == StateMode(I)
    inf.node_state("part1", A)
    assert inf.actual("system").state_mode == active("__DEFAULT__")
    inf.node_state("part0", U)
    actual = inf.actual("system")
    assert actual.state is State.UNKNOWN
    assert "no target" in actual.reason


def test_updates_are_incremental(inf: Inference) -> None:
    changes = inf.node_appeared("part1", A, DEFAULT)
    # The system stays unknown (part0 never seen); only its reason narrows to part0.
    assert set(changes) == {"part1", "system"}
    assert changes["system"][1].state is State.UNKNOWN and "part1" not in changes["system"][1].reason
    assert inf.node_appeared("part1", A, DEFAULT) == {}
    inf.node_appeared("part0", I, DEFAULT)
    changes = inf.node_parameters("part1", {"foo": 0.2, "bar": "DBG"})
    assert set(changes) == {"part1", "system"}
    old, new = changes["part1"]
    assert (str(old), str(new)) == ("active.__DEFAULT__", "active.AAA")
    assert inf.node_parameters("part1", {"foo": 0.2}) == {}


def test_tie_break_target_then_default_then_bytewise() -> None:
    inf = Inference(load_model(MODELS / "ambiguous.yaml", strict=True))
    inf.node_appeared("arm", A, {"torque": 0.1})
    assert inf.actual("arm").mode == "__DEFAULT__"
    inf.set_target("arm", active("WEAK"))
    assert inf.actual("arm").mode == "WEAK"
    inf.set_target("arm", active("STRONG"))  # the target does not match: back to the default
    assert inf.actual("arm").mode == "__DEFAULT__"
    inf.node_parameters("arm", {"torque": 0.7})  # matches only LIMP and HARD: byte-wise first
    assert inf.actual("arm").mode == "HARD"


def test_nested_systems() -> None:
    inf = Inference(load_model(MODELS / "nested.yaml"))
    inf.set_target("robot", active("WORK"))
    inf.set_target("base", active("PRECISE"))
    inf.node_appeared("drive", A, {"max_speed": 0.1})
    inf.node_appeared("lidar", A, {"rate": 10})
    inf.node_appeared("arm", A, {"max_torque": 0.5})
    assert inf.actual("base").state_mode == active("PRECISE")
    assert inf.actual("robot").state_mode == active("WORK")
    changes = inf.node_parameters("drive", {"max_speed": 0.5})
    assert set(changes) == {"drive", "base", "robot"}
    assert inf.actual("base").state_mode == StateMode(State.ACTIVATING, "__DEFAULT__")
    assert inf.actual("robot").state is State.ACTIVATING


def test_dont_care_entries_match_anything() -> None:
    inf = Inference(load_model(MODELS / "nested.yaml"))
    inf.set_target("robot", active("PARK"))
    inf.set_target("base", StateMode(I))
    inf.node_appeared("drive", I, {"max_speed": 0.5})
    inf.node_appeared("lidar", I, {"rate": 10})
    # arm never seen, but PARK does not care about it.
    assert inf.actual("robot").state_mode == active("PARK")


def test_an_unknown_systems_reason_stays_short_however_many_parts_it_lacks() -> None:
    """A system names three of its unknown parts and counts the rest; a system above names an
    unknown sub-system by its reason's headline, not by the sub-system's parts (so one appearance
    rebuilds strings of bounded length, not a reason that grows with the model)."""
    from sm_bt.engine.inference import infer_all
    from sm_bt.model.loader import load_model_text

    def system(name: str, parts: list[str]) -> str:
        return (f"{name}:\n  ros__parameters:\n    type: system\n    parts:\n"
                + "".join(f"      {p}\n" for p in parts)
                + "    modes:\n      __DEFAULT__:\n" + "".join(f"        {p}: active\n" for p in parts))

    nodes = [f"n{i}" for i in range(25)]
    text = system("root", ["s0", "s1", "s2", "s3", "s4"]) + "".join(
        system(f"s{i}", nodes[5 * i:5 * i + 5]) for i in range(5)) + "".join(
        f"{n}:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n"
        "        ros__parameters:\n          p: 1\n" for n in nodes)
    model = load_model_text(text, "big.yaml")
    inference = Inference(model)
    inference.node_appeared("n0", A, {})
    leaf = inference.actual("s0")  # n0..n4, n0 seen
    assert leaf.state is State.UNKNOWN
    assert leaf.reason == "part state unknown (n1: never seen; n2: never seen; n3: never seen; 1 more)"
    root = inference.actual("root")
    assert root.reason == ("part state unknown (s0: part state unknown; s1: part state unknown; "
                           "s2: part state unknown; 2 more)")
    # The reference inference from scratch says the same.
    observations = {node.name: inference.observation(node.name) for node in model.nodes}
    assert infer_all(model, observations, {}) == {name: inference.actual(name) for name in model.parts}
