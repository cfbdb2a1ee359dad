"""Requesters, priorities and holds: several masters of one robot, with a defined answer.

Every user request names its requester and has a priority (by default the requester's, from
:data:`PRIORITIES`; the manager's ``priorities=`` changes them). A **hold** keeps a part in a
target for its requester, at its priority, until it is released or its lease runs out without
renewal (so a requester that died cannot pin the robot forever):

* a request that would change a part held at a higher priority is refused at once, with the
  holder in the reason: ``pilot is held in active.f_degraded_mode by laser_watch (priority 100)
  since 3.2 s``;
* a request at the same or a higher priority wins, as the last request always did: the holds it
  overrides end (``superseded by request #12 ...``);
* the nodes below a held part are held with it (its targets imply theirs): a request for a node
  that a hold needs elsewhere is refused too; two holds that need the same node in the same way
  share it.

A rule that fires holds its new target at the rule's priority **while its condition lasts**: until
its ``if_part`` is seen out of ``if_part_state``, or a request of the rule's priority or higher
decides otherwise. When the rule's own target keeps the condition true (the pilot's degraded mode
leaves the failed laser unconfigured, so nothing would ever tell that it is repaired), only such
a request ends it: whoever knows the fault is over says so with a priority (``sm-bt mode set
pilot f_normal_mode --priority 100``, ``priority="100"`` on a tree's ``ChangeMode``). Rule
requests are admitted like any other, at the rule's priority. Recovery restores the targets the
holds set and competes with nobody. With no hold, nothing is refused: one requester behaves
exactly as before.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field

from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.requests import Request
from sm_bt.model.states import StateMode

log = logging.getLogger("sm_bt.manager")

#: Default priorities by requester: a safety rule over an operator over a metacontroller over a
#: mission tree. A requester not named has :data:`DEFAULT_PRIORITY`.
PRIORITIES: Mapping[str, int] = {"rule": 100, "operator": 80, "metacontroller": 60, "tree": 40, "user": 40}
DEFAULT_PRIORITY = 40

_ids = itertools.count(1)


@dataclass(eq=False)
class Hold:
    """``part`` kept in ``target`` for ``requester`` at ``priority``; ``lease``: seconds it lasts
    without a :meth:`renew` (``None``: until released). ``targets``: what it holds, the part's
    and the targets it implies below. Ended (``active`` false) when released, expired or
    superseded; ``reason`` says which."""

    part: str
    target: StateMode
    requester: str
    priority: int
    since: float
    lease: float | None
    targets: Mapping[str, StateMode]
    id: int = field(default_factory=lambda: next(_ids))
    expires: float | None = None
    active: bool = True
    reason: str = ""
    #: The change the hold asked for (made by :meth:`ModeManager.hold`).
    request: Request | None = None
    #: A rule's hold lasts while this part is in this state (``None``: not a rule's).
    condition: tuple[str, StateMode] | None = None
    _holds: Holds | None = field(default=None, repr=False)

    def renew(self) -> None:
        """Start the lease again (from now); nothing once it ended. Takes no lock (a tree renews on
        every tick): it only moves ``expires``, which the lease's timer reads under the lock."""
        if self._holds is not None:
            self._holds.renew(self)

    def release(self) -> None:
        """End it now (its part keeps its target: nothing is asked of the nodes)."""
        holds = self._holds
        if holds is not None:
            holds.locked(lambda: holds.end(self, "released"))

    def holder(self) -> str:
        """Who holds it, at which priority, until when: ``metacontroller (priority 60, until 12.3 s)``."""
        until = f", until {self.expires:.1f} s" if self.expires is not None else ""
        return f"{self.requester} (priority {self.priority}{until})"

    def lasts(self) -> str:
        """A rule's hold's condition, as a refusal or an event says it ("" for any other hold)."""
        return f", while {self.condition[0]} is {self.condition[1]}" if self.condition is not None else ""

    def describe(self, now: float, part: str | None = None) -> str:
        """Why a request for ``part`` (default: the held part) is refused."""
        held = self.part if part is None or part == self.part else f"{part} (a part of {self.part})"
        return (f"{held} is held in {self.targets.get(part or self.part, self.target)} by {self.requester} "
                f"(priority {self.priority}) since {now - self.since:.1f} s{self.lasts()}")

    def __str__(self) -> str:
        until = f", lease {self.lease:g} s" if self.lease is not None else ""
        return f"hold #{self.id}: {self.part} in {self.target} by {self.requester} (priority {self.priority}{until})"


