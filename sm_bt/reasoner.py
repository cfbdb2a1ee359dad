"""A metacontroller-style reasoner: pick the system mode of a part from component status and NFRs.

In the style of the MROS metacontroller (``mros2_reasoner``): each *function design* is a system
mode of one part, with estimated qualities (energy, performance, safety, ...) and the components
it requires. Components are reported OK or failed (``"FALSE"``; ``"RECOVERED"`` makes them OK
again). A design is *realisable* when none of its required components has failed. Among the
realisable designs, those that meet the objective's non-functional requirements (NFRs) are
preferred, ranked by the objective's utility quality, ties broken by mode name; when none meets
them, the best realisable design by utility is taken anyway, and the decision says so.

The reasoner is plain Python (no py_trees): a behaviour tree, a ROS node or a script can feed it
status reports, call :meth:`Reasoner.decide`, and apply the choice with
:meth:`Reasoner.reconfigure` through a :class:`~sm_bt.engine.manager.ModeManager`.

The pilot's designs and objective are the example's (:mod:`sm_bt.trees.pilot.designs`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model

__all__ = [
    "Decision",
    "FunctionDesign",
    "Objective",
    "Reasoner",
]

#: Status words of MROS diagnostics, by whether they mean "component OK".
_STATUS_WORDS = {"OK": True, "TRUE": True, "RECOVERED": True, "FALSE": False, "FAILED": False}


def _check_name(what: str, value: object) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"{what} must be a non-empty string, not {value!r}")
    return value


def _check_number(what: str, value: object) -> float:
    # bool is an int: reject it, a quality of True is a mistake, not 1.0.
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, not {value!r}")
    return float(value)


def _frozen_numbers(what: str, values: object) -> Mapping[str, float]:
    if not isinstance(values, Mapping):
        raise ValueError(f"{what} must be a mapping of quality name to number, not {values!r}")
    checked = {_check_name(f"a quality name in {what}", k): _check_number(f"{what}[{k!r}]", v)
               for k, v in values.items()}
    return MappingProxyType(checked)


@dataclass(frozen=True)
class FunctionDesign:
    """One way to realise the function: a system ``mode`` of the reasoner's part, the components
    it ``requires``, and its estimated ``qualities`` (quality name -> value)."""

    mode: str
    requires: frozenset[str]
    # Not hashed (a mapping is not hashable); equality still compares it.
    qualities: Mapping[str, float] = field(hash=False)

    def __post_init__(self) -> None:
        _check_name("a design's mode", self.mode)
        if "." in self.mode:
            raise ValueError(f"design mode {self.mode!r} may not contain '.' (it is a system mode name)")
        requires: object = self.requires
        if isinstance(requires, str) or not isinstance(requires, Iterable):
            raise ValueError(f"requires of design {self.mode} must be a set of component names, not {requires!r}")
        names = frozenset(_check_name(f"a component required by design {self.mode}", c) for c in requires)
        object.__setattr__(self, "requires", names)
        object.__setattr__(self, "qualities", _frozen_numbers(f"qualities of design {self.mode}", self.qualities))

    def quality(self, name: str) -> float:
        """The estimate of quality ``name``; ``ValueError`` naming the known ones if absent."""
        try:
            return self.qualities[name]
        except KeyError:
            known = ", ".join(sorted(self.qualities)) or "none"
            raise ValueError(f"design {self.mode} has no quality {name!r} (qualities: {known})") from None


@dataclass(frozen=True)
class Objective:
    """What the designs are judged by: upper bounds (``maximum``, e.g. energy) and lower bounds
    (``minimum``, e.g. safety) on qualities are the NFRs; ``utility`` ranks the designs."""

    maximum: Mapping[str, float] = field(default_factory=dict, hash=False)
    minimum: Mapping[str, float] = field(default_factory=dict, hash=False)
    utility: str = "performance"

    def __post_init__(self) -> None:
        object.__setattr__(self, "maximum", _frozen_numbers("objective maximum", self.maximum))
        object.__setattr__(self, "minimum", _frozen_numbers("objective minimum", self.minimum))
        _check_name("objective utility", self.utility)

    @property
    def qualities(self) -> frozenset[str]:
        """Every quality the objective reads (a design must estimate all of them)."""
        return frozenset(self.maximum) | frozenset(self.minimum) | {self.utility}

    def violations(self, design: FunctionDesign) -> tuple[str, ...]:
        """The NFRs ``design`` violates, readable (``"energy 0.7 > 0.5"``); empty when it meets them."""
        found = [f"{q} {design.quality(q):g} > {bound:g}" for q, bound in self.maximum.items()
                 if design.quality(q) > bound]
        found += [f"{q} {design.quality(q):g} < {bound:g}" for q, bound in self.minimum.items()
                  if design.quality(q) < bound]
        return tuple(found)

    def meets(self, design: FunctionDesign) -> bool:
        return not self.violations(design)

    def describe(self) -> str:
        """The NFRs as one line (``"energy <= 0.5, safety >= 0.5"``)."""
        bounds = [f"{q} <= {b:g}" for q, b in self.maximum.items()] + [f"{q} >= {b:g}" for q, b in self.minimum.items()]
        return ", ".join(bounds) or "no NFRs"


@dataclass(frozen=True)
class Decision:
    """The outcome of :meth:`Reasoner.decide`: the chosen ``design`` (``None`` when nothing is
    realisable), the realisable designs and those meeting the NFRs (best first), the failed
    components, and a one-line ``explanation``."""

    design: FunctionDesign | None
    realisable: tuple[str, ...]
    meeting_nfrs: tuple[str, ...]
    explanation: str
    failed: tuple[str, ...] = ()

    @property
    def mode(self) -> str | None:
        """The chosen mode, or ``None``."""
        return None if self.design is None else self.design.mode

    def __str__(self) -> str:
        return self.explanation


class Reasoner:
    """Choose the system mode of ``part`` among ``designs`` for ``objective``.

    Component statuses change through :meth:`component_failed`, :meth:`component_recovered`,
    :meth:`set_component` or :meth:`report`; every actual change increments :attr:`revision`,
    and :attr:`changed` tells whether one happened since the last :meth:`decide`, so a caller
    polling (a tree tick) only reconfigures when there is news. Thread-safe: reports may come
    from another thread than the one deciding.
    """

    def __init__(self, part: str, designs: Iterable[FunctionDesign], objective: Objective) -> None:
        self.part = _check_name("the reasoner's part", part)
        self.designs: tuple[FunctionDesign, ...] = tuple(designs)
        self.objective = objective
        if not self.designs:
            raise ValueError(f"reasoner for {part}: no function designs given")
        seen: set[str] = set()
        for design in self.designs:
            if not isinstance(design, FunctionDesign):
                raise ValueError(f"reasoner for {part}: {design!r} is not a FunctionDesign")
            if design.mode in seen:
                raise ValueError(f"reasoner for {part}: two designs for mode {design.mode}")
            seen.add(design.mode)
            missing = sorted(objective.qualities - set(design.qualities))
            if missing:
                raise ValueError(f"design {design.mode} lacks the qualities {', '.join(missing)} "
                                 f"that the objective reads ({objective.describe()}; utility {objective.utility})")
        #: Every component some design requires, sorted.
        self.components: tuple[str, ...] = tuple(sorted(set().union(*(d.requires for d in self.designs))))
        self._ok = dict.fromkeys(self.components, True)
        self._revision = 0
        self._decided_revision: int | None = None
        self._last: Decision | None = None
        self._lock = threading.RLock()

    # -- component status ------------------------------------------------------------------------

    def set_component(self, name: str, ok: bool) -> bool:
        """Set the status of component ``name``; return whether it changed."""
        with self._lock:
            self._check_component(name)
            if self._ok[name] is bool(ok):
                return False
            self._ok[name] = bool(ok)
            self._revision += 1
            return True

    def component_failed(self, name: str) -> bool:
        """Mark ``name`` failed (MROS status ``FALSE``); return whether it changed."""
        return self.set_component(name, False)

    def component_recovered(self, name: str) -> bool:
        """Mark ``name`` OK again (MROS status ``RECOVERED``); return whether it changed."""
        return self.set_component(name, True)

    def report(self, name: str, status: str) -> bool:
        """Apply an MROS-style diagnostic ``status`` (``"FALSE"``, ``"RECOVERED"``, ``"OK"``, any
        case); return whether the status changed."""
        ok = _STATUS_WORDS.get(str(status).strip().upper())
        if ok is None:
            raise ValueError(f"unknown status {status!r} for component {name} "
                             f"(use one of: {', '.join(_STATUS_WORDS)})")
        return self.set_component(name, ok)

    def is_ok(self, name: str) -> bool:
        with self._lock:
            self._check_component(name)
            return self._ok[name]

    def failed_components(self) -> tuple[str, ...]:
        """The failed components, sorted."""
        with self._lock:
            return tuple(name for name in self.components if not self._ok[name])

    @property
    def revision(self) -> int:
        """Incremented on every status change."""
        return self._revision

    @property
    def changed(self) -> bool:
        """True when a status changed since the last :meth:`decide` (or nothing was decided yet)."""
        with self._lock:
            return self._decided_revision != self._revision

    @property
    def last_decision(self) -> Decision | None:
        return self._last

    def _check_component(self, name: str) -> None:
        if name not in self._ok:
            raise ValueError(f"unknown component {name!r} for {self.part} (components: {', '.join(self.components)})")

    # -- decision -----------------------------------------------------------------------------

    def decide(self) -> Decision:
        """Choose a design for the current statuses (see the module docstring for the rules)."""
        with self._lock:
            failed = self.failed_components()
            decision = self._decide(failed)
            self._decided_revision = self._revision
            self._last = decision
            return decision

    def _decide(self, failed: tuple[str, ...]) -> Decision:
        utility = self.objective.utility
        broken = set(failed)
        realisable = sorted((d for d in self.designs if not d.requires & broken),
                            key=lambda d: (-d.quality(utility), d.mode))
        meeting = [d for d in realisable if self.objective.meets(d)]
        names = tuple(d.mode for d in realisable)
        meeting_names = tuple(d.mode for d in meeting)
        prefix = f"{', '.join(failed)} failed" if failed else "all components OK"
        if not realisable:
            return Decision(None, (), (), f"{prefix}: no design of {self.part} is realisable", failed)
        if meeting:
            chosen = meeting[0]
            if len(realisable) == 1:
                why = f"{chosen.mode} is the only realisable design"
            elif len(meeting) == 1:
                why = f"{chosen.mode} is the only realisable design meeting the NFRs ({self.objective.describe()})"
            else:
                why = (f"{chosen.mode} has the best {utility} ({chosen.quality(utility):g}) "
                       f"of the {len(meeting)} designs meeting the NFRs")
            excluded = [f"{d.mode}: {', '.join(self.objective.violations(d))}" for d in realisable if d not in meeting]
            if excluded:
                why += f" (excluded {'; '.join(excluded)})"
        else:
            chosen = realisable[0]
            why = (f"no realisable design meets the NFRs ({self.objective.describe()}); falling back to "
                   f"{chosen.mode}, the best {utility} ({chosen.quality(utility):g}) of {len(realisable)} realisable, "
                   f"which violates {', '.join(self.objective.violations(chosen))}")
        return Decision(chosen, names, meeting_names, f"{prefix}: {why}", failed)

    def reconfigure(self, manager: ModeManager, *, timeout: float | None = None,
                    requester: str = "reasoner") -> Request | None:
        """Decide, and ask ``manager`` for the chosen mode of the part unless its target already
        is that mode (active). ``None`` when there is nothing to do or nothing realisable
        (``last_decision`` says which). ``timeout`` bounds the change (``None``: the manager's);
        ``requester`` names who asks (:attr:`Request.requester`)."""
        decision = self.decide()
        if decision.design is None:
            return None
        if manager.target(self.part) == StateMode(State.ACTIVE, decision.design.mode):
            return None
        return manager.change_mode(self.part, decision.design.mode, timeout=timeout, requester=requester)

    def check(self, model: Model) -> None:
        """Raise ``ValueError`` unless ``model`` has the part and every design's mode is a mode
        of it: a typo would otherwise only show when the reasoner first picks that design."""
        try:
            part = model.part(self.part)
        except KeyError as error:
            raise ValueError(f"reasoner part {self.part!r} is not in the model: {error.args[0]}") from None
        missing = [d.mode for d in self.designs if d.mode not in part.modes]
        if missing:
            raise ValueError(f"designs of {self.part} name modes the model lacks: {', '.join(missing)} "
                             f"(modes of {self.part}: {', '.join(part.modes)})")
