"""Parse ``state[.MODE]`` values (system-mode entries, rule states) against the part they name.

The reference maps any label it does not know to ``unknown`` without a word; here a label must be
an exact lower-case lifecycle label, and a mode must exist in the part. ``active`` alone means
the part's default mode; ``__DEFAULT__`` means the default mode unless the part has a mode
literally called so. A mode after a non-active label (``inactive.__DEFAULT__``, written by
third-party users) is accepted and ignored, but must still exist: it is a typo otherwise.
"""

from __future__ import annotations

from sm_bt.model.declarations import PartDecl
from sm_bt.model.diagnostics import Diagnostics, did_you_mean, quoted_list
from sm_bt.model.states import LABELS, PRIMARY_STATES, State, StateMode
from sm_bt.model.types import DEFAULT_MODE

_TARGET_LABELS = tuple(s.label for s in State if s in PRIMARY_STATES)


def parse_state_mode(text: str, part: PartDecl, line: int, what: str, diag: Diagnostics, *,
                     target: bool = True) -> StateMode | None:
    """The resolved value, or ``None`` after reporting why not.

    ``target`` restricts the state to those a part can rest in (a target cannot be a transition
    state); rule conditions on a part's actual state (``if_part``) may use every label.
    """
    label, dot, mode = text.partition(".")
    allowed = _TARGET_LABELS if target else LABELS
    if label not in LABELS:
        _bad_label(text, label, mode, dot, line, what, allowed, diag)
        return None
    state = State.from_label(label)
    if label not in allowed:
        diag.error(line, f"{what}: {label!r} is not a state a part can be asked to rest in: write "
                         f"one of {quoted_list(allowed)}")
        return None
    if dot and not mode:
        diag.error(line, f"{what}: {text!r} ends with '.': write {label!r} or '{label}.MODE'")
        return None
    if "." in mode:
        diag.error(line, f"{what}: {text!r} has more than one '.': write 'state' or 'state.MODE' (mode "
                         "names cannot contain dots)")
        return None
    if not mode:
        if state is not State.ACTIVE:
            return StateMode(state)
        # None only when the part has no default mode, which is reported with the part.
        return StateMode(state, part.default_mode) if part.default_mode else None
    if part.modes is None:
        return None  # the part's own error has been reported
    resolved = part.resolve_mode(mode)
    if resolved is None and mode == DEFAULT_MODE and part.default_mode is None:
        return None  # the missing default is reported with the part
    if resolved is None:
        diag.error(line, f"{what}: part {part.name!r} has no mode {mode!r}"
                         f"{did_you_mean(mode, part.mode_names)}: use one of {quoted_list(part.mode_names)}")
        return None
    return StateMode(state, resolved)


def _bad_label(text: str, label: str, mode: str, dot: str, line: int, what: str,
               allowed: tuple[str, ...], diag: Diagnostics) -> None:
    lower = label.lower()
    if lower in allowed:
        diag.error(line, f"{what}: {text!r} is not a lifecycle state: write '{lower}{dot}{mode}' "
                         "(labels are lower-case)")
        return
    diag.error(line, f"{what}: {label!r} is not a lifecycle state{did_you_mean(lower, allowed)}: write "
                     f"one of {quoted_list(allowed)}, optionally followed by '.MODE' after 'active'")
