"""The goal state read from a serialised TransitionEvent is the one rclpy serialised, for every
state and label length (the alignment of the fields after a label depends on its length), in
either byte order; other encodings and cut bytes fall back to rclpy's deserialisation."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st
from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from rclpy.serialization import serialize_message

from sm_bt.ros.transition_events import _read, goal_state_id

labels = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_", max_size=24)
ids = st.integers(min_value=0, max_value=255)


def _event(transition: int, transition_label: str, start: int, start_label: str, goal: int, goal_label: str,
           stamp: int = 0) -> bytes:
    return bytes(serialize_message(TransitionEvent(
        timestamp=stamp, transition=TransitionMsg(id=transition, label=transition_label),
        start_state=StateMsg(id=start, label=start_label), goal_state=StateMsg(id=goal, label=goal_label))))


@given(ids, labels, ids, labels, ids, labels, st.integers(min_value=0, max_value=2**64 - 1))
def test_the_goal_state_is_read_where_rclpy_wrote_it(transition: int, transition_label: str, start: int,
                                                      start_label: str, goal: int, goal_label: str,
                                                      stamp: int) -> None:
    raw = _event(transition, transition_label, start, start_label, goal, goal_label, stamp)
    assert _read(raw) == goal
    assert goal_state_id(raw) == goal


def _big_endian(raw: bytes) -> bytes:
    """The same event in big-endian CDR (what a big-endian machine sends)."""
    body = bytearray(raw[4:])
    body[0:8] = body[0:8][::-1]  # the timestamp
    offset = 9
    for _ in range(2):  # the two labels' lengths; the ids are single bytes
        offset = (offset + 3) & ~3
        length = struct.unpack_from("<I", body, offset)[0]
        struct.pack_into(">I", body, offset, length)
        offset += 4 + length + 1
    return b"\x00\x00\x00\x00" + bytes(body)


def test_a_big_endian_event_is_read_too() -> None:
    raw = _big_endian(_event(1, "configure", 1, "unconfigured", 10, "configuring"))
    assert _read(raw) == 10


def test_what_is_not_plain_cdr_or_is_cut_short_is_deserialised_by_rclpy() -> None:
    raw = _event(3, "activate", 10, "configuring", 2, "inactive")
    assert _read(b"\x00\x07" + raw[2:]) is None  # another representation (XCDR2)
    assert _read(raw[:20]) is None
    assert goal_state_id(raw) == 2
    with pytest.raises(Exception):  # noqa: B017 - rclpy's own error for bytes it cannot read
        goal_state_id(raw[:20])
