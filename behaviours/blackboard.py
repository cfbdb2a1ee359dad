"""The state and mode of every part, on the blackboard.

:class:`ModesToBlackboard` copies what the manager infers into one blackboard namespace
(``/system_modes/<part>`` by default) through an attached client, so any behaviour can read it
(``py_trees.behaviours.CheckBlackboardVariableValue`` on ``/system_modes/pilot.mode``, ...) and
tree snapshots show who reads and writes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import py_trees
from py_trees.common import Status

from sm_bt.behaviours.manager_access import ManagerBehaviour
from sm_bt.engine.manager import ModeManager


@dataclass(frozen=True)
class PartStatus:
    """What the blackboard holds for one part. ``divergence`` is the cause (``"fault"``,
    ``"grace"``, ...) while the part is off its target, else ``None``."""

    part: str
    state: str
    mode: str | None
    target_state: str | None
    target_mode: str | None
    divergence: str | None

    @property
    def state_mode(self) -> str:
        """``"active.FAST"``, ``"inactive"``: the reference's notation."""
        return f"{self.state}.{self.mode}" if self.mode else self.state

    def __str__(self) -> str:
        return self.state_mode


def part_status(manager: ModeManager, part: str) -> PartStatus:
    actual = manager.actual(part)
    target = manager.target(part)
    divergence = manager.divergence(part)
    return PartStatus(
        part=part,
        state=actual.state.label,
        mode=actual.mode,
        target_state=target.state.label if target else None,
        target_mode=target.mode if target else None,
        divergence=divergence.cause.value if divergence else None,
    )


class ModesToBlackboard(ManagerBehaviour):
    """Write a :class:`PartStatus` for every part (or the given ``parts``) under ``namespace``.

    * ``setup``: register write access to one key per part on an attached blackboard client
    * ``update``: write the parts whose status changed since the last tick; always SUCCESS

    Put it first in the tree (as py_trees' "data gathering" idiom) so the rest of the tick sees
    fresh values.
    """

    def __init__(self, name: str = "Modes to Blackboard", namespace: str = "/system_modes",
                 parts: list[str] | None = None) -> None:
        super().__init__(name)
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

    def validate(self, manager: ModeManager) -> None:
        for part in self.parts or ():
            self._check_part(manager, part)

    def update(self) -> Status:
        """Copy what changed; SUCCESS (there is nothing to wait for)."""
        manager = self.manager  # NotSetUp when ticked without setup (parts are only known then)
        changed = 0
        for part in self.parts or ():
            status = part_status(manager, part)
            if self._written.get(part) != status:
                self.blackboard.set(part, status)
                self._written[part] = status
                changed += 1
        self.feedback_message = f"{changed} part(s) changed"
        return Status.SUCCESS
