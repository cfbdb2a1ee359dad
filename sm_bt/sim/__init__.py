"""Simulated lifecycle nodes (the embedded default backend) and :class:`SimulatedSystem`: a model
run by a mode manager over them, on a virtual clock."""

from sm_bt.sim.backend import SimBackend
from sm_bt.sim.events import NodeStatus, SimEvent, SimEventKind
from sm_bt.sim.node import ParameterRejected, SimNode, TransitionEvent, TransitionRefused, parameter_type
from sm_bt.sim.system import NotReached, SimulatedSystem, Tick, tick_until

__all__ = [
    "NodeStatus",
    "NotReached",
    "ParameterRejected",
    "SimBackend",
    "SimEvent",
    "SimEventKind",
    "SimNode",
    "SimulatedSystem",
    "Tick",
    "TransitionEvent",
    "TransitionRefused",
    "parameter_type",
    "tick_until",
]
