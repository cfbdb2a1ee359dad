"""Incremental inference (tallies, climbing only as far as something changed) against the
reference functions ``infer_node``/``infer_system`` recomputed from scratch after every update."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_generator import FIXED_MODELS, GeneratedModel, fixed_model, generated_models

from sm_bt.engine.inference import Inference, infer_all
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart

STATES = [State.UNCONFIGURED, State.INACTIVE, State.ACTIVE, State.ACTIVE, State.ACTIVE, State.FINALIZED,
          State.CONFIGURING, State.ACTIVATING, State.DEACTIVATING, State.ERRORPROCESSING]


@st.composite
def updates(draw: st.DrawFn, model: Model) -> list[tuple[str, object, object]]:
    """Reports and targets in random order: appear, state, parameters (a mode's values, or a
    value of no mode), vanish, and set or clear a target."""
    parts = list(model.parts)
    nodes = [p for p in model.nodes if isinstance(p, NodePart)]
    steps: list[tuple[str, object, object]] = []
    for _ in range(draw(st.integers(1, 40))):
        kind = draw(st.sampled_from(["appear", "state", "state", "parameters", "parameters", "vanish", "target"]))
        if kind == "target":
            part = model.parts[draw(st.sampled_from(parts))]
            choices = [None, StateMode(State.INACTIVE), StateMode(State.UNCONFIGURED)]
            choices += [StateMode(State.ACTIVE, mode) for mode in part.modes]
            steps.append(("target", part.name, draw(st.sampled_from(choices))))
            continue
        node = draw(st.sampled_from(nodes))
        if kind == "appear":
            mode = node.modes[draw(st.sampled_from(list(node.modes)))]
            steps.append(("appear", node.name, (draw(st.sampled_from(STATES[:3])), mode.values())))
        elif kind == "state":
            steps.append(("state", node.name, draw(st.sampled_from(STATES))))
        elif kind == "parameters":
            mode = node.modes[draw(st.sampled_from(list(node.modes)))]
            values = mode.values()
            if values and draw(st.booleans()):
                name = draw(st.sampled_from(list(values)))
                values = {name: "matches no mode"}
            steps.append(("parameters", node.name, values))
        else:
            steps.append(("vanish", node.name, "gone"))
    return steps


def _replay(model: Model, data: st.DataObject) -> None:
    inference = Inference(model)
    targets: dict[str, StateMode] = {}
    for kind, part, value in data.draw(updates(model)):
        if kind == "target":
            assert value is None or isinstance(value, StateMode)
            inference.set_target(part, value)
            if value is None:
                targets.pop(part, None)
            else:
                targets[part] = value
        elif kind == "appear":
            state, values = value  # type: ignore[misc]
            inference.node_appeared(part, state, values)
        elif kind == "state":
            inference.node_state(part, value)  # type: ignore[arg-type]
        elif kind == "parameters":
            inference.node_parameters(part, value)  # type: ignore[arg-type]
        else:
            inference.node_vanished(part, str(value))
        observations = {node.name: inference.observation(node.name) for node in model.nodes}
        expected = infer_all(model, observations, targets)
        for name in model.parts:
            assert inference.actual(name) == expected[name], (kind, part, value, name)


@examples(60)
@given(generated_models(), st.data())
def test_incremental_inference_equals_the_reference_on_generated_models(generated: GeneratedModel,
                                                                          data: st.DataObject) -> None:
    _replay(generated.load(), data)


@examples(40)
@given(st.sampled_from(sorted(FIXED_MODELS)), st.data())
def test_incremental_inference_equals_the_reference_on_the_fixed_models(name: str, data: st.DataObject) -> None:
    _replay(fixed_model(name), data)
