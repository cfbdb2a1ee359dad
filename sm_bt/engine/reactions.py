"""What the manager does about faults: rules first, bottom-up; then it restores nodes; within a budget.

For each ``FAULT`` divergence (children before their systems), the part's rules are tried: the
first whose ``if_target`` is the part's target and whose ``if_part`` is in the given state sets a
new target for the part. A rule that fired below keeps the systems above from reacting in the
same step: they see its effect once it is done. Where no rule fired, a node is restored to its
target. Nodes that cannot be reached (gone, never seen, finalized) are not restored: their
divergence says why, and they are restored once they come back.

Every reaction counts against the part's budget: ``attempts`` within a run of failures; the
budget is whole again once the part stayed on target for ``window`` seconds, or when a user
request covers it, or (for a node) when a new process of it appears. A part that used its budget
is *given up*: no more reactions, and its divergence says why (``"gave up after 3 attempts:
laser_resender hung in activating for 30 s"``) until it is back on target.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Protocol

from sm_bt.engine.divergences import EPSILON
from sm_bt.engine.events import Divergence
from sm_bt.engine.hierarchy import Hierarchy, implied_targets
from sm_bt.engine.inference import Actual, NodeObservation
from sm_bt.engine.requests import Origin
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, Rule


class StateReader(Protocol):
    def actual(self, part: str) -> Actual: ...

    def target(self, part: str) -> StateMode | None: ...

    def observation(self, node: str) -> NodeObservation: ...

    def chosen_by(self, part: str) -> Origin | None:
        """Who set the part's target for the part itself (``None``: it came from a system above)."""


@dataclass(frozen=True)
class FireRule:
    rule: Rule
    attempt: int


@dataclass(frozen=True)
class Restore:
    node: str
    target: StateMode
    attempt: int


@dataclass(frozen=True)
class GiveUp:
    divergence: Divergence
    message: str


Action = FireRule | Restore | GiveUp


class Reactions:
    """Decides the reactions to faults and keeps each part's budget."""

    def __init__(self, model: Model, hierarchy: Hierarchy, *, attempts: int, window: float,
                 rules: bool, recovery: bool) -> None:
        self._model = model
        self._hierarchy = hierarchy
        self.attempts = attempts
        self.window = window
        self.rules_enabled = rules
        self.recovery_enabled = recovery
        self.gave_up: dict[str, str] = {}  # part -> why
        self._used: dict[str, int] = {}  # reactions in the current run of failures
        self._back: dict[str, float] = {}  # when the part was last back on target after a reaction
        self._last: dict[str, str] = {}  # how the last reaction went

    # -- what happened (from the manager) -------------------------------------------------------

    def reset(self, parts: Iterable[str]) -> None:
        """A user asked for these parts (or a node restarted): their budgets are whole again."""
        for part in parts:
            self._used.pop(part, None)
            self._back.pop(part, None)
            self._last.pop(part, None)
            self.gave_up.pop(part, None)

    def back_on_target(self, part: str, now: float) -> None:
        self.gave_up.pop(part, None)
        if part in self._used:
            self._back[part] = now

    def finished(self, part: str, succeeded: bool, reason: str) -> None:
        """A reaction's request on ``part`` ended."""
        if not succeeded:
            self._last[part] = reason

    # -- decisions --------------------------------------------------------------------------------

    def decide(self, faults: list[Divergence], view: StateReader) -> list[Action]:
        """The reactions to ``faults`` (bottom-up), in the order to carry them out: every rule
        that applies first, then restoring the nodes that no rule above covers."""
        actions: list[Action] = []
        fired: set[str] = set()
        if self.rules_enabled:
            for divergence in faults:
                part = divergence.part
                if part in self.gave_up or any(part in self._hierarchy.ancestors[f] for f in fired):
                    continue  # given up, or a rule below is already correcting it
                rule = self._matching_rule(divergence, view)
                if rule is not None:
                    attempt = self._attempt(divergence, f"on {part}'s rules")
                    actions.append(attempt if isinstance(attempt, GiveUp) else FireRule(rule, attempt))
                    fired.add(part)
        if not self.recovery_enabled:
            return actions
        for divergence in faults:
            node = divergence.part
            if not isinstance(self._model.parts[node], NodePart) or node in self.gave_up or node in fired:
                continue
            if any(above in fired for above in self._hierarchy.ancestors[node]):
                continue  # a rule above has just re-targeted it
            obs = view.observation(node)
            if not obs.reachable or obs.state is State.FINALIZED:
                continue  # nothing to restore until it comes back; the divergence says why
            attempt = self._attempt(divergence, f"restoring {node} to {divergence.target}")
            actions.append(attempt if isinstance(attempt, GiveUp) else Restore(node, divergence.target, attempt))
        return actions

    def _matching_rule(self, divergence: Divergence, view: StateReader) -> Rule | None:
        for rule in self._model.parts[divergence.part].rules:
            condition = view.actual(rule.if_part)
            if rule.if_target == divergence.target and condition.meets(rule.if_part_state) \
                    and not self._users_choice(rule, view) and not self._undoes_users_choice(rule, view):
                return rule
        return None

    def _undoes_users_choice(self, rule: Rule, view: StateReader) -> bool:
        """Firing the rule would re-target a part below its system that a user asked for directly (an
        override, left alone): its new target asks something else of that part."""
        for part, wanted in implied_targets(self._model, rule.system, rule.new_target)[1:]:
            if view.chosen_by(part) is Origin.USER and view.target(part) != wanted:
                return True
        return False

    def _users_choice(self, rule: Rule, view: StateReader) -> bool:
        """The rule's condition holds because a user asked for it: its part is where its target
        says, and a user chose that target (for the part, or for a system between it and the
        rule's system). A rule never fires against that, nor when it would undo one (see below)."""
        part = rule.if_part
        target, actual = view.target(part), view.actual(part)
        if target is None or not actual.is_(target):
            return False
        height = self._hierarchy.height
        for chooser in (part, *self._hierarchy.ancestors[part]):
            if chooser == rule.system or height[chooser] >= height[rule.system]:
                break
            if view.chosen_by(chooser) is Origin.USER:
                return True
        return False

    def _attempt(self, divergence: Divergence, what: str) -> int | GiveUp:
        """The number of this attempt, or the decision to give up ``what`` (the budget is used)."""
        part = divergence.part
        back = self._back.get(part)
        if back is not None and divergence.since - back >= self.window - EPSILON:
            self.reset([part])  # it stayed on target for the window: a new run of failures
        elif back is not None:
            after = divergence.since - back
            when = f"{after:.2f} s after" if after >= 0.005 else "as soon as"  # no 3.55e-15 s
            self._last[part] = (f"{part} left {divergence.target} again {when} attempt "
                                f"{self._used.get(part, 0)} brought it back")
        self._back.pop(part, None)
        used = self._used.get(part, 0)
        if used >= self.attempts:
            last = self._last.get(part, f"{part} is {divergence.actual}")
            message = f"gave up {what} after {used} attempt{'s' if used != 1 else ''}: {last}"
            self.gave_up[part] = message
            return GiveUp(divergence, message)
        self._used[part] = used + 1
        return used + 1
