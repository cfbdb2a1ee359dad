"""Running counts of what a system's parts are, so that inferring the system costs O(its modes).

:func:`~sm_bt.engine.inference.infer_system` looks at every part of a system every time. A
:class:`Tally` keeps, per system, how many entries of each mode its parts do not match, how many
parts are in each lifecycle state, and which parts are unknown; one part's change updates those
counts in O(the modes that name the part), and :meth:`Tally.infer` gives the same answer as
``infer_system`` (which stays the reference: the tests compare the two). Only the reasons of a
system on its way somewhere are written by looking at the parts again: a settled system costs
O(1).
"""

from __future__ import annotations

from collections.abc import Callable, Container, Iterable

from sm_bt.engine.actual import STATE_LABELS, Actual
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import SystemPart

#: The state a system shows while its parts move towards a non-active target state.
MOVING_TO = {
    State.UNCONFIGURED: State.CLEANINGUP,
    State.FINALIZED: State.SHUTTINGDOWN,
}
_REASONS_KEPT = 4  # per system: a part flapping between two values, towards one of two modes
_GOING_DOWN = (State.ACTIVE, State.ACTIVATING, State.DEACTIVATING)
# The states the hot paths compare with, read once: looking up an enum's member on its class is
# slow (EnumType.__getattr__).
_UNKNOWN, _ACTIVE, _ACTIVATING, _ERRORPROCESSING = State.UNKNOWN, State.ACTIVE, State.ACTIVATING, State.ERRORPROCESSING


#: How many unknown parts a system's reason names (the others are counted), so that it stays short
#: however big the system; a sub-system is named by its reason's headline, not its parts'.
UNKNOWN_NAMED = 3
UNKNOWN_PARTS = "part state unknown"
UNKNOWN_UNTARGETED = "parts match no mode and no target is set"


def unknown_reason(unknown: Iterable[Actual]) -> str:
    """A system's reason for being unknown: ``unknown`` are its unknown parts that matter, in
    the order of its parts."""
    shown: list[str] = []
    more = 0
    for actual in unknown:
        if len(shown) == UNKNOWN_NAMED:
            more += 1
            continue
        why = actual.reason or "unknown"
        for headline in (UNKNOWN_PARTS, UNKNOWN_UNTARGETED):
            if why.startswith(headline):
                why = headline
        shown.append(f"{actual.part}: {why}")
    if more:
        shown.append(f"{more} more")
    return f"{UNKNOWN_PARTS} ({'; '.join(shown)})"


def relevant_parts(system: SystemPart, target: StateMode | None) -> Container[str]:
    """The parts whose state a system's inference needs: for a target mode, those it names."""
    if target is not None and target.mode is not None and target.mode in system.modes:
        return {e.part for e in system.modes[target.mode].entries.values() if not e.dont_care}
    return system.parts


def entry_matches(entry_target: StateMode | None, actual: Actual) -> bool:
    """A part's actual meets a system mode's entry for it (a don't-care entry always does)."""
    if entry_target is None:
        return True
    if actual.state is State.UNKNOWN or actual.state is not entry_target.state:
        return False
    return entry_target.mode == (actual.mode if actual.state is State.ACTIVE else None)


def system_mode_matches(part: SystemPart, mode: str, actual_of: Callable[[str], Actual]) -> bool:
    return all(entry_matches(e.target, actual_of(e.part)) for e in part.modes[mode].entries.values())


def first_difference(part: SystemPart, mode: str, actual_of: Callable[[str], Actual]) -> str:
    """Why the parts do not match ``mode``: its first entry they do not meet."""
    for entry in part.modes[mode].entries.values():
        actual = actual_of(entry.part)
        if not entry_matches(entry.target, actual):
            return f"{entry.part} is {actual}, {mode} wants {entry.target}"
    return ""


def untargeted_mismatch(part: SystemPart, actual_of: Callable[[str], Actual], states: set[State]) -> Actual:
    """A system with no target whose parts match none of its modes."""
    shown = ", ".join(f"{a.part} {a}" for a in map(actual_of, part.parts))
    if states == {State.ACTIVE}:
        return Actual(part.name, State.ACTIVE, reason=f"parts match no mode ({shown})")
    return Actual(part.name, State.UNKNOWN, reason=f"{UNKNOWN_UNTARGETED} ({shown})")


