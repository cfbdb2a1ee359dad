"""The two messages the backend hears most, read from their serialised (CDR) bytes; the two the
manager sends most, written as such.

For every transition it asks for, the backend hears two ``lifecycle_msgs/TransitionEvent`` s and
needs one field of each; for every parameter set, a ``rcl_interfaces/ParameterEvent`` (and every
other node's on the robot, which it drops by name). Building the messages costs more than the
rest of their handling, and many times what reading the needed fields from the bytes costs
(docs/performance.md).

The layouts are the messages' own, in plain CDR as the ROS 2 middlewares send them: a 4-byte
encapsulation header (representation ``0x0000`` big-endian, ``0x0001`` little-endian), then the
fields, each aligned to its size (at most 8) from the end of the header; a string is a ``uint32``
length (its NUL included) and its bytes; a sequence a ``uint32`` count and its elements (no
padding when it is empty). Anything else (another representation, bytes that end too soon)
gives ``None``, and the caller deserialises the usual way.

The manager's ``mode_event`` and ``transition_event`` messages (and the request topics of the same
types) are written the same way, little-endian, for ``Publisher.publish`` to send as they are:
every change is published at once (a latched topic must hold the latest true value for a reader
that comes later), and the bytes cost a fraction of building a message for rclpy to serialise.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from sm_bt.model.types import ParamValue

_HEADER = 4
_U32 = {0: struct.Struct(">I").unpack_from, 1: struct.Struct("<I").unpack_from}
_I64 = {0: struct.Struct(">q").unpack_from, 1: struct.Struct("<q").unpack_from}
_F64 = {0: struct.Struct(">d").unpack_from, 1: struct.Struct("<d").unpack_from}
_ORDER = {0: ">", 1: "<"}

# rcl_interfaces/ParameterType
_BOOL, _INTEGER, _DOUBLE, _STRING, _BYTE_ARRAY, _BOOL_ARRAY, _INTEGER_ARRAY, _DOUBLE_ARRAY, _STRING_ARRAY = range(1, 10)


def _align4(at: int) -> int:
    return _HEADER + ((at - _HEADER + 3) & ~3)


def _align8(at: int) -> int:
    return _HEADER + ((at - _HEADER + 7) & ~7)


def _plain_cdr(raw: bytes) -> bool:
    return len(raw) >= _HEADER and raw[0] == 0 and raw[1] in _U32


def goal_state_id(raw: bytes) -> int | None:
    """The ``goal_state.id`` of a serialised ``TransitionEvent`` (``uint64 timestamp``, then a
    ``Transition``, the start and the goal ``State``, each a ``uint8 id`` and a ``string label``)."""
    if not _plain_cdr(raw):
        return None
    u32 = _U32[raw[1]]
    try:
        at = _align4(_HEADER + 8 + 1)  # timestamp, transition id: its label
        at = _align4(at + 4 + u32(raw, at)[0] + 1)  # the start state's id: its label
        goal: int = raw[at + 4 + u32(raw, at)[0]]
        return goal
    except (IndexError, struct.error):
        return None


def parameter_event_node(raw: bytes) -> str | None:
    """The ``node`` of a serialised ``ParameterEvent`` (after its ``Time stamp``)."""
    if not _plain_cdr(raw):
        return None
    try:
        node, _ = _string(raw, _HEADER + 8, _U32[raw[1]])
    except (ValueError, struct.error):
        return None
    return node


def parameter_event_values(raw: bytes) -> dict[str, ParamValue] | None:
    """The values a serialised ``ParameterEvent`` gives its node (new and changed parameters; not
    set ones left out), typed as :func:`sm_bt.ros.parameters.from_parameter_value` types them."""
    if not _plain_cdr(raw):
        return None
    order = raw[1]
    u32 = _U32[order]
    values: dict[str, ParamValue] = {}
    try:
        _, at = _string(raw, _HEADER + 8, u32)
        for _ in range(2):  # new_parameters, changed_parameters (deleted ones carry no value)
            at = _align4(at)
            count = u32(raw, at)[0]
            at += 4
            for _ in range(count):
                name, at = _string(raw, at, u32)
                value, at = _parameter_value(raw, at, order)
                if value is not None:
                    values[name] = value
    except (ValueError, IndexError, struct.error):
        return None
    return values


def _string(raw: bytes, at: int, u32: Callable[[bytes, int], tuple[Any, ...]]) -> tuple[str, int]:
    """The string at ``at`` (aligned first) and where the next field may start."""
    at = _align4(at)
    length = u32(raw, at)[0]
    at += 4
    if at + length > len(raw):
        raise ValueError("cut short")
    return raw[at:at + max(length - 1, 0)].decode("utf-8"), at + length


def _parameter_value(raw: bytes, at: int, order: int) -> tuple[ParamValue | None, int]:
    """One ``ParameterValue``: every field is on the wire, the type says which one holds the value."""
    u32 = _U32[order]
    kind = raw[at]
    value: ParamValue | None = None
    if kind == _BOOL:
        value = raw[at + 1] != 0
    at = _align8(at + 2)
    if kind == _INTEGER:
        value = _I64[order](raw, at)[0]
    elif kind == _DOUBLE:
        value = _F64[order](raw, at + 8)[0]
    at += 16
    text, at = _string(raw, at, u32)
    if kind == _STRING:
        value = text
    for sequence in (_BYTE_ARRAY, _BOOL_ARRAY):  # octets: no alignment
        at = _align4(at)
        count = u32(raw, at)[0]
        at += 4
        if kind == sequence:
            octets = raw[at:at + count]
            value = tuple(octets) if kind == _BYTE_ARRAY else tuple(octet != 0 for octet in octets)
        at += count
    for sequence, letter in ((_INTEGER_ARRAY, "q"), (_DOUBLE_ARRAY, "d")):
        at = _align4(at)
        count = u32(raw, at)[0]
        at += 4
        if count:
            at = _align8(at)
            if kind == sequence:
                value = struct.unpack_from(f"{_ORDER[order]}{count}{letter}", raw, at)
            at += 8 * count
        elif kind == sequence:
            value = ()
    at = _align4(at)
    count = u32(raw, at)[0]
    at += 4
    texts = []
    for _ in range(count):
        text, at = _string(raw, at, u32)
        texts.append(text)
    if kind == _STRING_ARRAY:
        value = tuple(texts)
    if at > len(raw):
        raise ValueError("cut short")
    return value, at


# -- writing -------------------------------------------------------------------------------------------

_LITTLE = b"\x00\x01\x00\x00"  # plain CDR, little-endian
_PACK_U64 = struct.Struct("<Q").pack
_PACK_U32 = struct.Struct("<I").pack


def _put_string(out: bytearray, text: str) -> None:
    out.extend(b"\x00" * (-(len(out) - _HEADER) % 4))
    data = text.encode("utf-8")
    out += _PACK_U32(len(data) + 1)
    out += data
    out.append(0)


def mode_event(stamp: int, start: str, goal: str) -> bytes:
    """A serialised ``system_modes_msgs/ModeEvent``: ``uint64 timestamp``, then the start and the goal
    ``Mode`` (each a ``string label``)."""
    out = bytearray(_LITTLE)
    out += _PACK_U64(stamp)
    _put_string(out, start)
    _put_string(out, goal)
    return bytes(out)


def transition_event(stamp: int, transition: tuple[int, str], start: tuple[int, str], goal: tuple[int, str]) -> bytes:
    """A serialised ``lifecycle_msgs/TransitionEvent``: ``uint64 timestamp``, then the ``Transition``,
    the start and the goal ``State``, each ``(id, label)`` (a ``uint8 id`` and a ``string label``)."""
    out = bytearray(_LITTLE)
    out += _PACK_U64(stamp)
    for number, label in (transition, start, goal):
        out.append(number)
        _put_string(out, label)
    return bytes(out)
