"""``OnDivergence``: a condition that fires when a part strays from its target."""

from __future__ import annotations

from typing import Any

import py_trees
from py_trees.common import Status
from py_trees.ports import PortInformation

from sm_bt.behaviours.manager_access import ManagerBehaviour, flag
from sm_bt.engine.events import Divergence
from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model


class OnDivergence(ManagerBehaviour):
    """Does ``part`` (or, with ``part=None``, any part) diverge from its target?

    SUCCESS when the manager reports a divergence that is an error: it lasted beyond the grace
    period and no request explains it (a node left its target by itself, or was changed behind
    the manager's back); FAILURE otherwise. Never RUNNING, so it fits guards and selectors.

    On SUCCESS the :class:`~sm_bt.engine.events.Divergence` (``part``, ``target``, ``actual``,
    ``since`` on the manager's clock, ``cause``) is written to the blackboard under
    ``variable_name`` for the recovery subtree to read; with ``part=None`` it is the lowest
    diverging part (a node before its systems: the likely cause). On FAILURE the variable is
    removed, so a stale divergence is never read. The key is written or removed only when its
    value changes (activity views show changes, not every tick). ``errors_only=False`` also
    fires on transient divergences (a request in flight, the grace period).

    In XML the output is the ``divergence`` port: ``<OnDivergence part="pilot" divergence="{fault}"/>``.
    """

    OUTPUT_PORTS = {  # noqa: RUF012 (py_trees' read-only class declaration)
        "divergence": PortInformation(Divergence, required=False,
                                      description="the divergence found (unset when there is none)"),
    }

    def __init__(self, name: str, part: str | None = None, variable_name: str = "divergence",
                 errors_only: bool = True, *, manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        self.part = part
        self.variable_name = variable_name
        self.errors_only = flag(name, errors_only, "errors_only")
        self.blackboard = self.attach_blackboard_client(name)
        self.blackboard.register_key(variable_name, access=py_trees.common.Access.WRITE)
        self._written: Divergence | None = None

    WIRED_PORTS = frozenset({"divergence"})

    def wire_port(self, port: str, key: str) -> None:
        """The ``divergence`` port (XML) takes the place of ``variable_name``."""
        self.blackboards.remove(self.blackboard)
        self.blackboard = self.attach_blackboard_client(self.name)
        self.variable_name = port
        self.blackboard.register_key(port, access=py_trees.common.Access.WRITE, remap_to=key)

    @property
    def detail(self) -> str:
        return self.part or "any part"

    def check_model(self, model: Model) -> None:
        if self.part is not None:
            self._check_part(model, self.part)

    def update(self) -> Status:
        """SUCCESS and write the divergence if there is one, FAILURE (and clear it) if not."""
        found = self.manager.divergences(errors_only=self.errors_only)
        if self.part is not None:
            found = [d for d in found if d.part == self.part]
        if not found:
            if self._written is not None or self.blackboard.exists(self.variable_name):
                self.blackboard.unset(self.variable_name)
            self._written = None
            self.feedback_message = f"{self.part or 'every part'} on target"
            return Status.FAILURE
        divergence = found[0]
        if divergence != self._written:
            self.blackboard.set(self.variable_name, divergence)
            self._written = divergence
        since = self.manager.clock.now() - divergence.since
        more = f" (+{len(found) - 1} more)" if len(found) > 1 else ""
        self.feedback_message = f"{divergence} for {since:.1f} s{more}"
        return Status.SUCCESS
