"""StateMode semantics (the reference's state-and-mode comparison tests, re-expressed)."""

import pytest

from sm_bt.model.states import LABELS, State, StateMode

UNKNOWN = StateMode(State.UNKNOWN)
INACTIVE = StateMode(State.INACTIVE)
ACTIVE = StateMode(State.ACTIVE)
ACTIVE_DEFAULT = StateMode(State.ACTIVE, "__DEFAULT__")
ACTIVE_FOO = StateMode(State.ACTIVE, "FOO")


def test_labels_and_ids_match_lifecycle_msgs() -> None:
    assert [(s.value, s.label) for s in State] == [
        (0, "unknown"), (1, "unconfigured"), (2, "inactive"), (3, "active"), (4, "finalized"),
        (10, "configuring"), (11, "cleaningup"), (12, "shuttingdown"), (13, "activating"),
        (14, "deactivating"), (15, "errorprocessing"),
    ]
    assert LABELS[3] == "active"


def test_comparison() -> None:
    assert StateMode(State.INACTIVE) == INACTIVE
    assert ACTIVE != INACTIVE
    assert ACTIVE_DEFAULT != ACTIVE_FOO
    assert ACTIVE_DEFAULT != INACTIVE
    # The mode only counts while active.
    assert StateMode(State.INACTIVE, "FOO") == INACTIVE
    # "active" without a mode is "mode unknown", not the default: the loader resolves the default
    # by name, so the engine never has to equate "" with __DEFAULT__.
    assert ACTIVE != ACTIVE_DEFAULT


@pytest.mark.parametrize(
    ("value", "text"),
    [(INACTIVE, "inactive"), (ACTIVE, "active"), (ACTIVE_DEFAULT, "active.__DEFAULT__"),
     (ACTIVE_FOO, "active.FOO"), (StateMode(State.INACTIVE, "FOO"), "inactive")],
)
def test_string_round_trip(value: StateMode, text: str) -> None:
    assert str(value) == text
    assert StateMode.parse(text) == value


@pytest.mark.parametrize("text", ["ACTIVE", "Active.FOO", "running", "active.A.B", ""])
def test_parse_rejects(text: str) -> None:
    with pytest.raises(ValueError):
        StateMode.parse(text)


def test_primary_states() -> None:
    assert {s for s in State if s.is_primary} == {State.UNCONFIGURED, State.INACTIVE, State.ACTIVE, State.FINALIZED}
    assert State.from_label("errorprocessing") is State.ERRORPROCESSING
