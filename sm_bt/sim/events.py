"""What the simulation records: a simulated node's process status and :class:`SimEvent`\\ s."""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass

from sm_bt.model.types import ParamValue
from sm_bt.sim.node import TransitionEvent


class NodeStatus(str, enum.Enum):
    """Whether a simulated node's process runs and answers."""

    NOT_STARTED = "not started"
    RUNNING = "running"
    CRASHED = "crashed"  # stopped answering, not yet reported vanished
    VANISHED = "vanished"


class SimEventKind(str, enum.Enum):
    REQUEST = "request"  # a change_state / set_parameters call arrived at the backend
    RESPONSE = "response"  # its done() was called
    TRANSITION = "transition"  # a lifecycle TransitionEvent of the node
    PARAMETERS = "parameters"  # parameter values changed (by a set or from outside)
    FAULT = "fault"  # a fault was armed or took effect
    STARTED = "started"  # a node process started (late start, restart)
    VANISHED = "vanished"  # the backend reported the node gone


@dataclass(frozen=True)
class SimEvent:
    """Something that happened in the simulation; ``details`` is a one-line human description."""

    time: float
    node: str
    kind: SimEventKind
    details: str
    transition: TransitionEvent | None = None
    parameters: Mapping[str, ParamValue] | None = None

    def __str__(self) -> str:
        return f"{self.time:8.3f}  {self.node:<20} {self.kind.value:<10} {self.details}"



def format_values(values: Mapping[str, ParamValue]) -> str:
    return "{" + ", ".join(f"{key}: {value!r}" for key, value in values.items()) + "}"


