"""Build a remote part: a part another mode manager serves (a robot of a fleet, an arm's computer).

A remote part names its manager's namespace and its name in that manager's model, and lists the
modes that manager offers for it::

    robot1:
      ros__parameters:
        type: remote
        manager: /robot1        # its services: /robot1/pilot/change_mode, ... (omitted: the root)
        system: pilot           # omitted: the part's own name
        modes: [__DEFAULT__, f_degraded_mode]
        served_by: reference    # omitted: sm_bt (sm-bt manager)

To the engine it is a node whose one parameter, :data:`~sm_bt.model.types.REMOTE_MODE`, is the
mode its manager reports, and whose modes each set it to their name: inference, divergences,
rules, recovery, preview and holds treat it as they treat a node, and the backend turns a "set"
of that parameter into a request to its manager.
"""

from __future__ import annotations

import re

from sm_bt.model.declarations import PartDecl
from sm_bt.model.diagnostics import Diagnostics
from sm_bt.model.errors import Error
from sm_bt.model.rcl_yaml import YScalar, describe
from sm_bt.model.types import REMOTE_MANAGERS, REMOTE_MODE, Location, Model, NodeMode, NodePart, ParamSpec, Remote

# rmw_validate_namespace: an absolute namespace of segments as node names have them.
_NAMESPACE = re.compile(r"(/[A-Za-z_][A-Za-z0-9_]*)*/?")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")


def build_remote(decl: PartDecl, diag: Diagnostics) -> NodePart | None:
    """The remote part as the engine sees it, or ``None`` when it cannot be built (reported)."""
    manager = _text(decl, "manager", "", diag)
    system = _text(decl, "system", decl.name.rsplit("/", 1)[-1], diag)
    served_by = _text(decl, "served_by", REMOTE_MANAGERS[0], diag)
    if manager is None or system is None or served_by is None or decl.modes is None \
            or decl.default_mode is None:
        return None
    if served_by not in REMOTE_MANAGERS:
        diag.error(_line(decl, "served_by"), f"served_by {served_by!r} of remote part {decl.name!r} is not "
                                             f"{' or '.join(REMOTE_MANAGERS)}: 'reference' for micro-ROS/system_modes' "
                                             "mode_manager, else leave it out (sm-bt manager)")
        return None
    if not _NAMESPACE.fullmatch(manager):
        diag.error(_line(decl, "manager"), f"manager {manager!r} of remote part {decl.name!r} is not a ROS 2 "
                                           "namespace: write it absolute, e.g. '/robot1', or leave it out for the root")
        return None
    if not _NAME.fullmatch(system.lstrip("/")):
        diag.error(_line(decl, "system"), f"system {system!r} of remote part {decl.name!r} is not a part name: use "
                                          "letters, digits and underscores, as in that manager's model")
        return None
    modes = {}
    for key, _ in decl.modes:
        where = Location(diag.file, key.line)
        modes[key.text] = NodeMode(key.text, {REMOTE_MODE: ParamSpec(REMOTE_MODE, key.text, where)}, where)
    return NodePart(decl.name, decl.default_mode, modes, (), Location(diag.file, decl.line),
                    Remote(manager.rstrip("/"), system.lstrip("/"), served_by))


def _text(decl: PartDecl, key: str, default: str, diag: Diagnostics) -> str | None:
    entry = decl.params.get(key)
    if entry is None:
        return default
    if not isinstance(entry[1], YScalar) or not isinstance(entry[1].value, str):
        diag.error(entry[0].line, f"{key!r} of remote part {decl.name!r} must be a name, not {describe(entry[1])}")
        return None
    return entry[1].text


def _line(decl: PartDecl, key: str) -> int:
    entry = decl.params.get(key)
    return entry[0].line if entry is not None else decl.line


class MixedModel(Error, ValueError):
    """A model with both remote parts and nodes (a fleet manager's parts are remote ones only), or
    given to the ROS backend of the other kind."""


def check_fleet(model: Model) -> bool:
    """Whether ``model`` is a fleet's (its nodes are all remote parts); :class:`MixedModel` when only
    some are."""
    remote = [part.name for part in model.nodes if part.remote is not None]
    local = [part.name for part in model.nodes if part.remote is None]
    if remote and local:
        raise MixedModel(f"{model.path}: {', '.join(local[:5])}{' ...' if len(local) > 5 else ''} are nodes beside "
                         f"the remote parts {', '.join(remote[:5])}: a fleet manager drives remote parts only; put "
                         "the nodes in a robot's model, served by that robot's manager")
    return bool(remote)
