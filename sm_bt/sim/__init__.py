"""Simulated lifecycle nodes: the embedded default backend."""

from sm_bt.sim.backend import EventKind, NodeStatus, SimBackend, SimEvent
from sm_bt.sim.node import ParameterRejected, SimNode, TransitionEvent, TransitionRefused, parameter_type

__all__ = [
    "EventKind",
    "NodeStatus",
    "ParameterRejected",
    "SimBackend",
    "SimEvent",
    "SimNode",
    "TransitionEvent",
    "TransitionRefused",
    "parameter_type",
]
