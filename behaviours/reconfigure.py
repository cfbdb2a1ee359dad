"""``Reconfigure``: a reasoner chooses the mode, the tree requests it."""

from __future__ import annotations

from typing import Any

from py_trees.common import Status

from sm_bt.behaviours.change import _RequestBehaviour
from sm_bt.behaviours.manager_access import REQUESTER
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.types import Model
from sm_bt.reasoner import Reasoner


class Reconfigure(_RequestBehaviour):
    """Ask ``reasoner`` for the best realisable mode of its part and put the part in it.

    * ``initialise``: the reasoner decides from the component statuses it holds and, unless the
      part is already targeted at that mode, requests it (``Reasoner.reconfigure``)
    * ``update``: SUCCESS when nothing needed changing or the change is confirmed; RUNNING while
      it is in progress; FAILURE when no design is realisable (feedback: the reasoner's
      explanation) or the change failed (the manager's reason)
    * ``terminate``: withdraw the change when interrupted while RUNNING

    Tick it when the statuses change (``reasoner.changed``), for instance behind a condition.
    """

    def __init__(self, name: str, reasoner: Reasoner, timeout: float | None = None, *,
                 manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, reasoner.part, timeout, manager=manager, **kwargs)
        self.reasoner = reasoner
        self.decision_text = ""

    def check_model(self, model: Model) -> None:
        self._check_part(model, self.part)
        try:
            self.reasoner.check(model)
        except ValueError as error:
            raise ValueError(f"{self.qualified_name}: {error}") from None

    def _make_request(self, manager: ModeManager) -> Request | None:
        """Decide, then request the chosen mode if the part is not already targeted at it."""
        request = self.reasoner.reconfigure(manager, timeout=self.timeout, requester=REQUESTER)
        decision = self.reasoner.last_decision
        self.decision_text = decision.explanation if decision is not None else ""
        return request

    def update(self) -> Status:
        """SUCCESS (nothing to change, or confirmed), RUNNING, or FAILURE (see the class)."""
        if self.request is not None:
            status = super().update()
            if status is Status.SUCCESS:  # keep why this mode was chosen visible
                self.feedback_message = f"{self.decision_text} -> {self.feedback_message}"
            return status
        decision = self.reasoner.last_decision
        self.feedback_message = self.decision_text
        if decision is None or decision.design is None:
            return Status.FAILURE
        return Status.SUCCESS
