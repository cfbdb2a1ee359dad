"""One read model of the manager: a part as the manager knows it at one moment.

Every view of the manager (``sm-bt monitor``, the blackboard, ``/diagnostics``) renders
:class:`PartSnapshot` values that :meth:`~sm_bt.engine.manager.ModeManager.status` and
:meth:`~sm_bt.engine.manager.ModeManager.snapshot` gather under the manager's lock, as py_trees
gathers a tree's snapshot once and renders it many times.
"""

from __future__ import annotations

from dataclasses import dataclass

from sm_bt.engine.events import Divergence
from sm_bt.engine.inference import Actual
from sm_bt.engine.presence import NodeReturn
from sm_bt.model.states import StateMode
from sm_bt.model.types import PartKind


@dataclass(frozen=True)
class PartSnapshot:
    """``part`` at one moment: its inferred ``actual``, its ``target`` (None before anything was
    asked of it), its ``divergence`` (None on target), and whether rules and recovery gave up on
    it; ``held_by``: who holds it, and until when (:mod:`~sm_bt.engine.holds`; "" when nobody).
    For a node also: whether the backend reaches it (``reachable``; ``gone`` says why not) and how
    it came back the last time it had vanished."""

    part: str
    kind: PartKind
    actual: Actual
    target: StateMode | None
    divergence: Divergence | None
    gave_up: bool = False
    reachable: bool | None = None  # None for a system
    gone: str = ""
    last_return: NodeReturn | None = None
    held_by: str = ""

    @property
    def is_node(self) -> bool:
        return self.kind is PartKind.NODE
