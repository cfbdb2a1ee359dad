"""Requests: the caller's handle on a change.

A :class:`Request` says how a change goes (``done``, ``succeeded``, ``reason``, ``feedback``);
it never blocks. What carries the change out is the manager's business (:mod:`~sm_bt.engine.plans`,
:mod:`~sm_bt.engine.drivers`).
"""

from __future__ import annotations

import enum
import itertools
import threading
from collections.abc import Callable

from sm_bt.model.states import StateMode


class Origin(str, enum.Enum):
    """Who asked for a change."""

    USER = "user"
    RULE = "rule"
    RECOVERY = "recovery"


_ids = itertools.count(1)


class Request:
    """A change in progress. Poll it (``done``, ``succeeded``, ``reason``, ``feedback``) or add a
    done-callback; ``cancel()`` withdraws it."""

    def __init__(self, part: str, target: StateMode, description: str, origin: Origin, created: float,
                 withdraw: Callable[[Request], None] | None = None, requester: str | None = None,
                 parts: tuple[str, ...] | None = None) -> None:
        self.id = next(_ids)
        self.part = part
        self.target = target
        #: The parts it is about: it succeeds only with each of them at its target. ``(part,)``; for
        #: the continuation of a preempted request, the nodes it carries on with.
        self.parts = parts if parts is not None else (part,)
        self.description = description
        self.origin = origin
        #: Who asked, in a word: the caller's ``requester`` for a user request (``"user"`` unless
        #: said, ``"tree"`` from a behaviour), else ``"rule"`` or ``"recovery"``.
        self.requester = requester or origin.value
        self.created = created
        self.finished: float | None = None
        self.done = False
        self.succeeded = False
        self.reason = ""
        #: Refused as a whole (unknown part or mode, a node out of reach, ...): nothing was changed,
        #: no target, no request in flight. A refused request is done and failed.
        self.refused = False
        #: What happens when it fails by itself: "stay", "rollback" or "mode:<name>"
        #: (:mod:`sm_bt.engine.rollback`; a user request's, the manager's default unless given).
        self.on_failure = "stay"
        #: Makes its plan's preview once asked for (set when it starts: ModeManager.plan_of).
        self._plan: Callable[[], object] | None = None
        self._withdraw = withdraw
        self._progress: Callable[[], str] | None = None  # the step in progress, while running
        self._callbacks: list[Callable[[Request], None]] = []
        # A callback added from another thread (an application's, while the manager's executor
        # finishes the request) must be called once: added before the end, or at once after it.
        self._ending = threading.Lock()

    def cancel(self) -> None:
        """Withdraw the request: no further steps are sent, and the parts' previous targets are
        restored (what already changed is then handled like any other divergence)."""
        if not self.done and self._withdraw is not None:
            self._withdraw(self)

    def add_done_callback(self, callback: Callable[[Request], None]) -> None:
        """Call ``callback(request)`` when done (at once if it already is), from any thread."""
        with self._ending:
            if not self.done:
                self._callbacks.append(callback)
                return
        callback(self)

    @property
    def feedback(self) -> str:
        """What is going on: the step in progress (``"stage 2/3: amcl: activate"``), then the outcome."""
        if self.done:
            return "succeeded" if self.succeeded else f"failed: {self.reason}"
        return self._progress() if self._progress is not None else "queued"

    @property
    def outcome(self) -> str:
        """In a word: ``running``, ``succeeded``, ``failed`` or ``refused``."""
        if not self.done:
            return "running"
        if self.refused:
            return "refused"
        return "succeeded" if self.succeeded else "failed"

    @property
    def elapsed(self) -> float | None:
        return None if self.finished is None else self.finished - self.created

    def _finish(self, succeeded: bool, reason: str, now: float) -> None:
        with self._ending:
            if self.done:
                return
            self.done, self.succeeded, self.reason, self.finished = True, succeeded, reason, now
            self._progress = None
            callbacks, self._callbacks = self._callbacks, []
        for callback in callbacks:
            callback(self)

    def __repr__(self) -> str:
        status = "running" if not self.done else ("succeeded" if self.succeeded else f"failed ({self.reason})")
        return f"<Request #{self.id} {self.description} [{self.origin.value}]: {status}>"
