"""A node mode recognises observed parameters exactly as its parameters' own matches say.

``NodeMode.matches`` sorts its parameters into exact ones (checked inline, on every parameter
report) and the others once; this pins it to the per-parameter definition for any values.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from sm_bt.model.types import Location, Match, NodeMode, ParamSpec, ParamValue

LOC = Location("test.yaml", 1)
NAMES = ["a", "b", "c", "d"]

scalars: st.SearchStrategy[ParamValue] = st.one_of(
    st.booleans(), st.integers(-3, 3), st.floats(-3, 3, width=32), st.just(float("nan")),
    st.sampled_from(["x", "y", ""]))
values: st.SearchStrategy[ParamValue] = st.one_of(
    scalars, st.lists(st.integers(-2, 2), max_size=3).map(tuple), st.lists(st.booleans(), max_size=2).map(tuple))
matches = st.one_of(st.just(Match()), st.builds(Match, tolerance=st.sampled_from([0.0, 0.5, 2.0])),
                    st.builds(Match, minimum=st.sampled_from([None, -1.0]), maximum=st.sampled_from([None, 1.0])))


def _look_alikes(value: ParamValue) -> list[ParamValue]:
    """Values an observation may hold instead of ``value``: itself, and its twins of other types."""
    alikes: list[ParamValue] = [value]
    if isinstance(value, (bool, int, float)) and not isinstance(value, tuple):
        alikes += [bool(value), float(value)]
        if value == value and value == int(value):  # not NaN
            alikes.append(int(value))
    if isinstance(value, tuple):
        alikes += [tuple(bool(v) for v in value), tuple(float(v) for v in value)]
    return alikes


@given(st.dictionaries(st.sampled_from(NAMES), st.tuples(values, matches), min_size=1), st.data())
def test_a_mode_matches_when_every_parameter_matches(specs: dict[str, tuple[ParamValue, Match]],
                                                     data: st.DataObject) -> None:
    mode = NodeMode("M", {name: ParamSpec(name, value, LOC, match) for name, (value, match) in specs.items()}, LOC)
    observed: dict[str, ParamValue] = {}
    for name in NAMES:
        choice = data.draw(st.integers(0, 3))
        if choice == 1 and name in specs:
            observed[name] = data.draw(st.sampled_from(_look_alikes(specs[name][0])))
        elif choice >= 2:
            observed[name] = data.draw(values if choice == 2 else st.sampled_from(
                [specs[name][0]] if name in specs else ["x"]))
    expected = all(name in observed and spec.matches(observed[name]) for name, spec in mode.parameters.items())
    assert mode.matches(observed) is expected


def test_exact_parameters_compare_type_and_value() -> None:
    mode = NodeMode("M", {"n": ParamSpec("n", 1, LOC), "f": ParamSpec("f", 0.5, LOC),
                          "t": ParamSpec("t", (1, 2), LOC)}, LOC)
    assert mode.matches({"n": 1, "f": 0.5, "t": (1, 2), "extra": "ignored"})
    assert not mode.matches({"n": True, "f": 0.5, "t": (1, 2)})  # a bool is not the int 1
    assert not mode.matches({"n": 1.0, "f": 0.5, "t": (1, 2)})  # nor is a double
    assert not mode.matches({"n": 1, "t": (1, 2)})  # missing
    assert not mode.matches({"n": 1, "f": 0.5, "t": (1, 3)})
