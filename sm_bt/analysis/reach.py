"""Reachability: every mode of every part, from the start (every node unconfigured) and from
every mode of the systems above it, planned by the engine's own preview (no node is touched).

A mode no request can reach is an error; a mode of a part that the systems above never ask for is
reachable only by a direct request, which the manager then takes for an override of their target
(a warning)."""

from __future__ import annotations

from collections.abc import Iterator

from sm_bt.analysis.findings import Finding, Kind, Level
from sm_bt.engine.preview import configuration, nodes_of, preview
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, SystemPart


def top_systems(model: Model) -> list[str]:
    """The systems no other system has as a part (their modes are what a mission asks for)."""
    inner = {child for part in model.parts.values() if isinstance(part, SystemPart) for child in part.parts}
    return [name for name, part in model.parts.items() if isinstance(part, SystemPart) and name not in inner]


def top_parts(model: Model) -> list[str]:
    """The parts no system has as a part: the top systems, and nodes of no system."""
    inner = {child for part in model.parts.values() if isinstance(part, SystemPart) for child in part.parts}
    return [name for name in model.parts if name not in inner]


def asked_for(model: Model) -> set[tuple[str, str]]:
    """(part, mode) that some mode of a top system asks for, down the hierarchy."""
    found: set[tuple[str, str]] = set()
    frontier = [(name, mode) for name in top_systems(model) for mode in model.parts[name].modes]
    while frontier:
        part, mode = frontier.pop()
        if (part, mode) in found:
            continue
        found.add((part, mode))
        system = model.parts[part]
        if isinstance(system, SystemPart):
            for entry in system.modes[mode].entries.values():
                if entry.target is not None and entry.target.state is State.ACTIVE and entry.target.mode:
                    frontier.append((entry.part, entry.target.mode))
    return found


def starts(model: Model) -> Iterator[tuple[str, dict[str, StateMode]]]:
    """The configurations the analysis starts from: every node unconfigured, then each mode of
    each top system (named ``system=active.MODE``)."""
    yield "the start (every node unconfigured)", {}
    for system in top_systems(model):
        for mode in model.parts[system].modes:
            yield f"{system}=active.{mode}", nodes_of(model, {system: StateMode(State.ACTIVE, mode)})


def conflicts(model: Model, system: str, mode: str) -> list[str]:
    """What ``mode`` of ``system`` asks of one part in two ways, through different systems below
    it (a node shared by two systems asked for two modes can never be both)."""
    asked: dict[str, tuple[StateMode, str]] = {}
    found: list[str] = []
    frontier = [(system, mode)]
    while frontier:
        name, wanted = frontier.pop(0)
        part = model.parts[name]
        if not isinstance(part, SystemPart):
            continue
        for entry in part.modes[wanted].entries.values():
            if entry.target is None:
                continue
            earlier = asked.get(entry.part)
            if earlier is not None and earlier[0] != entry.target:
                found.append(f"{entry.part} {earlier[0]} (through {earlier[1]}) and {entry.target} (through {name})")
                continue
            asked[entry.part] = (entry.target, name)
            if entry.target.state is State.ACTIVE and entry.target.mode and earlier is None:
                frontier.append((entry.part, entry.target.mode))
    return found


def reachability(model: Model) -> list[Finding]:
    findings: list[Finding] = []
    for name, part in model.parts.items():
        if isinstance(part, SystemPart):
            for mode_name, system_mode in part.modes.items():
                clash = conflicts(model, name, mode_name)
                if clash:
                    findings.append(Finding(Kind.UNREACHABLE, Level.ERROR, system_mode.location,
                                            f"mode {mode_name} of {name} can never be reached: it asks "
                                            f"{'; '.join(clash)}", f"change_mode {name} {mode_name}"))
    asked = asked_for(model)
    above = {child: name for name, part in model.parts.items() if isinstance(part, SystemPart) for child in part.parts}
    configs = [(label, configuration(model, nodes)) for label, nodes in starts(model)]
    for name, part in model.parts.items():
        for mode_name, mode in part.modes.items():
            target = StateMode(State.ACTIVE, mode_name)
            description = f"change_mode {name} {mode_name}"
            refused = [(label, plan.refused) for label, config in configs
                       if not (plan := preview(model, config, name, target, description)).possible]
            if refused:
                label, why = refused[0]
                findings.append(Finding(Kind.UNREACHABLE, Level.ERROR, mode.location,
                                        f"mode {mode_name} of {name} cannot be reached from {len(refused)} of "
                                        f"{len(configs)} configurations", f"from {label}: {why}"))
            elif name in above and (name, mode_name) not in asked and mode_name != part.default_mode:
                findings.append(Finding(Kind.OVERRIDE_ONLY, Level.WARNING, mode.location,
                                        f"mode {mode_name} of {name}: no mode of {above[name]} (or the systems above "
                                        f"it) asks for it, so only a direct request reaches it, and the manager takes "
                                        f"that for an override of {above[name]}'s target",
                                        f"sm-bt mode set {name} {mode_name}"))
    return findings


def routes(model: Model) -> list[tuple[str, str, str, int | str]]:
    """From each start (:func:`starts`), each mode of each top system: (start, system, mode, the
    number of calls its plan sends, or why it cannot be made)."""
    found: list[tuple[str, str, str, int | str]] = []
    configs = [(label, configuration(model, nodes)) for label, nodes in starts(model)]
    for system in top_systems(model):
        for mode in model.parts[system].modes:
            for label, config in configs:
                plan = preview(model, config, system, StateMode(State.ACTIVE, mode), f"change_mode {system} {mode}")
                found.append((label, system, mode, plan.calls if plan.possible else plan.refused))
    return found
