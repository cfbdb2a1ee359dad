"""Bottom-up inference: from what nodes report to the state and mode of every part.

Nodes report a lifecycle state and parameter values; a node's mode is inferred from its
parameters (only while it is active), a system's state and mode from its parts, recursively.
Tie-breaking follows the reference implementation: the target mode first, then the default
mode, then every mode in byte-wise order of names. Unlike the reference, a part that was never
seen makes its systems ``unknown`` with a reason instead of failing the whole inference.

Inference is incremental: an update about one node recomputes that node and the systems above
it, and returns only the parts whose result changed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from sm_bt.engine.actual import Actual, NodeObservation
from sm_bt.engine.hierarchy import Hierarchy
from sm_bt.engine.tallies import (
    MOVING_TO,
    Tally,
    first_difference,
    relevant_parts,
    system_mode_matches,
    unknown_reason,
    untargeted_mismatch,
)
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, NodePart, ParamValue, SystemPart

__all__ = ["Actual", "Changes", "Inference", "NodeObservation", "infer_all", "infer_node", "infer_system"]


Changes = dict[str, tuple[Actual, Actual]]
_ACTIVE = State.ACTIVE  # read once: an enum's member is slow to look up


def node_mode_candidates(part: NodePart, target: StateMode | None) -> list[str]:
    """Modes in tie-break order: target mode, default mode, then byte-wise by name."""
    order: list[str] = []
    if target is not None and target.mode is not None and target.mode in part.modes:
        order.append(target.mode)
    order.append(part.default_mode)
    order.extend(sorted(part.modes))
    return list(dict.fromkeys(order))


def infer_node(part: NodePart, obs: NodeObservation, target: StateMode | None,
               candidates: Sequence[str] | None = None) -> Actual:
    """A node's actual from what it reported. ``candidates``: ``node_mode_candidates(part,
    target)``, when the caller keeps them."""
    if not obs.seen:
        return Actual(part.name, State.UNKNOWN, state_inferred=False, reason="never seen")
    if obs.gone:
        return Actual(part.name, State.UNKNOWN, state_inferred=False, reason=obs.gone)
    state_inferred = not obs.lifecycle
    if obs.state is not _ACTIVE:
        # A node's mode only means something while it is active.
        return Actual(part.name, obs.state, None, state_inferred, False)
    modes = part.modes
    for name in node_mode_candidates(part, target) if candidates is None else candidates:
        if modes[name].matches(obs.parameters):
            return Actual(part.name, _ACTIVE, name, state_inferred)
    return Actual(part.name, _ACTIVE, None, state_inferred, True, _mode_mismatch(part, obs.parameters))


def _mode_mismatch(part: NodePart, parameters: Mapping[str, ParamValue]) -> str:
    default = part.modes[part.default_mode]
    shown = ", ".join(
        f"{name}={parameters[name]!r}" if name in parameters else f"{name} unset" for name in default.parameters
    )
    return f"parameters match no mode ({shown})"


def infer_system(part: SystemPart, actual_of: Callable[[str], Actual], target: StateMode | None) -> Actual:
    actuals = [actual_of(name) for name in part.parts]
    for actual in actuals:
        if actual.state is State.ERRORPROCESSING:
            return Actual(part.name, State.ERRORPROCESSING, reason=f"{actual.part} is in errorprocessing")

    relevant = relevant_parts(part, target)
    unknown = [a for a in actuals if a.part in relevant and not a.known]
    if unknown:
        return Actual(part.name, State.UNKNOWN, reason=unknown_reason(unknown))

    if target is None:
        return _infer_untargeted(part, actual_of, actuals)
    if target.state is State.ACTIVE:
        wanted = target.mode if target.mode is not None and target.mode in part.modes else part.default_mode
        if system_mode_matches(part, wanted, actual_of):
            return Actual(part.name, State.ACTIVE, wanted)
        # Still on the way: report the first mode (byte-wise) the parts do match, as the reference.
        for name in sorted(part.modes):
            if name != wanted and system_mode_matches(part, name, actual_of):
                return Actual(part.name, State.ACTIVATING, name, reason=first_difference(part, wanted, actual_of))
        return Actual(part.name, State.ACTIVATING, reason=first_difference(part, wanted, actual_of))

    if all(a.state is target.state for a in actuals):
        return Actual(part.name, target.state)
    moving = MOVING_TO.get(target.state)
    if moving is None:  # target inactive: coming down from active, or up from unconfigured
        going_down = any(a.state in (State.ACTIVE, State.ACTIVATING, State.DEACTIVATING) for a in actuals)
        moving = State.DEACTIVATING if going_down else State.CONFIGURING
    lagging = next(a for a in actuals if a.state is not target.state)
    return Actual(part.name, moving, reason=f"{lagging.part} is {lagging.state.label}")


def _infer_untargeted(part: SystemPart, actual_of: Callable[[str], Actual], actuals: list[Actual]) -> Actual:
    """A system nobody has commanded yet: the parts' common state, or the mode they match."""
    states = {a.state for a in actuals}
    if len(states) == 1 and State.ACTIVE not in states:
        return Actual(part.name, states.pop())
    for name in [part.default_mode, *sorted(part.modes)]:
        if system_mode_matches(part, name, actual_of):
            return Actual(part.name, State.ACTIVE, name)
    return untargeted_mismatch(part, actual_of, states)


