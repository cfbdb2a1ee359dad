"""Parameter values between the model (:data:`~sm_bt.model.types.ParamValue`) and ``rcl_interfaces``.

The model's values are typed like rcl's YAML parser types them (bool, int, double, string and
homogeneous arrays of those), which is exactly the set ROS 2 parameters can hold, so the mapping
is one to one. Byte arrays have no model counterpart and come back as tuples of ints.
"""

from __future__ import annotations

from collections.abc import Mapping

from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue

from sm_bt.model.types import ParamValue


def to_parameter_value(value: ParamValue) -> ParameterValue:
    """The ``ParameterValue`` message holding ``value``; ``TypeError`` for an empty or mixed array."""
    message = ParameterValue()
    if isinstance(value, bool):
        message.type, message.bool_value = ParameterType.PARAMETER_BOOL, value
    elif isinstance(value, int):
        message.type, message.integer_value = ParameterType.PARAMETER_INTEGER, value
    elif isinstance(value, float):
        message.type, message.double_value = ParameterType.PARAMETER_DOUBLE, value
    elif isinstance(value, str):
        message.type, message.string_value = ParameterType.PARAMETER_STRING, value
    elif value and all(isinstance(item, bool) for item in value):
        message.type, message.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, list(value)
    elif value and all(isinstance(item, int) and not isinstance(item, bool) for item in value):
        message.type, message.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, list(value)
    elif value and all(isinstance(item, float) for item in value):
        message.type, message.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, list(value)
    elif value and all(isinstance(item, str) for item in value):
        message.type, message.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, list(value)
    else:
        raise TypeError(f"no ROS 2 parameter type holds {value!r} (arrays must be non-empty and of one type)")
    return message


def from_parameter_value(message: ParameterValue) -> ParamValue | None:
    """The value a ``ParameterValue`` holds; ``None`` when it is not set."""
    kind = message.type
    if kind == ParameterType.PARAMETER_BOOL:
        return bool(message.bool_value)
    if kind == ParameterType.PARAMETER_INTEGER:
        return int(message.integer_value)
    if kind == ParameterType.PARAMETER_DOUBLE:
        return float(message.double_value)
    if kind == ParameterType.PARAMETER_STRING:
        return str(message.string_value)
    if kind == ParameterType.PARAMETER_BYTE_ARRAY:
        return tuple(int.from_bytes(item, "little") if isinstance(item, bytes) else int(item)
                     for item in message.byte_array_value)
    if kind == ParameterType.PARAMETER_BOOL_ARRAY:
        return tuple(bool(item) for item in message.bool_array_value)
    if kind == ParameterType.PARAMETER_INTEGER_ARRAY:
        return tuple(int(item) for item in message.integer_array_value)
    if kind == ParameterType.PARAMETER_DOUBLE_ARRAY:
        return tuple(float(item) for item in message.double_array_value)
    if kind == ParameterType.PARAMETER_STRING_ARRAY:
        return tuple(str(item) for item in message.string_array_value)
    return None


def to_parameters(values: Mapping[str, ParamValue]) -> list[Parameter]:
    """``Parameter`` messages for ``values``, in their order."""
    return [Parameter(name=name, value=to_parameter_value(value)) for name, value in values.items()]


def from_parameters(messages: list[Parameter]) -> dict[str, ParamValue]:
    """The set values among ``Parameter`` messages (unset ones are left out)."""
    values: dict[str, ParamValue] = {}
    for message in messages:
        value = from_parameter_value(message.value)
        if value is not None:
            values[message.name] = value
    return values
