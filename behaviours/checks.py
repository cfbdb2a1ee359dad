"""Conditions on a part's inferred actual state and mode.

``ModeIs``/``StateIs`` follow py_trees' ``Check*`` semantics (SUCCESS or FAILURE in one tick,
never RUNNING); ``WaitForMode``/``WaitForState`` follow ``WaitFor*`` (RUNNING until it holds,
FAILURE only if a timeout was given and expires). All of them read the manager's inference, so
they see what the nodes report, not what was asked for.
"""

from __future__ import annotations

from typing import Any

from py_trees.common import Status

from sm_bt.behaviours.manager_access import ManagerBehaviour, require_mode_name, seconds
from sm_bt.engine.inference import Actual
from sm_bt.engine.manager import ModeManager
from sm_bt.model.states import State
from sm_bt.model.types import Model


class _Predicate:
    """What a condition expects of a part's actual state and mode."""

    def resolve(self, behaviour: ManagerBehaviour, model: Model, part: str) -> None:
        """Check the expectation against the model (at ``setup``)."""

    def holds(self, actual: Actual) -> bool:
        raise NotImplementedError

    def __str__(self) -> str:
        raise NotImplementedError


class _InMode(_Predicate):
    def __init__(self, mode: str) -> None:
        self.mode = mode
        self.resolved = mode

    def resolve(self, behaviour: ManagerBehaviour, model: Model, part: str) -> None:
        self.resolved = behaviour._check_mode(model, part, self.mode)

    def holds(self, actual: Actual) -> bool:
        return actual.state is State.ACTIVE and actual.mode == self.resolved

    def __str__(self) -> str:
        return f"active.{self.resolved}"


class _InState(_Predicate):
    def __init__(self, state: State | str) -> None:
        self.state = state if isinstance(state, State) else State.from_label(state)

    def holds(self, actual: Actual) -> bool:
        return actual.state is self.state

    def __str__(self) -> str:
        return self.state.label


class _PartCondition(ManagerBehaviour, register=False):
    """A condition on ``manager.actual(part)``."""

    def __init__(self, name: str, part: str, expected: _Predicate, *, manager: ModeManager | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        self.part = part
        self.expected = expected

    @property
    def detail(self) -> str:
        return f"{self.part} {self.expected}"

    def check_model(self, model: Model) -> None:
        self._check_part(model, self.part)
        self.expected.resolve(self, model, self.part)

    def _check(self) -> bool:
        actual = self.manager.actual(self.part)
        ok = self.expected.holds(actual)
        why = f" ({actual.reason})" if actual.reason and not ok else ""
        self.feedback_message = f"{self.part} is {actual}{why}" + ("" if ok else f", not {self.expected}")
        return ok


class _Check(_PartCondition, register=False):
    def update(self) -> Status:
        """SUCCESS if the part is there now, FAILURE otherwise (feedback: what it is)."""
        return Status.SUCCESS if self._check() else Status.FAILURE


class _Wait(_PartCondition, register=False):
    def __init__(self, name: str, part: str, expected: _Predicate, timeout: float | None, *,
                 manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, part, expected, manager=manager, **kwargs)
        self.timeout = seconds(name, timeout)
        self._started = 0.0

    def initialise(self) -> None:
        """Start the timeout (on the manager's clock, so virtual time works)."""
        self._started = self.manager.clock.now()

    def update(self) -> Status:
        """SUCCESS once the part is there, RUNNING until then, FAILURE when the timeout expires."""
        if self._check():
            return Status.SUCCESS
        waited = self.manager.clock.now() - self._started
        if self.timeout is not None and waited >= self.timeout - 1e-9:  # clock steps add up inexactly
            self.feedback_message = f"timed out after {self.timeout:g} s: {self.feedback_message}"
            return Status.FAILURE
        self.feedback_message = f"waiting: {self.feedback_message}"
        return Status.RUNNING


class ModeIs(_Check):
    """Is ``part`` active in ``mode`` now? SUCCESS or FAILURE in one tick, never RUNNING.

    ``mode`` may be ``"__DEFAULT__"`` for the part's default mode. An unknown part or mode is an
    error at ``setup``.
    """

    def __init__(self, name: str, part: str, mode: str, *, manager: ModeManager | None = None,
                 **kwargs: Any) -> None:
        require_mode_name(name, part, mode)
        super().__init__(name, part, _InMode(mode), manager=manager, **kwargs)


class StateIs(_Check):
    """Is ``part`` in lifecycle ``state`` (``"inactive"``, ``State.ACTIVE``, ...) now? SUCCESS or
    FAILURE in one tick, never RUNNING."""

    def __init__(self, name: str, part: str, state: State | str, *, manager: ModeManager | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, part, _InState(state), manager=manager, **kwargs)


class WaitForMode(_Wait):
    """Wait until ``part`` is active in ``mode``: RUNNING until then, SUCCESS when it is; with a
    ``timeout`` (seconds of the manager's clock, counted from ``initialise``) FAILURE when it
    expires first. It only watches: nothing is requested. Without a timeout it waits for as long
    as it takes: give one unless something else bounds the wait."""

    def __init__(self, name: str, part: str, mode: str, timeout: float | None = None, *,
                 manager: ModeManager | None = None, **kwargs: Any) -> None:
        require_mode_name(name, part, mode)
        super().__init__(name, part, _InMode(mode), timeout, manager=manager, **kwargs)


class WaitForState(_Wait):
    """Wait until ``part`` is in lifecycle ``state``: RUNNING until then, SUCCESS when it is;
    FAILURE when the optional ``timeout`` expires first (without one, it waits without bound)."""

    def __init__(self, name: str, part: str, state: State | str, timeout: float | None = None, *,
                 manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, part, _InState(state), timeout, manager=manager, **kwargs)