class Inference:
    """Keeps node observations and targets, and the inferred actual of every part up to date.

    Systems are inferred from a :class:`~sm_bt.engine.tallies.Tally` of their parts (the same
    answer as :func:`infer_system`, in time independent of their size), and an update climbs only
    as far as something changed.
    """

    def __init__(self, model: Model, hierarchy: Hierarchy | None = None) -> None:
        self.model = model
        self._hierarchy = hierarchy if hierarchy is not None else Hierarchy.of(model)
        self._observations = {node.name: NodeObservation() for node in model.nodes}
        self._targets: dict[str, StateMode] = {}
        self._actual: dict[str, Actual] = {}
        self._tallies: dict[str, Tally] = {}
        self._actual_of = self._actual.__getitem__
        #: Read-only views for the engine's hot paths (a mapping lookup, not a method call).
        self.targets: Mapping[str, StateMode] = self._targets
        self.actuals: Mapping[str, Actual] = self._actual
        self.observations: Mapping[str, NodeObservation] = self._observations
        # A node's candidate modes depend only on its mode names, default and target mode: nodes
        # alike share one list (at 100,000 nodes, a list per node and mode asked was 30 MB).
        self._modes_of: dict[str, tuple[str, ...]] = {}
        shared: dict[tuple[str, ...], tuple[str, ...]] = {}
        for node in model.nodes:
            names = (node.default_mode, *node.modes)
            self._modes_of[node.name] = shared.setdefault(names, names)
        self._candidates: dict[tuple[tuple[str, ...], str | None], list[str]] = {}  # (modes, target mode) -> order
        for name in self._hierarchy.bottom_up:
            part = model.parts[name]
            if isinstance(part, SystemPart):
                self._tallies[name] = Tally(part, self._actual.__getitem__)
            self._actual[name] = self._compute(name)

    # -- queries -----------------------------------------------------------------------------

    def actual(self, part: str) -> Actual:
        return self._actual[part]

    def target(self, part: str) -> StateMode | None:
        return self._targets.get(part)

    def observation(self, node: str) -> NodeObservation:
        return self._observations[node]

    # -- updates (each returns what changed) ---------------------------------------------------

    def set_target(self, part: str, target: StateMode | None) -> Changes:
        if target is None:
            self._targets.pop(part, None)
        else:
            self._targets[part] = target
        return self._recompute(part)

    def node_appeared(self, node: str, state: State, parameters: Mapping[str, ParamValue],
                      lifecycle: bool = True) -> Changes:
        self._observations[node] = NodeObservation(True, state, dict(parameters), lifecycle)
        return self._recompute(node)

    def node_state(self, node: str, state: State) -> Changes:
        obs = self._observations[node]
        obs.seen, obs.state, obs.gone = True, state, ""
        return self._recompute(node)

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> Changes:
        obs = self._observations[node]
        # A new dict, not an update: whoever holds the old one (a preview) keeps what it saw.
        obs.parameters = {**obs.parameters, **changed}
        return self._recompute(node)

    def node_vanished(self, node: str, reason: str) -> Changes:
        obs = self._observations[node]
        obs.gone = reason or "vanished"
        return self._recompute(node)

    def _recompute(self, part: str) -> Changes:
        """``part``, then the systems above it that see a change, bottom-up."""
        changes: Changes = {}
        actual, parents, tallies = self._actual, self._hierarchy.parents, self._tallies
        pending = {part}
        for name in (part, *self._hierarchy.ancestors[part]):
            if name not in pending:
                continue
            pending.discard(name)
            new = self._compute(name)
            old = actual[name]
            if new != old:
                actual[name] = new
                changes[name] = (old, new)
                for parent in parents[name]:
                    tallies[parent].update(name, old, new)
                    pending.add(parent)
            if not pending:
                break
        return changes

    def _compute(self, name: str) -> Actual:
        target = self._targets.get(name)
        tally = self._tallies.get(name)
        if tally is not None:
            return tally.infer(target, self._actual_of)
        part = self.model.parts[name]
        assert isinstance(part, NodePart)
        key = (self._modes_of[name], None if target is None else target.mode)
        candidates = self._candidates.get(key)
        if candidates is None:
            candidates = self._candidates[key] = node_mode_candidates(part, target)
        return infer_node(part, self._observations[name], target, candidates)


def infer_all(model: Model, observations: Mapping[str, NodeObservation],
              targets: Mapping[str, StateMode]) -> dict[str, Actual]:
    """Every part's actual from scratch, with :func:`infer_node`/:func:`infer_system` (the
    reference the incremental :class:`Inference` must agree with)."""
    actual: dict[str, Actual] = {}
    for name in Hierarchy.of(model).bottom_up:
        part = model.parts[name]
        if isinstance(part, NodePart):
            actual[name] = infer_node(part, observations[name], targets.get(name))
        else:
            actual[name] = infer_system(part, actual.__getitem__, targets.get(name))
    return actual
