"""Behaviours that change a part: :class:`ChangeMode` and :class:`ChangeState`.

Both work the same way for systems and nodes (the tree need not know which a part is): the
request is made in ``initialise``, each tick reports its progress without blocking, and an
interruption withdraws it.
"""

from __future__ import annotations

from typing import Any

from py_trees.common import Status

from sm_bt.behaviours.manager_access import REQUESTER, ManagerBehaviour, require_mode_name, seconds
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.preview import Preview
from sm_bt.engine.requests import Request
from sm_bt.engine.rollback import MODE_POLICY, check_policy
from sm_bt.model.types import Model

#: The lifecycle transitions a tree may ask for, by label.
TRANSITIONS = REQUESTABLE_LABELS


def _priority(name: str, priority: int | str | None) -> int | None:
    """A priority as a whole number of 0 or more (an XML attribute is text); ``ValueError`` naming
    the behaviour otherwise."""
    if priority is None:
        return None
    try:
        value = int(priority)
    except (TypeError, ValueError):
        value = -1
    if value < 0:
        raise ValueError(f"{name}: priority must be a whole number, 0 or more, not {priority!r}")
    return value


def _flag(name: str, what: str, value: bool | str) -> bool:
    """A yes/no option (an XML attribute is text: "true" or "false")."""
    if isinstance(value, bool):
        return value
    if value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise ValueError(f"{name}: {what} must be true or false, not {value!r}")


