"""Helpers for engine tests: a manager over simulated nodes, and a way to let time pass."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from sm_bt.bundled import path
from sm_bt.engine.events import Event, EventKind
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.loader import load_model
from sm_bt.model.types import Model
from sm_bt.sim import SimBackend

MODELS = Path(__file__).parent / "models"


def bundled(name: str) -> Model:
    return load_model(path(name), strict=True)


def fixture(name: str) -> Model:
    return load_model(MODELS / f"{name}.yaml")


class Rig:
    """A manager over a simulated backend, recording every event it emits."""

    def __init__(self, model: Model, **options: Any) -> None:
        sim_options = {k: options.pop(k) for k in list(options) if k in SIM_OPTIONS}
        self.backend = SimBackend(model, **sim_options)
        self.clock = self.backend.clock
        self.manager = ModeManager(model, self.backend, **options)
        self.events: list[Event] = []
        self.manager.subscribe(self.events.append)

    def run(self, seconds: float, step: float = 0.01) -> None:
        end = self.clock.now() + seconds
        while self.clock.now() < end - 1e-9:
            self.clock.advance(min(step, end - self.clock.now()))

    def until(self, condition: Callable[[], bool], limit: float = 60.0, step: float = 0.01) -> float:
        """Advance until ``condition()`` holds; return the virtual time it took. Fails at ``limit``."""
        start = self.clock.now()
        while not condition():
            if self.clock.now() - start > limit:
                raise AssertionError(f"condition not met within {limit} s of virtual time")
            self.clock.advance(step)
        return self.clock.now() - start

    def finish(self, request: Request, limit: float = 60.0) -> Request:
        self.until(lambda: request.done, limit)
        return request

    def kinds(self, kind: EventKind, part: str | None = None) -> list[Event]:
        return [e for e in self.events if e.kind is kind and (part is None or e.part == part)]

    def state(self, part: str) -> str:
        return str(self.manager.actual(part))


SIM_OPTIONS = {"transition_delay", "error_delay", "parameter_delay", "vanish_after", "initial_state", "report_delay",
               "initial_parameters", "clock", "late"}
