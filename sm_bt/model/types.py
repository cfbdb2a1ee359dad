"""Immutable data of a loaded SMH (system modes and hierarchy) model.

Everything here is plain, frozen data produced by :func:`sm_bt.load_model`. The loader resolves
what the file leaves implicit, so that no later layer has to: node modes carry the *full*
parameter set (defaults inherited), system modes carry an entry for every part (default entries
inherited), an ``active`` entry without a mode names the part's default mode, and rules carry
resolved states.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TypeAlias

from sm_bt.model.states import StateMode

#: A parameter value as a ROS 2 parameter file can hold it. Arrays are tuples (immutable).
ParamValue: TypeAlias = (
    bool | int | float | str | tuple[bool, ...] | tuple[int, ...] | tuple[float, ...] | tuple[str, ...]
)

#: The reference's name of the default mode; still accepted, and used when no ``defaultmode`` is set.
DEFAULT_MODE = "__DEFAULT__"
#: Part-entry value (extension) meaning "leave this part as it is" in a system mode.
DONT_CARE = "__DONTCARE__"


#: The one parameter of a remote part: to the engine a remote part is a node whose parameter is the
#: mode its manager reports, and whose modes each set it to their name (sm_bt.model.remote_parts).
REMOTE_MODE = "__mode__"
#: Who a fleet's requests come from, to the manager of a remote part (its holds and log name it).
FLEET_REQUESTER = "fleet"
#: The managers a remote part may be served by (``served_by``, :class:`Remote`); the first is the default.
REMOTE_MANAGERS = ("sm_bt", "reference")


class PartKind(str, enum.Enum):
    """What a top-level entry of the model is."""

    NODE = "node"
    SYSTEM = "system"


@dataclass(frozen=True)
class Location:
    """Where something was written: file and 1-based line (0: the file as a whole, e.g. unreadable)."""

    file: str
    line: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file


@dataclass(frozen=True)
class Match:
    """How an observed parameter value is compared with a mode's value during inference.

    With no field set the comparison is exact (same type, equal value; arrays element-wise).
    ``tolerance`` accepts ``|actual - value| <= tolerance``; ``minimum``/``maximum`` accept a
    closed range. Both apply to numbers only (an int observed for a double counts as a number).
    """

    tolerance: float | None = None
    minimum: float | None = None
    maximum: float | None = None

    def accepts(self, expected: ParamValue, actual: ParamValue) -> bool:
        if self.tolerance is None and self.minimum is None and self.maximum is None:
            return exact_match(expected, actual)
        if not _is_number(actual):
            return False
        value = float(actual)  # type: ignore[arg-type]
        if math.isnan(value):
            return False
        if self.tolerance is not None and (
            not _is_number(expected) or abs(value - float(expected)) > self.tolerance  # type: ignore[arg-type]
        ):
            return False
        below = self.minimum is not None and value < self.minimum
        above = self.maximum is not None and value > self.maximum
        return not (below or above)


EXACT = Match()


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


_MISSING = object()


def exact_match(expected: ParamValue, actual: ParamValue) -> bool:
    """Same type and equal value; ``bool`` is never equal to ``int``; arrays compare element-wise."""
    if type(expected) is not type(actual):
        return False
    return expected == actual


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a node mode: the value to set, and how to recognise it when observed."""

    name: str
    value: ParamValue
    location: Location
    match: Match = EXACT

    def matches(self, actual: ParamValue) -> bool:
        return self.match.accepts(self.value, actual)


