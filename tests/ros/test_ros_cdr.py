"""What the backend reads from serialised events is what rclpy serialised: the goal state of a
TransitionEvent, and the node and values of a ParameterEvent, for every value type, label and
name length (the alignment of what follows a string depends on its length) and both byte orders;
other encodings and cut bytes give None, and the backend deserialises those the usual way. What
the manager writes as bytes (its ModeEvent and TransitionEvent messages) is what rclpy reads."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples
from lifecycle_msgs.msg import State as StateMsg
from lifecycle_msgs.msg import Transition as TransitionMsg
from lifecycle_msgs.msg import TransitionEvent
from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue
from rclpy.serialization import deserialize_message, serialize_message
from system_modes_msgs.msg import ModeEvent

from sm_bt.ros.cdr import goal_state_id, mode_event, parameter_event_node, parameter_event_values, transition_event
from sm_bt.ros.parameters import from_parameters

pytestmark = pytest.mark.ros

labels = st.text(alphabet="abcdefghijklmnopqrstuvwxyz_/.", max_size=24)
ids = st.integers(min_value=0, max_value=255)
ints = st.integers(min_value=-(2**63), max_value=2**63 - 1)
floats = st.floats(allow_nan=False)
texts = st.text(max_size=12)


def _transition_event(transition: int, transition_label: str, start: int, start_label: str, goal: int,
                      goal_label: str, stamp: int = 0) -> bytes:
    return bytes(serialize_message(TransitionEvent(
        timestamp=stamp, transition=TransitionMsg(id=transition, label=transition_label),
        start_state=StateMsg(id=start, label=start_label), goal_state=StateMsg(id=goal, label=goal_label))))


@examples(200)
@given(ids, labels, ids, labels, ids, labels, st.integers(min_value=0, max_value=2**64 - 1))
def test_the_goal_state_is_read_where_rclpy_wrote_it(transition: int, transition_label: str, start: int,
                                                      start_label: str, goal: int, goal_label: str,
                                                      stamp: int) -> None:
    assert goal_state_id(_transition_event(transition, transition_label, start, start_label, goal, goal_label,
                                           stamp)) == goal


# Any Unicode but NUL (labels are UTF-8 on the wire; a ROS string ends at its first NUL, and the loader
# refuses one in a name).
any_text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=24)
stamps = st.integers(min_value=0, max_value=2**64 - 1)


@examples(200)
@given(stamps, any_text, any_text)
def test_a_written_mode_event_is_the_message_rclpy_reads(stamp: int, start: str, goal: str) -> None:
    message = deserialize_message(mode_event(stamp, start, goal), ModeEvent)
    assert (message.timestamp, message.start_mode.label, message.goal_mode.label) == (stamp, start, goal)


@examples(200)
@given(stamps, ids, any_text, ids, any_text, ids, any_text)
def test_a_written_transition_event_is_the_message_rclpy_reads(stamp: int, transition: int, transition_label: str,
                                                               start: int, start_label: str, goal: int,
                                                               goal_label: str) -> None:
    raw = transition_event(stamp, (transition, transition_label), (start, start_label), (goal, goal_label))
    message = deserialize_message(raw, TransitionEvent)
    assert (message.timestamp, message.transition.id, message.transition.label, message.start_state.id,
            message.start_state.label, message.goal_state.id, message.goal_state.label) == \
        (stamp, transition, transition_label, start, start_label, goal, goal_label)
    assert goal_state_id(raw) == goal  # the backend reads ours as it reads the nodes'


def test_a_big_endian_transition_event_is_read_too() -> None:
    raw = bytearray(_transition_event(1, "configure", 1, "unconfigured", 10, "configuring"))
    raw[1] = 0  # big-endian: the timestamp (0) reads the same; the labels' lengths turn around
    start_label = (12 + 4 + len("configure\0") + 1 + 3) & ~3  # after the start state's id, aligned
    for at in (4 + 12, 4 + start_label):
        struct.pack_into(">I", raw, at, struct.unpack_from("<I", raw, at)[0])
    assert goal_state_id(bytes(raw)) == 10


def _value(kind: int, value: object) -> ParameterValue:
    field = {ParameterType.PARAMETER_BOOL: "bool_value", ParameterType.PARAMETER_INTEGER: "integer_value",
             ParameterType.PARAMETER_DOUBLE: "double_value", ParameterType.PARAMETER_STRING: "string_value",
             ParameterType.PARAMETER_BYTE_ARRAY: "byte_array_value",
             ParameterType.PARAMETER_BOOL_ARRAY: "bool_array_value",
             ParameterType.PARAMETER_INTEGER_ARRAY: "integer_array_value",
             ParameterType.PARAMETER_DOUBLE_ARRAY: "double_array_value",
             ParameterType.PARAMETER_STRING_ARRAY: "string_array_value"}
    message = ParameterValue(type=kind)
    if kind in field:
        setattr(message, field[kind], value)
    return message


values = st.one_of(
    st.tuples(st.just(ParameterType.PARAMETER_NOT_SET), st.none()),
    st.tuples(st.just(ParameterType.PARAMETER_BOOL), st.booleans()),
    st.tuples(st.just(ParameterType.PARAMETER_INTEGER), ints),
    st.tuples(st.just(ParameterType.PARAMETER_DOUBLE), floats),
    st.tuples(st.just(ParameterType.PARAMETER_STRING), texts),
    st.tuples(st.just(ParameterType.PARAMETER_BYTE_ARRAY),
              st.lists(st.integers(min_value=0, max_value=255).map(lambda b: bytes([b])), max_size=5)),
    st.tuples(st.just(ParameterType.PARAMETER_BOOL_ARRAY), st.lists(st.booleans(), max_size=5)),
    st.tuples(st.just(ParameterType.PARAMETER_INTEGER_ARRAY), st.lists(ints, max_size=5)),
    st.tuples(st.just(ParameterType.PARAMETER_DOUBLE_ARRAY), st.lists(floats, max_size=5)),
    st.tuples(st.just(ParameterType.PARAMETER_STRING_ARRAY), st.lists(texts, max_size=4)),
)
parameters = st.lists(st.tuples(labels, values), max_size=4)


@examples(300)
@given(labels, parameters, parameters, st.lists(labels, max_size=2), st.integers(min_value=0, max_value=2**31 - 1))
def test_a_parameter_events_node_and_values_are_what_rclpy_reads(
        node: str, new: list[tuple[str, tuple[int, object]]], changed: list[tuple[str, tuple[int, object]]],
        deleted: list[str], seconds: int) -> None:
    def messages(items: list[tuple[str, tuple[int, object]]]) -> list[Parameter]:
        return [Parameter(name=name, value=_value(kind, value)) for name, (kind, value) in items]

    event = ParameterEvent(node=node, new_parameters=messages(new), changed_parameters=messages(changed),
                           deleted_parameters=[Parameter(name=name) for name in deleted])
    event.stamp.sec = seconds
    raw = bytes(serialize_message(event))
    received = deserialize_message(raw, ParameterEvent)  # what rclpy makes of the same bytes
    assert parameter_event_node(raw) == received.node
    expected = from_parameters(list(received.new_parameters) + list(received.changed_parameters))
    read = parameter_event_values(raw)
    assert read == expected
    assert read is not None and [type(v) for v in read.values()] == [type(v) for v in expected.values()]


def test_what_is_not_plain_cdr_or_is_cut_short_gives_none() -> None:
    raw = _transition_event(3, "activate", 10, "configuring", 2, "inactive")
    assert goal_state_id(b"\x00\x07" + raw[2:]) is None  # another representation (XCDR2)
    assert goal_state_id(raw[:20]) is None
    event = ParameterEvent(node="/amcl", changed_parameters=[
        Parameter(name="alpha1", value=_value(ParameterType.PARAMETER_DOUBLE_ARRAY, [0.5, 0.25]))])
    raw = bytes(serialize_message(event))
    assert parameter_event_values(raw) == {"alpha1": (0.5, 0.25)}
    assert parameter_event_node(b"\x00\x07" + raw[2:]) is None
    value_ends = raw.index(struct.pack("<d", 0.25)) + 8
    for cut in range(4, value_ends):
        assert parameter_event_values(raw[:cut]) is None, cut
    assert parameter_event_node(raw[:14]) is None
