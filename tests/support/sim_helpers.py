"""Helpers for the simulated-backend tests: tiny models built in code, and a recording listener."""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import AbstractContextManager
from types import TracebackType
from typing import Any

from sm_bt.engine.backend import NodeReport
from sm_bt.model.states import State
from sm_bt.model.types import DEFAULT_MODE, Location, Model, NodeMode, NodePart, ParamSpec, ParamValue
from sm_bt.sim import SimBackend

LOC = Location("test.yaml", 1)


def node_part(name: str, params: Mapping[str, ParamValue]) -> NodePart:
    """A node with only a default mode holding ``params``."""
    specs = {key: ParamSpec(key, value, LOC) for key, value in params.items()}
    return NodePart(name, DEFAULT_MODE, {DEFAULT_MODE: NodeMode(DEFAULT_MODE, specs, LOC)}, (), LOC)


def model_of(*parts: NodePart) -> Model:
    return Model("test.yaml", {p.name: p for p in parts})


class Recorder:
    """A BackendListener that keeps every report as (kind, node, payload)."""

    def __init__(self) -> None:
        self.reports: list[tuple[str, str, Any]] = []
        #: (first, end) indices into ``reports`` of each batch that had reports in it.
        self.batches: list[tuple[int, int]] = []

    def node_appeared(self, node: str, report: NodeReport) -> None:
        self.reports.append(("appeared", node, report))

    def node_state(self, node: str, state: State) -> None:
        self.reports.append(("state", node, state))

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        self.reports.append(("parameters", node, dict(changed)))

    def node_vanished(self, node: str, reason: str) -> None:
        self.reports.append(("vanished", node, reason))

    def batch(self) -> AbstractContextManager[None]:
        """Notes where each batch began and ended in :attr:`reports` (as ``batches``)."""
        return _Batch(self)

    def states(self, node: str) -> list[State]:
        return [p for kind, n, p in self.reports if kind == "state" and n == node]

    def about(self, node: str) -> list[tuple[str, Any]]:
        return [(kind, payload) for kind, n, payload in self.reports if n == node]


class _Batch:
    def __init__(self, recorder: Recorder) -> None:
        self._recorder = recorder
        self._first = 0

    def __enter__(self) -> None:
        self._first = len(self._recorder.reports)

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        end = len(self._recorder.reports)
        if end > self._first:
            self._recorder.batches.append((self._first, end))


def attached(model: Model, **options: Any) -> tuple[SimBackend, Recorder]:
    """A backend over ``model`` with a recorder attached to every node, initial reports cleared."""
    backend = SimBackend(model, **options)
    recorder = Recorder()
    backend.attach(backend.nodes, recorder)
    recorder.reports.clear()
    return backend, recorder
