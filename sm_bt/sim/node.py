"""A simulated ROS 2 managed node: the ``rcl_lifecycle`` default state machine and typed parameters.

:class:`SimNode` is the node's own logic, without time: :meth:`SimNode.start` enters a transition
state, :meth:`SimNode.complete` applies a callback outcome (``on_configure`` returned FAILURE, ...)
from :data:`~sm_bt.engine.lifecycle.OUTCOMES`. Its driver (:class:`~sm_bt.sim.backend.SimBackend`)
decides when callbacks finish and what they return, so the node stays a plain, testable machine.
Every state change is kept as a :class:`TransitionEvent`, as a node publishes on ``transition_event``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from sm_bt.engine.clock import Clock
from sm_bt.engine.lifecycle import OUTCOMES, REQUESTABLE, Outcome, PlanError, Transition, edge_for
from sm_bt.model.errors import Error
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue

#: rclcpp's names of parameter types (``rclcpp::to_string(ParameterType)``); used in rejection reasons.
_SCALAR_TYPES: dict[type, str] = {bool: "bool", int: "integer", float: "double", str: "string"}
#: The type of ``()``: an empty array fits every array type (it carries no element type).
EMPTY_ARRAY = "array"


class TransitionRefused(Error, ValueError):
    """The node refused a transition request (not valid in its state, or a transition is running)."""


class ParameterRejected(Error, ValueError):
    """The node rejected a parameter set; nothing of it was applied."""


@dataclass(frozen=True)
class TransitionEvent:
    """One ``lifecycle_msgs/TransitionEvent``: ``transition`` took the node from ``start`` to ``goal``."""

    time: float
    transition: Transition
    start: State
    goal: State

    def __str__(self) -> str:
        return f"{self.transition.name.lower()} ({int(self.transition)}): {self.start} -> {self.goal}"


def parameter_type(value: object) -> str | None:
    """The rclcpp type name of ``value`` (``"double"``, ``"integer_array"``); ``None`` if it has none.

    Types are exact: ``True`` is a ``bool``, never an ``integer``; arrays must be homogeneous tuples.
    """
    if isinstance(value, tuple):
        if not value:
            return EMPTY_ARRAY
        element_types = {type(item) for item in value}
        if len(element_types) != 1:
            return None
        element = _SCALAR_TYPES.get(element_types.pop())
        return None if element is None else element + "_array"
    return _SCALAR_TYPES.get(type(value))


def _fits(declared: str, given: str) -> bool:
    if declared == given:
        return True
    return EMPTY_ARRAY in (declared, given) and declared.endswith("array") and given.endswith("array")


class SimNode:
    """A lifecycle node process: its state, its declared parameters and its transition events.

    Parameters are declared with the types of ``parameters`` (the node's default mode values) and
    start with those values. Use :meth:`start`/:meth:`complete` to move through the state machine;
    the clock only stamps the events.

    ``lifecycle=False`` makes a plain node (parameters only, no lifecycle services): it is
    ``active`` as long as its process runs, and :meth:`start` refuses every transition. With
    ``history=False`` :attr:`transitions` stays empty (benchmarks: a bring-up of 10,000 nodes
    would keep 40,000 events).
    """

    def __init__(
        self,
        name: str,
        parameters: Mapping[str, ParamValue],
        clock: Clock,
        *,
        state: State = State.UNCONFIGURED,
        lifecycle: bool = True,
        history: bool = True,
    ) -> None:
        if not state.is_primary:
            raise ValueError(f"node {name} cannot start in {state}: a node starts in a primary state")
        if not lifecycle and state is not State.ACTIVE:
            raise ValueError(f"node {name} has no lifecycle services (parameters only): it runs active, "
                             f"not {state}")
        self.name = name
        self.lifecycle = lifecycle
        self._history = history
        self._clock = clock
        self._state = state
        self._types: dict[str, str] = {}
        for key, value in parameters.items():
            kind = parameter_type(value)
            if kind is None:
                raise ValueError(f"node {name}: parameter {key!r} has no ROS 2 type ({value!r})")
            self._types[key] = kind
        self._values: dict[str, ParamValue] = dict(parameters)
        #: Every state change so far, oldest first (the node's ``transition_event`` topic).
        self.transitions: list[TransitionEvent] = []

    @property
    def state(self) -> State:
        return self._state

    @property
    def in_transition(self) -> bool:
        """True while a transition callback (or error processing) is running."""
        return not self._state.is_primary

    @property
    def parameters(self) -> dict[str, ParamValue]:
        """A copy of the current parameter values."""
        return dict(self._values)

    @property
    def parameter_types(self) -> dict[str, str]:
        """Declared parameter name -> rclcpp type name."""
        return dict(self._types)

    def valid_transitions(self) -> tuple[Transition, ...]:
        """The transitions a client may request in the current state (none while in transition, and
        none ever for a plain node)."""
        if not self.lifecycle:
            return ()
        return tuple(step.transition for step in REQUESTABLE if step.start is self._state)

    def start(self, transition: Transition) -> TransitionEvent:
        """Begin ``transition``: move to its transition state. ``TransitionRefused`` if not valid now."""
        if not self.lifecycle:
            # The ROS backend's wording (sm_bt.ros.backend), so both backends read the same.
            raise TransitionRefused(f"node {self.name} has no lifecycle services (parameters only): "
                                    f"it cannot {transition.label}")
        if self.in_transition:
            raise TransitionRefused(
                f"cannot {transition.label} while {self._state} (a transition is in progress)"
            )
        try:
            step = edge_for(self._state, transition)
        except PlanError as error:
            raise TransitionRefused(str(error)) from None
        return self._move(transition, step.via)

    def complete(self, outcome: Outcome) -> TransitionEvent:
        """Finish the running callback with ``outcome`` (in ``errorprocessing``: ``on_error``'s outcome)."""
        if not self.in_transition:
            raise RuntimeError(f"node {self.name} is in {self._state}: no transition callback is running")
        transition, goal = OUTCOMES[self._state][outcome]
        return self._move(transition, goal)

    def _move(self, transition: Transition, goal: State) -> TransitionEvent:
        event = TransitionEvent(self._clock.now(), transition, self._state, goal)
        self._state = goal
        if self._history:
            self.transitions.append(event)
        return event

    def check_parameters(self, values: Mapping[str, ParamValue]) -> str | None:
        """Why ``values`` would be rejected (every offending parameter named), or ``None`` if acceptable."""
        problems: list[str] = []
        for key, value in values.items():
            declared = self._types.get(key)
            given = parameter_type(value)
            if declared is None:
                problems.append(f"parameter '{key}' is not declared")
            elif given is None:
                problems.append(f"parameter '{key}': {value!r} is not a ROS 2 parameter value")
            elif not _fits(declared, given):
                # rclcpp's wording (node_parameters.cpp), so that logs read the same as on a robot.
                problems.append(
                    f"Wrong parameter type, parameter {{{key}}} is of type {{{declared}}}, "
                    f"setting it to {{{given}}} is not allowed."
                )
        return "; ".join(problems) or None

    def set_parameters(self, values: Mapping[str, ParamValue]) -> None:
        """Apply all of ``values``, or none of them (``ParameterRejected`` with the reason)."""
        problem = self.check_parameters(values)
        if problem is not None:
            raise ParameterRejected(problem)
        self._values.update(values)
