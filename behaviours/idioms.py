"""Tree idioms for modes: hold a mode while a subtree runs; switch mode when a part diverges.

py_trees idioms are functions that return a subtree; these two follow that style.
"""

from __future__ import annotations

import logging
from typing import Any

import py_trees
from py_trees.common import Status
from py_trees.ports import PortInformation, PortsMixin

from sm_bt.behaviours.change import ChangeMode
from sm_bt.behaviours.divergence import OnDivergence
from sm_bt.behaviours.manager_access import REQUESTER, ManagerBehaviour, require_mode_name, seconds
from sm_bt.engine.holds import Hold
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model

log = logging.getLogger("sm_bt.behaviours")


class HoldMode(ManagerBehaviour, register=False):
    """A context switch (py_trees' context-switching pattern): puts ``part`` in ``mode`` and
    puts it back when it stops, whatever the reason.

    * ``initialise``: remember the part's target, request ``mode``
    * ``update``: RUNNING while the change is in progress and for as long as it holds the mode
      (it never succeeds by itself); FAILURE if the change fails
    * ``terminate`` (SUCCESS of the work beside it, FAILURE, or interruption): withdraw the
      change if still in flight and request the remembered target back, unless somebody else
      asked for another target meanwhile (their request wins, nothing is restored) or it was
      ``finalized`` (not a target to ask for: only a restart leaves it)

    With ``lease`` (seconds) or ``priority`` it holds the part through the manager
    (:meth:`ModeManager.hold`): requests of a lower priority that would change it are refused,
    the lease is renewed on every tick, and ``terminate`` releases the hold first (a tree that
    stops ticking, or dies, frees the part within its lease).

    Use it through :func:`hold_mode`, which runs it in a parallel next to the work.
    """

    def __init__(self, name: str, part: str, mode: str, timeout: float | None = None, *,
                 manager: ModeManager | None = None, lease: float | None = None, priority: int | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        require_mode_name(name, part, mode)
        self.part = part
        self.mode = mode
        self.timeout = seconds(name, timeout)
        self.lease = seconds(name, lease)
        self.priority = priority
        #: The manager's hold, with ``lease`` or ``priority``, while it runs.
        self.holding: Hold | None = None
        self.request: Request | None = None
        self.restore_request: Request | None = None
        self._held: StateMode | None = None
        self._previous: StateMode | None = None

    @property
    def detail(self) -> str:
        return f"{self.part} {self.mode}"

    def check_model(self, model: Model) -> None:
        self._held = StateMode(State.ACTIVE, self._check_mode(model, self.part, self.mode))

    @property
    def held(self) -> StateMode | None:
        """The state and mode held (known once set up)."""
        return self._held

    def initialise(self) -> None:
        """Remember the current target and request the mode."""
        self._previous = self.manager.target(self.part)
        self.restore_request = None
        if self.lease is not None or self.priority is not None:
            self.holding = self.manager.hold(self.part, self.mode, requester=REQUESTER, priority=self.priority,
                                             lease=self.lease, timeout=self.timeout)
            self.request = self.holding.request
        else:
            self.request = self.manager.change_mode(self.part, self.mode, timeout=self.timeout, requester=REQUESTER)
        self.feedback_message = f"requested {self._held}"

    def update(self) -> Status:
        """RUNNING while changing and while holding; FAILURE if the change fails."""
        request = self.request
        if request is None:
            return Status.INVALID
        if self.holding is not None:
            self.holding.renew()
        if not request.done:
            self.feedback_message = request.feedback
            return Status.RUNNING
        if not request.succeeded:
            self.feedback_message = request.reason
            return Status.FAILURE
        target = self.manager.target(self.part)
        if self.holding is not None and not self.holding.active:
            self.feedback_message = f"no longer held: {self.holding.reason}"
        elif target == self._held:
            self.feedback_message = f"holding {self.part} in {self._held}"
        else:
            self.feedback_message = f"{self.part} was re-targeted to {target}: it will not be restored"
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        """Give the part back: withdraw the change if in flight, request the previous target."""
        request, self.request = self.request, None
        if self.holding is not None:
            self.holding.release()
            self.holding = None
        if request is None:
            return
        ours = self.manager.target(self.part) == self._held
        if not request.done:
            request.cancel()
        previous = self._previous
        if not ours or previous is None or previous == self._held:
            return
        if previous.state not in RESTORABLE:  # finalized: only a restart brings a node back from there
            self.feedback_message = f"{self.part} was {previous} before: not a target to ask for, left {self._held}"
            return
        self.restore_request = self.manager.change_to(self.part, previous, requester=REQUESTER)
        restoring = f"restoring {self.part} to {previous}"
        # On FAILURE (the change failed) keep why in the feedback, as every FAILURE does.
        self.feedback_message = f"{request.reason}; {restoring}" if new_status is Status.FAILURE else restoring
        self.restore_request.add_done_callback(_report_restore)


#: The targets a part can be taken back to (``change_to``'s).
RESTORABLE = (State.UNCONFIGURED, State.INACTIVE, State.ACTIVE)


def _report_restore(request: Request) -> None:
    if request.succeeded:
        log.info("restored: %s", request.description)
    else:
        log.warning("could not restore (%s): %s", request.description, request.reason)


class HeldModeReady(ManagerBehaviour, register=False):
    """The gate of :func:`hold_mode`'s work: has ``hold`` put its part in the mode?

    * ``update``: RUNNING while the hold's request is in progress (bounded by that request's
      timeout); SUCCESS once it succeeded and the part is still in the mode; FAILURE when the
      request failed, or the part lost the mode before the work could start (it never waits
      for the mode to come back: that wait would have no bound)
    """

    def __init__(self, name: str, hold: HoldMode, *, manager: ModeManager | None = None) -> None:
        super().__init__(name, manager=manager)
        self.hold = hold

    @property
    def detail(self) -> str:
        return self.hold.detail

    def check_model(self, model: Model) -> None:
        self._check_mode(model, self.hold.part, self.hold.mode)

    def update(self) -> Status:
        """RUNNING while the hold's change is in progress, then SUCCESS or FAILURE at once."""
        request = self.hold.request
        if request is None:
            self.feedback_message = "the hold has not started"
            return Status.FAILURE
        if not request.done:
            self.feedback_message = f"waiting for {request.description}"
            return Status.RUNNING
        if not request.succeeded:
            self.feedback_message = request.reason
            return Status.FAILURE
        part, actual = self.hold.part, self.manager.actual(self.hold.part)
        if actual.known and actual.state_mode == self.hold.held:
            self.feedback_message = f"{part} is {actual}"
            return Status.SUCCESS
        self.feedback_message = f"{part} lost {self.hold.held} before the work started (now {actual})"
        return Status.FAILURE


class _Subtree(PortsMixin, register=False):
    """An idiom's subtree as one XML node: ports-enabled, without ports of its own."""

    INPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        if port_remappings:
            raise KeyError(f"{self.name}: no ports (given: {', '.join(port_remappings)})")
        self._subtree_namespace = subtree_namespace


class HoldModeSubtree(_Subtree, py_trees.composites.Parallel, tag="HoldMode"):
    """What :func:`hold_mode` returns; in XML ``<HoldMode name=".." part=".." mode=".."
    [timeout=".."] [lease=".."] [priority=".."]>child</HoldMode>``."""

    def __init__(self, name: str, part: str, mode: str, children: list[py_trees.behaviour.Behaviour] | None = None,
                 timeout: float | None = None, *, manager: ModeManager | None = None, lease: float | None = None,
                 priority: int | None = None, **kwargs: Any) -> None:
        work = list(children or [])
        if len(work) != 1:
            raise ValueError(f"{name}: HoldMode holds its mode while exactly one child runs, not {len(work)}")
        # Names lead with the mode (viewers cut long names short) and hold no ':' (dot reads a port).
        hold = HoldMode(f"Hold {mode}", part, mode, timeout=timeout, manager=manager, lease=lease,
                        priority=None if priority is None else int(priority))
        gated = py_trees.composites.Sequence(f"{mode} work", memory=True, children=[
            HeldModeReady(f"{mode} reached?", hold, manager=manager),
            work[0],
        ])
        super().__init__(name, policy=py_trees.common.ParallelPolicy.SuccessOnOne(), children=[hold, gated],
                         **kwargs)


class SwitchOnDivergenceSubtree(_Subtree, py_trees.composites.Sequence, tag="SwitchOnDivergence"):
    """What :func:`switch_on_divergence` returns; in XML ``<SwitchOnDivergence name=".."
    part=".." system=".." mode=".." [timeout=".."]/>`` (no ``part``: any part)."""

    def __init__(self, name: str, system: str, mode: str, part: str | None = None, timeout: float | None = None,
                 children: list[py_trees.behaviour.Behaviour] | None = None, *, manager: ModeManager | None = None,
                 **kwargs: Any) -> None:
        if children:
            raise ValueError(f"{name}: SwitchOnDivergence has no children of its own (given {len(children)})")
        watched = part or "any part"
        super().__init__(name, memory=True, children=[
            OnDivergence(f"{watched} diverged?", part, manager=manager),
            ChangeMode(f"{mode} on divergence", system, mode, timeout=timeout, manager=manager),
        ], **kwargs)


def hold_mode(name: str, part: str, mode: str, child: py_trees.behaviour.Behaviour,
              timeout: float | None = None, *, lease: float | None = None,
              priority: int | None = None) -> py_trees.behaviour.Behaviour:
    """Run ``child`` with ``part`` held in ``mode``; restore the part's previous target when the
    subtree ends, whether ``child`` succeeded, failed or was interrupted.

    Returns ``Parallel(SuccessOnOne)`` of a :class:`HoldMode` and ``Sequence(memory=True)`` of
    :class:`HeldModeReady` then ``child``: the child starts once the hold's change is confirmed,
    the subtree has the child's result, and it fails if the mode cannot be reached (within
    ``timeout``, or the manager's ``request_timeout``) or is lost before the child starts. With
    ``lease`` or ``priority`` the part is held through the manager (:class:`HoldMode`).
    """
    return HoldModeSubtree(name, part, mode, [child], timeout=timeout, lease=lease, priority=priority)


def switch_on_divergence(name: str, part: str | None, system: str, mode: str,
                         timeout: float | None = None) -> py_trees.behaviour.Behaviour:
    """"When ``part`` diverges from its target, put ``system`` in ``mode``": a rule, in the tree.

    Returns ``Sequence(memory=True)`` of ``OnDivergence(part)`` then ``ChangeMode(system, mode)``.
    Place it in a ``Selector(memory=False)`` of contingencies (with a fallback child): the
    selector re-checks it every tick, and once the divergence is seen the memory sequence keeps
    the mode change running even though switching clears the divergence. FAILURE when there is
    no divergence, else the mode change's result.
    """
    return SwitchOnDivergenceSubtree(name, system, mode, part=part, timeout=timeout)