class _RequestBehaviour(ManagerBehaviour, register=False):
    """Common life of a behaviour that owns one manager request."""

    def __init__(self, name: str, part: str, timeout: float | None, *, manager: ModeManager | None = None,
                 on_failure: str | None = None, priority: int | str | None = None, queue: bool | str = False,
                 **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        self.part = part
        self.timeout = seconds(name, timeout)
        #: The request's priority against the manager's holds (``None``: the tree's, 40).
        self.priority = _priority(name, priority)
        #: Held back by a hold, the request waits for it to end (RUNNING, "queued: ...") rather
        #: than failing at once; its timeout still bounds it.
        self.queue = _flag(name, "queue", queue)
        try:
            #: What the request leaves behind if it fails: "stay", "rollback", "mode:<name>"
            #: (``None``: the manager's default).
            self.on_failure = check_policy(on_failure) if on_failure is not None else None
        except ValueError as error:
            raise ValueError(f"{name}: {error}") from None
        self.request: Request | None = None
        #: The change's plan, as previewed from where the parts were when it was asked for
        #: (``ChangeMode``), or ``None``.
        self.plan: Preview | None = None

    def _check_policy(self, model: Model) -> None:
        if self.on_failure is not None and self.on_failure.startswith(MODE_POLICY):
            self._check_mode(model, self.part, self.on_failure[len(MODE_POLICY):])

    def _make_request(self, manager: ModeManager) -> Request | None:
        """Ask the manager (it returns at once); ``None`` when there is nothing to ask for."""
        raise NotImplementedError

    def initialise(self) -> None:
        """Send the request to the manager (it returns at once)."""
        self.request = self._make_request(self.manager)

    def update(self) -> Status:
        """RUNNING while the manager works on the request (feedback: the step in progress),
        SUCCESS once the manager confirmed the part reached the target, FAILURE with the
        manager's reason (refused transition, rejected parameters, timeout, preempted, ...)."""
        request = self.request
        if request is None:  # ticked without initialise: py_trees never does this
            return Status.INVALID
        if not request.done:
            planned = f" (plan: {self.plan.calls} calls)" if self.plan is not None and self.plan.possible else ""
            self.feedback_message = request.feedback + planned
            return Status.RUNNING
        if request.succeeded:
            self.feedback_message = f"{self.part} is {request.target} ({request.elapsed or 0.0:.2f} s)"
            return Status.SUCCESS
        self.feedback_message = request.reason
        self.logger.debug(f"{self.qualified_name}: {request.description} failed: {request.reason}")
        return Status.FAILURE

    def terminate(self, new_status: Status) -> None:
        """Interrupted (INVALID) while the request is in flight: withdraw it, so the manager
        sends no further steps and restores the previous targets."""
        if new_status is Status.INVALID and self.request is not None and not self.request.done:
            self.request.cancel()
            self.feedback_message = f"cancelled: {self.request.description}"


class ChangeMode(_RequestBehaviour):
    """Put ``part`` (a system or a node) in ``mode``, active.

    * ``initialise``: request the change (``ModeManager.change_mode``); ``plan``: its preview,
      from where the parts were (:meth:`ModeManager.plan_of`)
    * ``update``: RUNNING while in progress (feedback: the step in progress, and the plan's
      calls), SUCCESS when the manager confirms the part's inferred actual state is
      ``active.<mode>``, FAILURE with the manager's reason otherwise
    * ``terminate``: withdraw the request when interrupted while RUNNING

    ``timeout`` (seconds of the manager's clock) bounds the whole change; ``None`` takes the
    manager's ``request_timeout``. ``on_failure``: what a failed change leaves behind ("stay",
    "rollback", "mode:<name>"; ``None``: the manager's default). ``priority``: the request's
    against the manager's holds (``None``: the tree's; a part held at a higher one refuses it:
    FAILURE naming the holder, or with ``queue`` RUNNING until the hold ends, within
    ``timeout``). An unknown part or mode is an error at ``setup``.
    """

    def __init__(self, name: str, part: str, mode: str, timeout: float | None = None, *,
                 manager: ModeManager | None = None, on_failure: str | None = None, priority: int | str | None = None,
                 queue: bool | str = False, **kwargs: Any) -> None:
        super().__init__(name, part, timeout, manager=manager, on_failure=on_failure, priority=priority,
                         queue=queue, **kwargs)
        require_mode_name(name, part, mode)
        self.mode = mode

    @property
    def detail(self) -> str:
        return f"{self.part} {self.mode}"

    def check_model(self, model: Model) -> None:
        self._check_mode(model, self.part, self.mode)
        self._check_policy(model)

    def _make_request(self, manager: ModeManager) -> Request:
        request = manager.change_mode(self.part, self.mode, timeout=self.timeout, requester=REQUESTER,
                                      on_failure=self.on_failure, priority=self.priority, queue=self.queue)
        self.plan = manager.plan_of(request)
        return request


class CanChangeMode(ManagerBehaviour):
    """Could ``part`` be put in ``mode`` now? A check before committing to a contingency.

    * ``update``: SUCCESS when the manager could carry the change out from where the parts are
      now (feedback: the plan's calls), FAILURE when it would refuse it (feedback: why, in the
      words a refused request uses: a node out of reach, finalized, ...). One tick, never
      RUNNING; nothing is asked of the nodes. ``plan``: the last preview.

    An unknown part or mode is an error at ``setup``.
    """

    def __init__(self, name: str, part: str, mode: str, *, manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        require_mode_name(name, part, mode)
        self.part = part
        self.mode = mode
        self.plan: Preview | None = None

    @property
    def detail(self) -> str:
        return f"{self.part} {self.mode}"

    def check_model(self, model: Model) -> None:
        self._check_mode(model, self.part, self.mode)

    def update(self) -> Status:
        """SUCCESS if the change could be made now, FAILURE with the reason it could not."""
        self.plan = self.manager.preview(self.part, self.mode)
        self.feedback_message = self.plan.summary()
        return Status.SUCCESS if self.plan.possible else Status.FAILURE


class ChangeState(_RequestBehaviour):
    """Take ``part`` (a system or a node) through a lifecycle ``transition``: ``"configure"``,
    ``"activate"``, ``"deactivate"``, ``"cleanup"`` or ``"shutdown"``.

    * ``initialise``: request it (``ModeManager.change_state``); a part already in the
      transition's goal state succeeds at once, and activation keeps the last mode asked for
    * ``update``: RUNNING while in progress, SUCCESS when the part is confirmed in the goal
      state, FAILURE with the manager's reason (for instance a transition invalid from the
      part's current state, or one a node refused)
    * ``terminate``: withdraw the request when interrupted while RUNNING
    """

    def __init__(self, name: str, part: str, transition: str | Transition, timeout: float | None = None, *,
                 manager: ModeManager | None = None, on_failure: str | None = None, priority: int | str | None = None,
                 queue: bool | str = False, **kwargs: Any) -> None:
        super().__init__(name, part, timeout, manager=manager, on_failure=on_failure, priority=priority,
                         queue=queue, **kwargs)
        label = transition.label if isinstance(transition, Transition) else transition
        if label not in TRANSITIONS:
            raise ValueError(f"{name}: cannot request transition {label!r} (one of: {', '.join(TRANSITIONS)})")
        self.transition = label

    @property
    def detail(self) -> str:
        return f"{self.part} {self.transition}"

    def check_model(self, model: Model) -> None:
        self._check_part(model, self.part)
        self._check_policy(model)

    def _make_request(self, manager: ModeManager) -> Request:
        return manager.change_state(self.part, self.transition, timeout=self.timeout, requester=REQUESTER,
                                    on_failure=self.on_failure, priority=self.priority, queue=self.queue)


__all__ = ["TRANSITIONS", "CanChangeMode", "ChangeMode", "ChangeState"]
