"""What a viewer shows of a py_trees tree after a tick, independent of how it is sent.

:func:`behaviours` walks the tree once and describes every behaviour (status, feedback, what it
works on, where it sits, which blackboard keys it touches); the ROS snapshot streams
(:mod:`sm_bt.ros.snapshot_streams`) turn that into ``py_trees_ros_interfaces`` messages, and a web
page can turn the same into py_trees_js JSON. Blackboard values are shown as ``str(value)``,
which is all a watcher sees of them.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import py_trees
from py_trees.common import BlackBoxLevel, Status

#: The kinds py_trees_ros and py_trees_js tell apart.
KINDS = ("behaviour", "sequence", "selector", "parallel", "chooser", "decorator")


@dataclass(frozen=True)
class BehaviourView:
    """One behaviour as a viewer shows it."""

    id: uuid.UUID
    name: str
    class_name: str  # module.Class
    kind: str  # one of KINDS
    status: Status
    feedback: str
    detail: str  # short text for the behaviour's box: a policy, a part and mode
    parent: uuid.UUID | None
    children: tuple[uuid.UUID, ...]
    tip: uuid.UUID | None  # the deepest running/ticked behaviour under it (None: itself or invalid)
    current_child: uuid.UUID | None
    blackbox: BlackBoxLevel
    access: tuple[tuple[str, str], ...]  # (key, "r" | "w" | "x")
    active: bool  # on the path ticked last


def kind_of(behaviour: py_trees.behaviour.Behaviour) -> str:
    if isinstance(behaviour, py_trees.composites.Sequence):
        return "sequence"
    if isinstance(behaviour, py_trees.composites.Selector):
        return "selector"
    if isinstance(behaviour, py_trees.composites.Parallel):
        return "parallel"
    if isinstance(behaviour, py_trees.decorators.Decorator):
        return "decorator"
    return "behaviour"


def detail_of(behaviour: py_trees.behaviour.Behaviour) -> str:
    """A composite's policy and memory; an sm_bt behaviour's part and mode (its ``detail``)."""
    own = getattr(behaviour, "detail", None)
    if isinstance(own, str) and own:
        return own
    if isinstance(behaviour, py_trees.composites.Parallel):
        return behaviour.policy.__class__.__name__.replace("Success", "")
    if isinstance(behaviour, py_trees.composites.Composite):
        return "memory" if getattr(behaviour, "memory", False) else ""
    return ""


def behaviours(root: py_trees.behaviour.Behaviour, visited: Iterable[uuid.UUID] = ()) -> list[BehaviourView]:
    """Every behaviour of the tree under ``root``, depth first; ``visited`` marks the active path."""
    active = set(visited)
    return [_view(behaviour, behaviour.id in active) for behaviour in root.iterate()]


def _view(behaviour: py_trees.behaviour.Behaviour, active: bool) -> BehaviourView:
    tip = behaviour.tip()
    current = getattr(behaviour, "current_child", None) if isinstance(behaviour, py_trees.composites.Composite) \
        else None
    return BehaviourView(
        id=behaviour.id,
        name=behaviour.name,
        class_name=f"{type(behaviour).__module__}.{type(behaviour).__name__}",
        kind=kind_of(behaviour),
        status=behaviour.status,
        feedback=behaviour.feedback_message,
        detail=detail_of(behaviour),
        parent=behaviour.parent.id if behaviour.parent is not None else None,
        children=tuple(child.id for child in behaviour.children),
        tip=tip.id if tip is not None and tip is not behaviour else None,
        current_child=current.id if current is not None else None,
        blackbox=behaviour.blackbox_level,
        access=tuple(_access(behaviour)),
        active=active,
    )


def _access(behaviour: py_trees.behaviour.Behaviour) -> Iterator[tuple[str, str]]:
    for client in behaviour.blackboards:
        yield from ((key, "r") for key in sorted(client.read))
        yield from ((key, "w") for key in sorted(client.write))
        yield from ((key, "x") for key in sorted(client.exclusive))


def blackboard_values(client_ids: Iterable[uuid.UUID]) -> list[tuple[str, str]]:
    """The blackboard variables these clients registered, as ``(key, str(value))`` (``-`` when
    unset), sorted by key."""
    keys = py_trees.blackboard.Blackboard.keys_filtered_by_clients(client_ids=set(client_ids))
    values = []
    for key in sorted(keys):
        try:
            values.append((key, str(py_trees.blackboard.Blackboard.get(key))))
        except KeyError:
            values.append((key, "-"))
    return values