@dataclass(frozen=True)
class NodeMode:
    """A named parameter set of a node. ``parameters`` is complete: defaults are inherited."""

    name: str
    parameters: Mapping[str, ParamSpec]
    location: Location
    # Inference checks modes on every parameter report: the exact parameters as (name, value,
    # type) and the others' specs, sorted out once.
    _exact: tuple[tuple[str, ParamValue, type], ...] = field(init=False, repr=False, compare=False)
    _inexact: tuple[ParamSpec, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        exact: list[tuple[str, ParamValue, type]] = []
        inexact: list[ParamSpec] = []
        for spec in self.parameters.values():
            if spec.match is EXACT or spec.match == EXACT:  # most are the shared EXACT: no __eq__
                exact.append((spec.name, spec.value, type(spec.value)))
            else:
                inexact.append(spec)
        object.__setattr__(self, "_exact", tuple(exact))
        object.__setattr__(self, "_inexact", tuple(inexact))

    @functools.cached_property
    def active_label(self) -> str:
        """How a preview names the node in this mode (made once, when first asked)."""
        return f"active.{self.name}"

    @functools.cached_property
    def set_label(self) -> str:
        """How a preview and a request's feedback name the call that sets this mode's parameters (of
        a remote part: the mode asked of its manager)."""
        if set(self.parameters) == {REMOTE_MODE}:
            return f"change_mode {self.name}"
        return f"set parameters of mode {self.name}"

    def values(self) -> dict[str, ParamValue]:
        """The full parameter set to send (atomically) when switching a node to this mode."""
        return {name: spec.value for name, spec in self.parameters.items()}

    def matches(self, observed: Mapping[str, ParamValue]) -> bool:
        """True when every parameter of the mode is observed with a matching value."""
        missing = _MISSING
        for name, value, kind in self._exact:  # exact_match, inlined
            seen = observed.get(name, missing)
            if type(seen) is not kind or seen != value:
                return False
        return all(spec.name in observed and spec.matches(observed[spec.name]) for spec in self._inexact)


@dataclass(frozen=True)
class PartEntry:
    """What a system mode asks of one of its parts.

    ``target`` is ``None`` for a don't-care entry (the part is left as it is and any state of it
    matches). For ``active`` the mode is always resolved (to the part's default when omitted).
    """

    part: str
    target: StateMode | None
    location: Location
    inherited: bool = False

    @property
    def dont_care(self) -> bool:
        return self.target is None


@dataclass(frozen=True)
class SystemMode:
    """A named set of part entries of a system. ``entries`` covers every part of the system.

    ``stages`` is the switching order: stages run one after another, the parts of one stage in
    parallel. The default (no order given) is a single stage holding every part.
    """

    name: str
    entries: Mapping[str, PartEntry]
    stages: tuple[tuple[str, ...], ...]
    location: Location


@dataclass(frozen=True)
class Rule:
    """``if target(system) == if_target and actual(if_part) == if_part_state: target := new_target``."""

    name: str
    system: str
    if_target: StateMode
    if_part: str
    if_part_state: StateMode
    new_target: StateMode
    location: Location


@dataclass(frozen=True)
class Remote:
    """Where a remote part is served: the namespace of its manager's services (``""``: the root)
    and the part's name in that manager's model. ``served_by``: which manager that is, ``sm_bt``
    (``sm-bt manager``) or ``reference`` (micro-ROS/system_modes' ``mode_manager``, which learns
    states only from its nodes' events and sends its own from a 1 s timer)."""

    manager: str
    system: str
    served_by: str = REMOTE_MANAGERS[0]

    @property
    def fqn(self) -> str:
        """The name its services hang from: ``/robot1/pilot`` has ``/robot1/pilot/change_mode``."""
        return f"{self.manager}/{self.system}"


@dataclass(frozen=True)
class NodePart:
    """A lifecycle node of the model, with its parameter modes (file order); or, with ``remote``, a
    part another manager serves, seen as a node whose one parameter (:data:`REMOTE_MODE`) is its mode."""

    name: str
    default_mode: str
    modes: Mapping[str, NodeMode]
    rules: tuple[Rule, ...]
    location: Location
    remote: Remote | None = None
    kind: PartKind = field(default=PartKind.NODE, init=False)

    @property
    def parts(self) -> tuple[str, ...]:
        return ()

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The parameter set shared by every mode (the default mode's, in file order)."""
        return tuple(self.modes[self.default_mode].parameters)


@dataclass(frozen=True)
class SystemPart:
    """A system of the model: its parts (in ``parts:`` order) and its modes (file order)."""

    name: str
    default_mode: str
    modes: Mapping[str, SystemMode]
    parts: tuple[str, ...]
    rules: tuple[Rule, ...]
    location: Location
    kind: PartKind = field(default=PartKind.SYSTEM, init=False)


Part: TypeAlias = NodePart | SystemPart


def resolve_mode(part: Part, mode: str) -> str | None:
    """The mode of ``part`` that ``mode`` names: itself, or the default mode for ``__DEFAULT__``;
    None if the part has no such mode."""
    if mode in part.modes:
        return mode
    if mode == DEFAULT_MODE:
        return part.default_mode
    return None


class Severity(str, enum.Enum):
    ERROR = "error"
    WARNING = "warning"


@dataclass(frozen=True)
class ModelIssue:
    """One finding of the loader: where, how bad, and what to change."""

    location: Location
    severity: Severity
    message: str

    def __str__(self) -> str:
        return f"{self.location}: {self.severity.value}: {self.message}"


@dataclass(frozen=True)
class Model:
    """A validated model. Parts are in file order; see the query helpers for the hierarchy."""

    path: str
    parts: Mapping[str, Part]
    warnings: tuple[ModelIssue, ...] = ()

    def part(self, name: str) -> Part:
        """The part called ``name``; ``KeyError`` with the known names otherwise."""
        try:
            return self.parts[name]
        except KeyError:
            raise KeyError(f"no part {name!r} in model {self.path} (parts: {', '.join(self.parts)})") from None

    @property
    def nodes(self) -> tuple[NodePart, ...]:
        return tuple(p for p in self.parts.values() if isinstance(p, NodePart))

    @property
    def systems(self) -> tuple[SystemPart, ...]:
        return tuple(p for p in self.parts.values() if isinstance(p, SystemPart))

    def parents(self, name: str) -> tuple[str, ...]:
        """The systems that list ``name`` as one of their parts."""
        return tuple(s.name for s in self.systems if name in s.parts)

    def roots(self) -> tuple[str, ...]:
        """Parts that belong to no system (the tops of the hierarchies)."""
        return tuple(name for name in self.parts if not self.parents(name))

    def nodes_under(self, name: str) -> tuple[str, ...]:
        """Every node reachable from ``name`` (``name`` itself if it is a node), each once."""
        seen: dict[str, None] = {}
        stack = [name]
        while stack:
            current = self.parts[stack.pop()]
            if isinstance(current, NodePart):
                seen.setdefault(current.name, None)
            else:
                stack.extend(reversed(current.parts))
        return tuple(seen)

    def ancestors(self, name: str) -> tuple[str, ...]:
        """Every system above ``name``, lowest first (bottom-up order), each once."""
        order: list[str] = []
        frontier = list(self.parents(name))
        while frontier:
            current = frontier.pop(0)
            if current not in order:
                order.append(current)
                frontier.extend(self.parents(current))
        heights = self._heights(order)
        return tuple(sorted(order, key=heights.__getitem__))

    def height(self, name: str) -> int:
        """0 for a node, 1 + the tallest part for a system: sorting by it gives bottom-up order."""
        return self._heights([name])[name]

    def _heights(self, names: list[str]) -> dict[str, int]:
        """The height of each of ``names`` and of every part below them, without recursion (a
        hierarchy may be deeper than Python's recursion limit)."""
        heights: dict[str, int] = {}
        for start in names:
            stack = [(start, False)]
            while stack:
                current, expanded = stack.pop()
                if current in heights:
                    continue
                part = self.parts[current]
                children = () if isinstance(part, NodePart) else part.parts
                if not expanded and any(child not in heights for child in children):
                    stack.append((current, True))
                    stack.extend((child, False) for child in children if child not in heights)
                    continue
                heights[current] = 1 + max(heights.get(child, 0) for child in children) if children else 0
        return heights
