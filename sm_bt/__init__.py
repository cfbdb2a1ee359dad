"""sm_bt: system modes for py_trees mission trees.

Reconfigure a ROS 2 robot by *mode* instead of by node: load an SMH model, put a
:class:`ModeManager` over a backend (the embedded simulated one, :class:`sm_bt.sim.SimBackend`,
by default), and ask for modes; the manager plans, executes and confirms the change.
"""

import logging

from sm_bt.engine.events import Cause, Divergence, Event, EventKind, Subscription
from sm_bt.engine.inference import Actual
from sm_bt.engine.lifecycle import Transition
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.preview import Preview, configuration
from sm_bt.engine.requests import Origin, Request
from sm_bt.model.errors import Error, ModelError, RequestError
from sm_bt.model.loader import load_model
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model

# A library leaves logging configuration to the application.
logging.getLogger("sm_bt").addHandler(logging.NullHandler())

__all__ = [
    "Actual",
    "Cause",
    "Divergence",
    "Error",
    "Event",
    "EventKind",
    "ModeManager",
    "Model",
    "ModelError",
    "Origin",
    "Preview",
    "Request",
    "RequestError",
    "State",
    "StateMode",
    "Subscription",
    "Transition",
    "configuration",
    "load_model",
]
