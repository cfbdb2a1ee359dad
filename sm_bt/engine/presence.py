"""What the backend reports of the nodes (appeared, state, parameters, vanished), applied.

A node that vanishes fails the requests that drive it at once (not when one of their calls times
out); one that comes back is reported with what changed while it was away (:class:`NodeReturn`), and
its rules' and recovery's budget is whole again. A node that comes back from ``finalized`` is a
new process: it starts a new life (:meth:`NodeReports._new_life`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass

from sm_bt.engine.backend import NodeReport
from sm_bt.engine.clock import Clock
from sm_bt.engine.divergences import Divergences
from sm_bt.engine.drivers import NodeDriver
from sm_bt.engine.executions import Executions
from sm_bt.engine.hierarchy import Hierarchy, child_targets
from sm_bt.engine.ledger import Ledger
from sm_bt.engine.serialiser import Serialiser
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import ParamValue, SystemPart

log = logging.getLogger("sm_bt.manager")
_FINALIZED = State.FINALIZED  # read once: an enum's member is slow to look up


@dataclass(frozen=True)
class NodeReturn:
    """A node that had vanished, back: how long it was away, and its state and mode before and after."""

    node: str
    away: float  # seconds
    before: StateMode
    after: StateMode

    @property
    def changed(self) -> bool:
        return self.before != self.after

    def describe(self) -> str:
        """``unconfigured (back after 4.2 s; was active.f_normal)``, or ``... (back after 4.2 s, as before)``."""
        if self.changed:
            return f"{self.after} (back after {self.away:.1f} s; was {self.before})"
        return f"{self.after} (back after {self.away:.1f} s, as before)"


class NodeReports:
    """The manager's :class:`~sm_bt.engine.backend.BackendListener`: each report inside an entry
    of ``serialiser``, applied to ``ledger`` and the node's driver."""

    def __init__(self, ledger: Ledger, divergences: Divergences, executions: Executions, hierarchy: Hierarchy,
                 drivers: Mapping[str, NodeDriver], serialiser: Serialiser, clock: Clock, *,
                 renew_budgets: Callable[[Iterable[str]], None]) -> None:
        self._ledger = ledger
        self._inference = ledger.inference
        self._divergences = divergences
        self._executions = executions
        self._hierarchy = hierarchy
        self._drivers = drivers
        self._serialiser = serialiser
        self._clock = clock
        self._renew_budgets = renew_budgets
        self._away: dict[str, tuple[float, StateMode]] = {}  # vanished nodes: since when, and as they were
        self.returns: dict[str, NodeReturn] = {}  # the last time each node came back

    def batch(self) -> AbstractContextManager[None]:
        """One entry for everything made inside: the manager settles once, when it ends."""
        return self._serialiser

    def node_appeared(self, node: str, report: NodeReport) -> None:
        with self._serialiser:
            away = self._away.pop(node, None)
            if away is None:
                log.info("node %s appeared: %s%s", node, report.state.label,
                         "" if report.lifecycle else " (parameters only)")
            self._renew_budgets([node])
            self._drivers[node].node_appeared(report.state)
            self._ledger.apply(self._inference.node_appeared(node, report.state, report.parameters, report.lifecycle))
            self._new_life(node, report.state)
            if away is not None:  # what changed while it was out of reach (recovery logs what it does)
                since, before = away
                after = self._inference.actual(node).state_mode
                back = NodeReturn(node, self._clock.now() - since, before, after)
                self.returns[node] = back
                log.info("node %s appeared: %s", node, back.describe())
            self._drivers[node].advance()

    def node_state(self, node: str, state: State) -> None:
        with self._serialiser:
            # Nothing leaves finalized: a finalized node heard in another state is a new process
            # (restarted too quickly to be seen gone in between).
            reborn = self._inference.observation(node).state is _FINALIZED and state is not _FINALIZED
            self._ledger.apply(self._inference.node_state(node, state))
            if reborn:
                self._renew_budgets([node])
                self._new_life(node, state)
            self._drivers[node].state_reported(state)
            self._drivers[node].advance()

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        with self._serialiser:
            self._ledger.apply(self._inference.node_parameters(node, changed))
            self._drivers[node].parameters_reported()
            self._drivers[node].advance()

    def node_vanished(self, node: str, reason: str) -> None:
        with self._serialiser:
            log.warning("node %s vanished: %s", node, reason)
            self._away.setdefault(node, (self._clock.now(), self._inference.actual(node).state_mode))
            self._ledger.apply(self._inference.node_vanished(node, reason))
            # A request that needs it cannot complete while it is out of reach: it ends now, not
            # when one of its calls times out (a node that waits for its turn has none in flight).
            for execution in self._executions.driving(node):
                self._executions.finish(execution, False, f"{node} is not reachable ({reason})")
            self._drivers[node].advance()

    def _new_life(self, node: str, state: State) -> None:
        """A node whose target is ``finalized`` appeared alive: it was restarted, and starts a new
        life. Its target becomes what its system's target needs of it (the first parent with a
        target that asks something of it, unless that is ``finalized`` too), else the state it came
        back in; from then on it is a node like any other (requests include it, recovery restores
        it). Without this, the manager would shut every new process of it down again."""
        target = self._inference.target(node)
        if target is None or target.state is not State.FINALIZED or state is State.FINALIZED:
            return
        wanted: StateMode | None = StateMode(state) if state.is_primary else None
        why = "the state it came back in"
        for parent in self._hierarchy.parents[node]:
            parent_target = self._inference.target(parent)
            spec = self._ledger.model.parts[parent]
            if parent_target is None or not isinstance(spec, SystemPart):
                continue
            asked = dict(child_targets(spec, parent_target)).get(node)
            if asked is not None and asked.state is not State.FINALIZED:
                wanted, why = asked, f"what {parent}'s target {parent_target} needs"
                break
        log.info("node %s came back after being finalized: a new life, its target now %s (%s)", node,
                 wanted if wanted is not None else "none", why)
        self._ledger.set_target(node, wanted)
        self._divergences.chosen(node, None)
