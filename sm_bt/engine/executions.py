"""An execution: a request being carried out, with its plan and what the manager keeps for it."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from sm_bt.engine.clock import TimerHandle
from sm_bt.engine.drivers import NodeDriver
from sm_bt.engine.plans import Sequence, Step, build_plan
from sm_bt.engine.requests import Origin, Request
from sm_bt.model.states import StateMode
from sm_bt.model.types import Model


class Host(Protocol):
    """The manager, as an execution sees it."""

    model: Model

    def later(self, action: Callable[[], None]) -> None: ...

    def driver(self, node: str) -> NodeDriver: ...

    def confirm(self, execution: Execution) -> None: ...

    def finish(self, execution: Execution, succeeded: bool, reason: str) -> None: ...


class Execution:
    """``request`` in progress: its plan over ``scope`` (the nodes it drives), and the targets it
    replaced (restored if it is withdrawn).

    A *continuation* (``continuation=True``) carries on with the nodes of a preempted request
    that the preempting one does not drive: its plan holds only those nodes, and it is done when
    they reached their goals (the part as a whole is no longer expected to reach the target).
    """

    def __init__(self, host: Host, request: Request, scope: frozenset[str],
                 previous_targets: dict[str, tuple[StateMode | None, Origin | None]],
                 continuation: bool = False) -> None:
        self.host = host
        self.request = request
        self.scope = scope
        self.previous_targets = previous_targets
        self.continuation = continuation
        self.active = True
        self.planned = False  # every step reached its goal; waiting for the part's actual to confirm
        self.timer: TimerHandle | None = None
        self.root, self.steps = build_plan(host.model, self, request.part, request.target,
                                           scope if continuation else None)

    # -- the plan's run (see plans.Run) ---------------------------------------------------------

    def later(self, action: Callable[[], None]) -> None:
        self.host.later(action)

    def driver(self, node: str) -> NodeDriver:
        return self.host.driver(node)

    def plan_done(self) -> None:
        if self.active:
            self.planned = True
            self.host.confirm(self)

    def plan_failed(self, reason: str) -> None:
        if self.active:
            self.host.finish(self, False, reason)

    # -- life -----------------------------------------------------------------------------------

    def start(self) -> None:
        self.later(self.root.start)

    def stop(self) -> None:
        """No further steps: the drivers are released (calls in flight still complete)."""
        self.active = False
        if self.timer is not None:
            self.timer.cancel()
        for step in self.steps:
            step.release()

    # -- what it is doing -----------------------------------------------------------------------

    def _running(self) -> list[Step]:
        return [s for s in self.steps if s.started and not s.done]

    def feedback(self) -> str:
        if self.planned:
            return f"confirming {self.request.part} is {self.request.target}"
        running = self._running()
        text = "; ".join(self.driver(s.node).describe() for s in running) or "starting"
        root = self.root
        if isinstance(root, Sequence) and len(root.children) > 1 and root.index < len(root.children):
            return f"stage {root.index + 1}/{len(root.children)}: {text}"
        return text

    def stall(self) -> str:
        """Why it is not done yet (for a timeout)."""
        running = self._running()
        if not running:
            return self.feedback()
        return "; ".join(self.driver(s.node).stall() for s in running)
