"""The state and mode of every part, on the blackboard.

:class:`ModesToBlackboard` copies what the manager infers into one blackboard namespace
(``/system_modes/<part>`` by default) through an attached client, so any behaviour can read it
(``py_trees.behaviours.CheckBlackboardVariableValue`` on ``/system_modes/pilot.mode``, ...) and
tree snapshots show who reads and writes it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.manager_access import ManagerBehaviour
from sm_bt.engine.clock import Clock
from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model


@dataclass(frozen=True)
class PartStatus:
    """What the blackboard holds for one part; ``str()`` tells it in one line, as watchers and
    viewers show it: ``active.f_slow_mode (target active.f_slow_mode)``, ``unconfigured (target
    active: fault for 1.1 s)``.

    ``divergence`` is the cause (``"fault"``, ``"grace"``, ...) while the part is off its target,
    else ``None``; ``since`` is when that began (the manager's clock), and ``clock`` lets ``str()``
    say for how long. Every field has a default, so blackboard tools list them all.
    """

    part: str = ""
    state: str = "unknown"
    mode: str | None = None
    target_state: str | None = None
    target_mode: str | None = None
    divergence: str | None = None
    since: float | None = field(default=None, compare=False)
    clock: Clock | None = field(default=None, compare=False, repr=False)

    @property
    def state_mode(self) -> str:
        """``"active.FAST"``, ``"inactive"``: the reference's notation."""
        return f"{self.state}.{self.mode}" if self.mode else self.state

    @property
    def target(self) -> str | None:
        """The target in the same notation, or ``None`` before anything was asked of the part."""
        if self.target_state is None:
            return None
        return f"{self.target_state}.{self.target_mode}" if self.target_mode else self.target_state

    def __str__(self) -> str:
        target = self.target
        if target is None:
            return f"{self.state_mode} (no target)"
        if self.divergence is None:
            return f"{self.state_mode} (target {target})"
        lasted = ""
        if self.since is not None and self.clock is not None:
            lasted = f" for {max(0.0, self.clock.now() - self.since):.1f} s"
        return f"{self.state_mode} (target {target}: {self.divergence}{lasted})"


def part_status(manager: ModeManager, part: str) -> PartStatus:
    status = manager.status(part)
    actual, target, divergence = status.actual, status.target, status.divergence
    return PartStatus(
        part=part,
        state=actual.state.label,
        mode=actual.mode,
        target_state=target.state.label if target else None,
        target_mode=target.mode if target else None,
        divergence=divergence.cause.value if divergence else None,
        since=divergence.since if divergence else None,
        clock=manager.clock,
    )


class ModesToBlackboard(ManagerBehaviour):
    """Write a :class:`PartStatus` for every part (or the given ``parts``) under ``namespace``.

    * ``setup``: register write access to one key per part on an attached blackboard client
    * ``update``: write the parts whose status changed since the last tick (a divergence that
      began again counts as a change); always SUCCESS

    Put it first in the tree (as py_trees' "data gathering" idiom) so the rest of the tick sees
    fresh values.
    """

    def __init__(self, name: str = "Modes to Blackboard", namespace: str = "/system_modes",
                 parts: list[str] | None = None, *, manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, manager=manager, **kwargs)
        self.namespace = namespace.rstrip("/") or "/"
        self.parts = list(parts) if parts is not None else None
        self.blackboard = self.attach_blackboard_client(name, namespace=self.namespace)
        self._written: dict[str, PartStatus] = {}

    def setup(self, **kwargs: Any) -> None:
        super().setup(**kwargs)
        self.parts = list(self.parts if self.parts is not None else self.manager.model.parts)
        for part in self.parts:
            self.blackboard.register_key(part, access=py_trees.common.Access.WRITE)
        self._written.clear()

    def check_model(self, model: Model) -> None:
        for part in self.parts or ():
            self._check_part(model, part)

    def update(self) -> Status:
        """Copy what changed; SUCCESS (there is nothing to wait for)."""
        manager = self.manager  # NotSetUp when ticked without setup (parts are only known then)
        changed = 0
        for part in self.parts or ():
            status = part_status(manager, part)
            written = self._written.get(part)
            if written is None or written != status or written.since != status.since:
                self.blackboard.set(part, status)
                self._written[part] = status
                changed += 1
        self.feedback_message = f"{changed} part(s) changed"
        return Status.SUCCESS
