"""The requests :class:`~sm_bt.ros.backend.RosBackend` sends, built once and reused (a request is
serialised when it is sent; nothing keeps or changes it), and the fallback reading of a message."""

from __future__ import annotations

import functools
import logging
from collections.abc import Mapping
from typing import Any

from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParametersAtomically

from sm_bt.engine.lifecycle import Transition
from sm_bt.model.types import ParamValue
from sm_bt.ros.parameters import to_parameters

log = logging.getLogger("sm_bt.ros.backend")

#: What a parameter set whose event came first is taken to have answered.
APPLIED = SetParametersAtomically.Response(result=SetParametersResult(successful=True))
#: list_parameters asked with this prefix answers with nothing: a liveness probe, not a query.
NO_SUCH_PREFIX = "sm_bt.liveness.none"


@functools.cache
def change_state_request(transition: Transition) -> Any:
    """The request of ``transition``, with its id and label: one per transition, for every call
    (a request is serialised when it is sent; nothing keeps or changes it)."""
    request = ChangeState.Request()
    request.transition = TransitionMsg(id=int(transition), label=transition.label)
    return request


TypedItems = tuple[tuple[str, ParamValue, object], ...]


def typed_items(values: Mapping[str, ParamValue]) -> TypedItems:
    """``values`` as a key that tells ``1``, ``1.0`` and ``True`` apart (they are equal in Python)."""
    return tuple((name, tuple(value) if isinstance(value, list) else value,
                  tuple(map(type, value)) if isinstance(value, (tuple, list)) else type(value))
                 for name, value in values.items())


@functools.lru_cache(maxsize=4096)
def set_parameters_request(items: TypedItems) -> Any:
    """The request that sets these values: one per node mode, as a mode's values are set again and
    again (building the messages costs the thread that makes the calls); like the transitions'
    requests, it is serialised when sent and never changed."""
    return SetParametersAtomically.Request(parameters=to_parameters({name: value for name, value, _ in items}))


def deserialised(raw: bytes, kind: Any, source: str) -> Any:
    """``raw`` as a ``kind`` message, the usual way; None (and a warning) if it is not one."""
    from rclpy.serialization import deserialize_message

    try:
        return deserialize_message(raw, kind)
    except Exception:  # nothing to learn from it
        log.warning("unreadable %s from %s (%d bytes) ignored", kind.__name__, source, len(raw))
        return None
