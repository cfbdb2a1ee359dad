"""The state and mode of every part, on the blackboard.

:class:`ModesToBlackboard` copies what the manager infers into one blackboard namespace
(``/system_modes/<part>`` by default) through an attached client, so any behaviour can read it
(``py_trees.behaviours.CheckBlackboardVariableValue`` on ``/system_modes/pilot.mode``, ...) and
tree snapshots show who reads and writes it.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.manager_access import ManagerBehaviour
from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import Model

#: Clock readings above this are seconds since the epoch (a wall clock), below it a virtual clock's.
_EPOCH_READINGS = 1e8


@dataclass(frozen=True)
class PartStatus:
    """What the blackboard holds for one part; ``str()`` tells it in one line, as watchers and
    viewers show it: ``active.f_slow_mode (target active.f_slow_mode)``, ``unconfigured (target
    active: fault since 14:02:31)``.

    ``divergence`` is the cause (``"fault"``, ``"grace"``, ...) while the part is off its target,
    else ``None``; ``since`` is when that began (the manager's clock: a wall clock's time of day, or
    ``t=12.3 s`` on a virtual clock). Plain data only, so py_trees_ros can copy and pickle it to
    tell blackboard watchers what changed; every field has a default, so blackboard tools list
    them all.
    """

    part: str = ""
    state: str = "unknown"
    mode: str | None = None
    target_state: str | None = None
    target_mode: str | None = None
    divergence: str | None = None
    since: float | None = field(default=None, compare=False)

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
        since = ""
        if self.since is not None:
            since = f" since {time.strftime('%H:%M:%S', time.localtime(self.since))}" \
                if self.since > _EPOCH_READINGS else f" since t={self.since:.1f} s"
        return f"{self.state_mode} (target {target}: {self.divergence}{since})"


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
        self._written.clear()
        if self.parts is not None or self._manager is not None:  # else the manager names them later
            self._register(self.manager.model.parts if self.parts is None else self.parts)

    def _register(self, parts: Iterable[str]) -> None:
        self.parts = list(parts)
        for part in self.parts:
            self.blackboard.register_key(part, access=py_trees.common.Access.WRITE)

    def check_model(self, model: Model) -> None:
        for part in self.parts or ():
            self._check_part(model, part)

    def update(self) -> Status:
        """Copy what changed; SUCCESS (there is nothing to wait for)."""
        manager = self.manager  # NotSetUp when there is still no manager
        if self.parts is None:  # set up before its manager was attached: every part of its model
            self._register(manager.model.parts)
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
