"""What a request asks for, checked against the model: the part, the mode (``__DEFAULT__``
resolved), the lifecycle transition and its goal, the failure policy. Every name the model does
not have is a :class:`~sm_bt.model.errors.RequestError` with the real names and the closest one."""

from __future__ import annotations

from sm_bt.engine.lifecycle import (
    REQUESTABLE,
    REQUESTABLE_LABELS,
    PlanError,
    Transition,
    edge_for,
    transition_by_label,
)
from sm_bt.engine.rollback import MODE_POLICY, check_policy
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import DEFAULT_MODE, Model, NodePart, resolve_mode

_GOAL = {step.transition: step.goal for step in REQUESTABLE}


def check_part(model: Model, part: str) -> None:
    if part not in model.parts:
        raise RequestError(f"unknown part {part!r}{did_you_mean(part, model.parts)} "
                           f"(parts: {', '.join(model.parts)})")


def check_node(model: Model, node: str) -> None:
    check_part(model, node)
    if not isinstance(model.parts[node], NodePart):
        raise RequestError(f"{node} is a system, not a node (nodes: {', '.join(n.name for n in model.nodes)})")


def modes_of(model: Model, part: str) -> list[str]:
    """Every mode of ``part``, sorted byte-wise (as the reference's ``get_available_modes``)."""
    check_part(model, part)
    return sorted(model.parts[part].modes)


def mode_target(model: Model, part: str, wanted: StateMode, description: str) -> StateMode:
    """``wanted`` with an active mode resolved (``__DEFAULT__``: the default mode)."""
    check_part(model, part)
    if wanted.state is State.ACTIVE:
        resolved = resolve_mode(model.parts[part], wanted.mode or DEFAULT_MODE)
        if resolved is None:
            modes = modes_of(model, part)
            raise RequestError(f"{description}: unknown mode {wanted.mode!r} of {part}"
                               f"{did_you_mean(wanted.mode or '', modes)} (modes: {', '.join(modes)})")
        wanted = StateMode(State.ACTIVE, resolved)
    return wanted


def failure_policy(model: Model, part: str, on_failure: str | None) -> str | None:
    """``on_failure`` checked: a policy, and a safe mode the part has."""
    if on_failure is None:
        return None
    try:
        check_policy(on_failure)
    except ValueError as error:
        raise RequestError(str(error)) from None
    if on_failure.startswith(MODE_POLICY):
        mode = on_failure[len(MODE_POLICY):]
        resolved = resolve_mode(model.parts[part], mode)
        if resolved is None:
            modes = modes_of(model, part)
            raise RequestError(f"on_failure={on_failure!r}: {part} has no mode {mode!r}"
                               f"{did_you_mean(mode, modes)} (modes: {', '.join(modes)})")
        return f"{MODE_POLICY}{resolved}"
    return on_failure


def state_target(part: str, transition: Transition | str | int, current: State, moving: bool,
                 activation_mode: str) -> tuple[str, StateMode, Transition, str]:
    """``change_state``'s description, target, transition, and why it is refused ("" if not).
    ``moving``: a request is moving the part (any requestable transition goes then);
    ``activation_mode``: the mode an activation keeps."""
    name = transition.label if isinstance(transition, Transition) else str(transition)
    description = f"change_state {part} {name}"
    try:
        resolved = resolve_transition(transition, current)
    except ValueError as error:
        raise RequestError(f"{description}: {error} (transitions: {', '.join(REQUESTABLE_LABELS)})"
                           f"{did_you_mean(name, REQUESTABLE_LABELS)}") from None
    if resolved not in _GOAL:
        raise RequestError(f"{description}: {resolved.label} ({int(resolved)}) cannot be requested "
                           f"(transitions: {', '.join(REQUESTABLE_LABELS)})")
    goal = _GOAL[resolved]
    refusal = ""
    try:
        if current.is_primary and goal is not current and not moving:
            edge_for(current, resolved)  # raises with the valid ones when invalid here
    except PlanError as error:
        refusal = f"{part}: {error}"
    return description, StateMode(goal, activation_mode if goal is State.ACTIVE else None), resolved, refusal


def resolve_transition(transition: Transition | str | int, current: State) -> Transition:
    if isinstance(transition, Transition):
        return transition
    if isinstance(transition, int):
        return Transition(transition)
    return transition_by_label(transition, current)
