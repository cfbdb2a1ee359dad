"""Models for tests: bundled ones (strictly loaded) and the test models of tests/models/. A manager over
simulated nodes with time in the test's hands is :class:`sm_bt.sim.SimulatedSystem`."""

from __future__ import annotations

from pathlib import Path

from sm_bt.bundled import path
from sm_bt.model.loader import load_model
from sm_bt.model.types import Model

MODELS = Path(__file__).parents[1] / "models"


def bundled(name: str) -> Model:
    return load_model(path(name), strict=True)


def fixture(name: str) -> Model:
    return load_model(MODELS / f"{name}.yaml")