class Tally:
    """The counts of one system; :meth:`update` them on each change of a part, then :meth:`infer`."""

    __slots__ = ("_by_part", "_mismatch", "_modes_sorted", "_reasons", "_size", "_states", "_unknown", "system")

    def __init__(self, system: SystemPart, actual_of: Callable[[str], Actual]) -> None:
        self.system = system
        self._size = len(system.parts)
        self._modes_sorted = sorted(system.modes)
        # mode -> {place of an entry its part does not meet: that part}
        self._mismatch: dict[str, dict[int, str]] = {name: {} for name in system.modes}
        # part -> (its mode's mismatches, the entry's state and mode, the entry's place in the mode)
        # for each entry that names it (don't-care entries name nothing).
        self._by_part: dict[str, list[tuple[dict[int, str], State, str | None, int]]] = {
            part: [] for part in system.parts}
        for name, mode in system.modes.items():
            for place, entry in enumerate(mode.entries.values()):
                if entry.target is not None:
                    self._by_part.setdefault(entry.part, []).append(
                        (self._mismatch[name], entry.target.state, entry.target.mode, place))
        # A plain dict with every state: Counter's lookup of a missing key runs Python code.
        self._states: dict[State, int] = dict.fromkeys(State, 0)
        self._unknown: set[str] = set()
        # (wanted mode, first part it lacks, that part's actual) -> the reason: a part flapping
        # between two values makes the same two strings again and again.
        self._reasons: dict[tuple[str, str, Actual], str] = {}
        for part in system.parts:
            self._add(part, actual_of(part))

    def update(self, part: str, old: Actual, new: Actual) -> None:
        """``part``'s actual went from ``old`` to ``new``."""
        self._states[old.state] -= 1
        if old.state is _UNKNOWN:
            self._unknown.discard(part)
        self._add(part, new)

    def _add(self, part: str, actual: Actual) -> None:
        state = actual.state
        self._states[state] += 1
        if state is _UNKNOWN:
            self._unknown.add(part)
        mode = actual.mode if state is _ACTIVE else None
        for mismatch, entry_state, entry_mode, place in self._by_part.get(part, ()):
            if state is entry_state and state is not _UNKNOWN and mode == entry_mode:
                mismatch.pop(place, None)
            else:
                mismatch[place] = part

    def infer(self, target: StateMode | None, actual_of: Callable[[str], Actual]) -> Actual:
        """What ``infer_system`` would say, from the counts."""
        system = self.system
        if self._states[_ERRORPROCESSING]:
            failing = next(p for p in system.parts if actual_of(p).state is _ERRORPROCESSING)
            return Actual(system.name, _ERRORPROCESSING, reason=f"{failing} is in errorprocessing")
        if self._unknown:
            relevant = relevant_parts(system, target)
            unknown = [p for p in system.parts if p in self._unknown and p in relevant]
            if unknown:
                return Actual(system.name, _UNKNOWN, reason=unknown_reason(map(actual_of, unknown)))
        if target is None:
            return self._untargeted(actual_of)
        if target.state is _ACTIVE:
            wanted = target.mode if target.mode is not None and target.mode in system.modes else system.default_mode
            missing = self._mismatch[wanted]
            if not missing:
                return Actual(system.name, _ACTIVE, wanted)
            first = missing[min(missing)]
            reason = self._reason(wanted, first, actual_of(first))
            for name in self._modes_sorted:
                if name != wanted and not self._mismatch[name]:
                    return Actual(system.name, _ACTIVATING, name, True, True, reason)  # positional: keywords cost more
            return Actual(system.name, _ACTIVATING, None, True, True, reason)
        if self._states[target.state] == self._size:
            return Actual(system.name, target.state)
        moving = MOVING_TO.get(target.state)
        if moving is None:  # target inactive: coming down from active, or up from unconfigured
            going_down = any(self._states[state] for state in _GOING_DOWN)
            moving = State.DEACTIVATING if going_down else State.CONFIGURING
        lagging = next(a for a in map(actual_of, system.parts) if a.state is not target.state)
        return Actual(system.name, moving, reason=f"{lagging.part} is {STATE_LABELS[lagging.state]}")

    def _reason(self, wanted: str, first: str, actual: Actual) -> str:
        key = (wanted, first, actual)
        reason = self._reasons.get(key)
        if reason is None:
            if len(self._reasons) >= _REASONS_KEPT:
                self._reasons.clear()
            entry = self.system.modes[wanted].entries[first]
            reason = self._reasons[key] = f"{first} is {actual}, {wanted} wants {entry.target}"
        return reason

    def _untargeted(self, actual_of: Callable[[str], Actual]) -> Actual:
        system = self.system
        present = [state for state, count in self._states.items() if count > 0]
        if len(present) == 1 and present[0] is not State.ACTIVE:
            return Actual(system.name, present[0])
        for name in [system.default_mode, *self._modes_sorted]:
            if not self._mismatch[name]:
                return Actual(system.name, State.ACTIVE, name)
        return untargeted_mismatch(system, actual_of, set(present))
