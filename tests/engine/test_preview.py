"""Previews (``manager.preview``/``preview_state``): the plan a change would be carried out by,
computed without doing anything, and the property that makes it worth reading: without faults,
the calls a request then sends are exactly the previewed ones, node by node, in stage order."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from model_files import bundled
from model_generator import GeneratedModel, generated_models, node_starts

from sm_bt.engine.preview import NodeSteps, Preview, SystemSteps, configuration, nodes_of
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart
from sm_bt.sim import SimulatedSystem
from sm_bt.sim.events import SimEventKind

REQUESTABLE = ("configure", "activate", "deactivate", "cleanup")


def test_a_bring_up_is_previewed_node_by_node_without_a_call() -> None:
    system = SimulatedSystem(bundled("pilot"))
    preview = system.manager.preview("pilot", "f_normal_mode")
    assert not any(e.kind is SimEventKind.REQUEST for e in system.backend.events)
    assert preview.possible and preview.calls == 7
    assert preview.lines() == [
        "change_mode pilot f_normal_mode: 7 calls",
        "  pilot -> active.f_normal_mode",
        "    amcl: unconfigured -> active.__DEFAULT__: configure, activate",
        "    controller_server: unconfigured -> active.__DEFAULT__: configure, activate",
        "    pointcloud_to_laser: unconfigured -> inactive: configure",
        "    laser_resender: unconfigured -> active.__DEFAULT__: configure, activate"]


def test_a_mode_switch_shows_its_stages_and_each_parameters_old_and_new_value() -> None:
    system = SimulatedSystem(bundled("pilot"))
    system.finish(system.manager.change_mode("pilot", "f_normal_mode"))
    preview = system.manager.preview("pilot", "f_degraded_mode")
    assert isinstance(preview.plan, SystemSteps) and len(preview.plan.stages) == 3
    assert [[member.node for member in stage if isinstance(member, NodeSteps)] for stage in preview.plan.stages] == [
        ["pointcloud_to_laser"], ["amcl", "controller_server"], ["laser_resender"]]
    controller = next(step for step in preview.steps if step.node == "controller_server")
    assert controller.calls == ("set parameters of mode DEGRADED",)
    assert controller.parameters[:2] == (("FollowPath.max_vel_x", 0.3, 0.1), ("FollowPath.max_speed_xy", 0.3, 0.1))
    assert preview.as_json()["plan"]["stages"][2][0] == {
        "node": "laser_resender", "start": "active.__DEFAULT__", "goal": "unconfigured",
        "calls": ["deactivate", "cleanup"], "parameters": []}
    already = system.manager.preview("pilot", "__DEFAULT__")
    assert already.target == "active.__DEFAULT__"


def test_a_preview_keeps_the_values_it_saw_when_the_node_changes_later() -> None:
    system = SimulatedSystem(bundled("pilot"))
    system.finish(system.manager.change_mode("pilot", "f_normal_mode"))
    preview = system.manager.preview("controller_server", "DEGRADED")
    system.set_parameter("controller_server", "FollowPath.max_vel_x", 0.7)  # someone else, afterwards
    system.run(0.1)
    assert system.manager.observation("controller_server").parameters["FollowPath.max_vel_x"] == 0.7
    (steps,) = preview.steps
    assert steps.parameters[0] == ("FollowPath.max_vel_x", 0.3, 0.1)


def test_a_change_that_would_be_refused_says_why_in_the_same_words() -> None:
    system = SimulatedSystem(bundled("pilot"))
    system.finish(system.manager.change_mode("pilot", "f_normal_mode"))
    refused = system.manager.preview_state("pilot", "configure")
    request = system.manager.change_state("pilot", "configure")
    assert not refused.possible and request.refused and refused.refused == request.reason
    system.crash("laser_resender")
    system.run(2.0)
    gone = system.manager.preview("pilot", "f_slow_mode")
    request = system.manager.change_mode("pilot", "f_slow_mode")
    assert gone.refused == request.reason == "laser_resender is not reachable (no answer for 1.0 s (crashed?))"
    assert gone.lines() == [f"change_mode pilot f_slow_mode: cannot be made now: {gone.refused}"]
    with pytest.raises(RequestError, match="unknown mode 'f_slwo_mode' of pilot"):
        system.manager.preview("pilot", "f_slwo_mode")


def test_rules_that_would_start_or_stop_firing_are_named() -> None:
    system = SimulatedSystem(bundled("pilot_rules"), rules=False, recovery=False)
    system.finish(system.manager.change_mode("pilot", "f_normal_mode"))
    system.finish(system.manager.change_state("laser_resender", "deactivate"))
    # degrade_from_normal: under f_normal_mode, laser_resender unconfigured -> f_degraded_mode.
    cleanup = system.manager.preview_state("laser_resender", "cleanup")
    assert cleanup.rules_start == ("degrade_from_normal (pilot: laser_resender is unconfigured -> "
                                   "active.f_degraded_mode)",)
    assert "  rule degrade_from_normal (pilot: laser_resender is unconfigured -> active.f_degraded_mode) would fire" \
        in cleanup.lines()
    system.finish(system.manager.change_state("laser_resender", "cleanup"))
    assert system.manager.preview_state("laser_resender", "configure").rules_stop == ("degrade_from_normal",)
    assert system.manager.preview("pilot", "f_slow_mode").rules_stop == ("degrade_from_normal",)  # another target


def test_offline_a_model_alone_is_previewed_from_a_configuration_given() -> None:
    model = bundled("pilot")
    system = SimulatedSystem(model)
    offline = configuration(model, nodes_of(model, {"pilot": StateMode(State.ACTIVE, "f_normal_mode")}))
    preview = system.manager.preview("pilot", "f_degraded_mode", from_=offline)
    assert preview.calls == 5 and not any(e.kind is SimEventKind.REQUEST for e in system.backend.events)
    assert "amcl: active.__DEFAULT__ -> active.DEGRADED: set parameters of mode DEGRADED" in "\n".join(preview.lines())
    assert configuration(model).actual("pilot").state is State.UNCONFIGURED


# -- the property --------------------------------------------------------------------------------


@st.composite
def previewed_changes(draw: st.DrawFn) -> tuple[Model, dict[str, Any], str, str, str]:
    """A generated model, where its nodes start (states, modes), and a request: (part, "mode" or
    "state", mode or transition)."""
    generated: GeneratedModel = draw(generated_models())
    model = generated.load()
    start = draw(node_starts(model))
    part = draw(st.sampled_from(sorted(model.parts)))
    if draw(st.booleans()):
        return model, start, part, "mode", \
            draw(st.sampled_from(sorted(model.parts[part].modes)))
    return model, start, part, "state", \
        draw(st.sampled_from(REQUESTABLE))


def _executed(system: SimulatedSystem, model: Model, since: int) -> dict[str, list[tuple[int, str]]]:
    """Each node's calls since event ``since``: (event index, the transition's label, or the values set)."""
    calls: dict[str, list[tuple[int, str]]] = {}
    for index, event in enumerate(system.backend.events[since:], since):
        if event.kind is not SimEventKind.REQUEST:
            continue
        if event.parameters is not None:
            label = f"set parameters {sorted(event.parameters.items())}"
        else:
            label = event.details.split()[1]  # "change_state configure (1)"
        calls.setdefault(event.node, []).append((index, label))
    return calls


def _paths(entry: SystemSteps | NodeSteps, path: tuple[tuple[str, int], ...] = ()) -> dict[str, tuple[tuple[str, int],
                                                                                                      ...]]:
    """Each node's place in the plan: the (system, stage) it is in, from the top."""
    if isinstance(entry, NodeSteps):
        return {entry.node: path}
    found: dict[str, tuple[tuple[str, int], ...]] = {}
    for index, stage in enumerate(entry.stages):
        for member in stage:
            found.update(_paths(member, (*path, (entry.system, index))))
    return found


