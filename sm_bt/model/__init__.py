"""Model layer: parse and validate SMH files into immutable data.

This is the bottom layer of sm_bt: it imports nothing else from the package.
"""

from sm_bt.model.errors import ModelError
from sm_bt.model.loader import load_model, load_model_text
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import (
    DEFAULT_MODE,
    DONT_CARE,
    Location,
    Match,
    Model,
    ModelIssue,
    NodeMode,
    NodePart,
    ParamSpec,
    ParamValue,
    Part,
    PartEntry,
    Rule,
    Severity,
    SystemMode,
    SystemPart,
)

__all__ = [
    "DEFAULT_MODE",
    "DONT_CARE",
    "Location",
    "Match",
    "Model",
    "ModelError",
    "ModelIssue",
    "NodeMode",
    "NodePart",
    "ParamSpec",
    "ParamValue",
    "Part",
    "PartEntry",
    "Rule",
    "Severity",
    "State",
    "StateMode",
    "SystemMode",
    "SystemPart",
    "load_model",
    "load_model_text",
]