class Holds:
    """The holds in force, their leases on ``clock``; ``locked(action)`` runs ``action`` under the
    manager's lock (a lease ends in the clock's thread)."""

    def __init__(self, clock: Clock, priorities: Mapping[str, int] | None = None,
                 locked: Callable[[Callable[[], None]], None] | None = None,
                 told: Callable[[Hold, str], None] | None = None) -> None:
        self._clock = clock
        #: Told each hold that begins or ends, with a line that says so (the manager's events).
        self.told = told or (lambda hold, text: None)
        #: Called when a hold ends (queued requests may go ahead: :mod:`sm_bt.engine.waiting`).
        self.ended: Callable[[], None] = lambda: None
        self.priorities = {**PRIORITIES, **(priorities or {})}
        #: Runs an action under the manager's lock (a lease ends in the clock's thread).
        self.locked = locked or (lambda action: action())
        self._holds: dict[int, Hold] = {}
        self._timers: dict[int, TimerHandle] = {}
        # Each held part's holds, and how many parts are held in all: admission looks a request's
        # targets up here, or goes through the holds, whichever is fewer.
        self._by_part: dict[str, list[Hold]] = {}
        self._held_parts = 0
        self._conditional: list[Hold] = []  # rules' holds

    def priority_of(self, requester: str, priority: int | None = None) -> int:
        return priority if priority is not None else self.priorities.get(requester, DEFAULT_PRIORITY)

    def __iter__(self) -> Iterator[Hold]:
        return iter(list(self._holds.values()))

    def __bool__(self) -> bool:
        return bool(self._holds)

    def on(self, part: str) -> list[Hold]:
        """The holds that hold ``part`` (its own, and those of the systems above it)."""
        return list(self._by_part.get(part, ()))

    # -- admission --------------------------------------------------------------------------------

    def breaking(self, targets: Mapping[str, StateMode]) -> list[tuple[Hold, str]]:
        """The holds that ``targets`` would break, each with the first part it would change."""
        found: dict[int, tuple[Hold, str]] = {}
        if len(targets) <= self._held_parts:
            by_part = self._by_part
            for part, value in targets.items():
                for hold in by_part.get(part, ()):
                    if hold.id not in found and hold.targets[part] != value:
                        found[hold.id] = (hold, part)
        else:
            for hold in self._holds.values():
                changed = _conflict(hold.targets, targets)
                if changed is not None:
                    found[hold.id] = (hold, changed)
        return list(found.values())

    def overridden(self, targets: Mapping[str, StateMode], priority: int) -> list[Hold]:
        """The holds of the same or a lower priority that ``targets`` would break."""
        return [hold for hold, _ in self.breaking(targets) if hold.priority <= priority]

    def refusal(self, targets: Mapping[str, StateMode], priority: int) -> str:
        """Why a request for ``targets`` at ``priority`` is refused: the holds of a higher
        priority it would break ("" when none)."""
        now = self._clock.now()
        return "; ".join(hold.describe(now, part) for hold, part in self.breaking(targets) if hold.priority > priority)

    # -- life of a hold ---------------------------------------------------------------------------

    def add(self, part: str, target: StateMode, targets: Mapping[str, StateMode], requester: str, priority: int,
            lease: float | None, condition: tuple[str, StateMode] | None = None) -> Hold:
        now = self._clock.now()
        hold = Hold(part, target, requester, priority, now, lease, dict(targets), condition=condition, _holds=self)
        self._holds[hold.id] = hold
        for name in hold.targets:
            self._by_part.setdefault(name, []).append(hold)
        self._held_parts += len(hold.targets)
        if condition is not None:
            self._conditional.append(hold)
        if lease is not None:
            hold.expires = now + lease
            self._arm(hold)
        log.info("%s: held", hold)
        self.told(hold, f"{part} held in {target} by {hold.holder()}{hold.lasts()}")
        return hold

    def renew(self, hold: Hold) -> None:
        if hold.active and hold.lease is not None:
            hold.expires = self._clock.now() + hold.lease  # the timer re-arms itself when it fires early

    def end(self, hold: Hold, reason: str) -> None:
        if not hold.active:
            return
        hold.active, hold.reason = False, reason
        self._holds.pop(hold.id, None)
        for name in hold.targets:
            holders = self._by_part[name]
            holders.remove(hold)
            if not holders:
                del self._by_part[name]
        self._held_parts -= len(hold.targets)
        if hold.condition is not None:
            self._conditional.remove(hold)
        timer = self._timers.pop(hold.id, None)
        if timer is not None:
            timer.cancel()
        log.info("%s: %s", hold, reason)
        self.told(hold, f"{hold.part} no longer held by {hold.requester}: {reason}")
        self.ended()

    def conditions_over(self, is_in: Callable[[str, StateMode], bool]) -> None:
        """End the rules' holds whose condition no longer holds (``is_in(part, state)``: is the
        part in that state now)."""
        for hold in list(self._conditional):
            assert hold.condition is not None
            part, state = hold.condition
            if not is_in(part, state):
                self.end(hold, f"its condition is over: {part} is no longer {state}")

    def _arm(self, hold: Hold) -> None:
        assert hold.expires is not None
        self._timers[hold.id] = self._clock.call_later(max(0.0, hold.expires - self._clock.now()),
                                                       lambda: self.locked(lambda: self._due(hold)))

    def _due(self, hold: Hold) -> None:
        self._timers.pop(hold.id, None)
        if not hold.active or hold.expires is None:
            return
        if self._clock.now() + 1e-9 < hold.expires:  # renewed meanwhile
            self._arm(hold)
            return
        self.end(hold, f"its lease of {hold.lease:g} s ran out")

    def close(self) -> None:
        for hold in list(self._holds.values()):
            self.end(hold, "the manager is closed")


def _conflict(held: Mapping[str, StateMode], wanted: Mapping[str, StateMode]) -> str | None:
    """The first part ``wanted`` would give another target than ``held`` holds (``None``: none)."""
    small, large = (held, wanted) if len(held) <= len(wanted) else (wanted, held)
    for part, value in small.items():
        if part in large and large[part] != value:
            return part
    return None
