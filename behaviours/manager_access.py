"""How behaviours reach the embedded mode manager: ``tree.setup(manager=...)``.

py_trees hands runtime objects to behaviours through ``setup(**kwargs)``; every sm_bt behaviour
takes the manager from there and checks the part (and mode) it was built for against the
manager's model, so a typo fails at set-up with the part's real names, not at the first tick.
"""

from __future__ import annotations

from typing import Any

import py_trees

from sm_bt.engine.manager import ModeManager
from sm_bt.model.types import DEFAULT_MODE


class NotSetUp(RuntimeError):
    """A behaviour was ticked without a manager (``tree.setup(manager=...)`` was not called)."""


def _hint(behaviour: py_trees.behaviour.Behaviour) -> str:
    return (f"{behaviour.qualified_name}: no mode manager; set the tree up with "
            "tree.setup(manager=ModeManager(model, backend))")


def require_mode_name(behaviour: str, part: str, mode: str) -> None:
    """``ValueError`` for an empty mode name: ``__DEFAULT__`` is the explicit name of the default."""
    if not mode:
        raise ValueError(f"{behaviour}: the mode name of {part} is empty (name a mode, or {DEFAULT_MODE} "
                         "for the default mode)")


class ManagerBehaviour(py_trees.behaviour.Behaviour):
    """A behaviour that works through a :class:`ModeManager`.

    ``setup(manager=...)`` stores the manager and validates the behaviour's configuration (see
    :meth:`validate`); it raises :class:`NotSetUp` when no manager is given and ``ValueError``
    for a part or mode the model does not have.
    """

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self._manager: ModeManager | None = None

    def setup(self, **kwargs: Any) -> None:
        manager = kwargs.get("manager")
        if manager is None:
            raise NotSetUp(_hint(self))
        if not isinstance(manager, ModeManager):
            raise TypeError(f"{self.qualified_name}: manager= must be a ModeManager, not {type(manager).__name__}")
        self.validate(manager)
        self._manager = manager

    @property
    def manager(self) -> ModeManager:
        if self._manager is None:
            raise NotSetUp(_hint(self))
        return self._manager

    def validate(self, manager: ModeManager) -> None:
        """Check the configuration against ``manager.model``; raise ``ValueError`` if it is wrong."""

    # -- shared checks -------------------------------------------------------------------------

    def _check_part(self, manager: ModeManager, part: str) -> None:
        if part not in manager.model.parts:
            raise ValueError(f"{self.qualified_name}: unknown part {part!r} "
                             f"(parts: {', '.join(manager.model.parts)})")

    def _check_mode(self, manager: ModeManager, part: str, mode: str) -> str:
        """The mode name ``mode`` stands for (``__DEFAULT__`` is the part's default mode)."""
        self._check_part(manager, part)
        require_mode_name(self.name, part, mode)
        spec = manager.model.parts[part]
        if mode in spec.modes:
            return mode
        if mode == DEFAULT_MODE:
            return spec.default_mode
        raise ValueError(f"{self.qualified_name}: {part} has no mode {mode!r} "
                         f"(modes: {', '.join(manager.available_modes(part))})")
