"""What a simulated backend tells its listener, and when: at once, or ``delay`` seconds later in
order (as ROS 2 may deliver a node's events after the answer to the call that caused them)."""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping

from sm_bt.engine.backend import BackendListener, NodeReport
from sm_bt.engine.clock import VirtualClock
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue


class Reports:
    """The listener of the nodes it watches; a node is *visible* from its appearance until it vanishes
    or the listener detaches, and only visible nodes' states and parameters are reported."""

    def __init__(self, clock: VirtualClock, delay: float) -> None:
        self._clock = clock
        self.delay = delay
        self._listener: BackendListener | None = None
        self._watched: frozenset[str] = frozenset()
        self._visible: set[str] = set()

    def attach(self, nodes: Collection[str], listener: BackendListener) -> None:
        self._listener = listener
        self._watched = frozenset(nodes)
        self._visible = set()

    def detach(self) -> None:
        self._listener = None
        self._watched = frozenset()
        self._visible = set()

    def watched(self, node: str) -> bool:
        return node in self._watched

    def visible(self, node: str) -> bool:
        return node in self._visible

    def appeared(self, node: str, report: NodeReport) -> None:
        if self._listener is not None:
            self._visible.add(node)
            self._send(lambda listener: listener.node_appeared(node, report))

    def state(self, node: str, state: State) -> None:
        if node in self._visible:
            self._send(lambda listener: listener.node_state(node, state))

    def parameters(self, node: str, values: Mapping[str, ParamValue]) -> None:
        if values and node in self._visible:
            changed = dict(values)
            self._send(lambda listener: listener.node_parameters(node, changed))

    def vanished(self, node: str, reason: str) -> None:
        if node in self._visible:
            self._visible.discard(node)
            self._send(lambda listener: listener.node_vanished(node, reason))

    def _send(self, deliver: Callable[[BackendListener], None]) -> None:
        """Tell the listener now, or ``delay`` later (in order: equal delays run FIFO); a report still
        on its way when the listener detaches is dropped."""
        listener = self._listener
        if listener is None:
            return
        if self.delay == 0:
            deliver(listener)
            return

        def deferred() -> None:
            if self._listener is listener:
                deliver(listener)

        self._clock.call_later(self.delay, deferred)