def check_preview_is_the_truth(model: Model, start: dict[str, Any], part: str, kind: str, value: str) -> None:
    system = SimulatedSystem(model, rules=False, recovery=False, **start)
    system.run(0.5)  # the manager has seen every node
    manager = system.manager
    preview: Preview = manager.preview(part, value) if kind == "mode" else manager.preview_state(part, value)
    since = len(system.backend.events)
    request = manager.change_mode(part, value) if kind == "mode" else manager.change_state(part, value)
    if not preview.possible:
        assert request.done and not request.succeeded and request.reason == preview.refused, (preview, request)
        return
    system.finish(request, timeout=120.0)
    assert request.succeeded, (request.reason, preview.lines())
    executed = _executed(system, model, since)
    for step in preview.steps:
        node = model.parts[step.node]
        assert isinstance(node, NodePart)
        # A set is told by its values: two modes of a node may hold the same ones.
        wanted = [f"set parameters {sorted(node.modes[call.rsplit(' ', 1)[1]].values().items())}"
                  if call.startswith(("set parameters of mode ", "change_mode ")) else call for call in step.calls]
        assert [label for _, label in executed.get(step.node, [])] == wanted, (step, executed)
    assert set(executed) <= {step.node for step in preview.steps if step.calls}
    # Stage order: every call of an earlier stage of a system before any call of a later one.
    assert preview.plan is not None
    paths = _paths(preview.plan)
    for a, a_calls in executed.items():
        for b, b_calls in executed.items():
            shared = next(((x, y) for x, y in zip(paths[a], paths[b], strict=False) if x != y), None)
            if shared is not None and shared[0][0] == shared[1][0] and shared[0][1] < shared[1][1]:
                assert a_calls[-1][0] < b_calls[0][0], (a, b, preview.lines())


@examples(200, stress=10_000)
@given(previewed_changes())
def test_without_faults_a_request_sends_exactly_the_previewed_calls_in_stage_order(
        change: tuple[Model, dict[str, Any], str, str, str]) -> None:
    check_preview_is_the_truth(*change)
