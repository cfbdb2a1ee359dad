"""The ROS 2 names of a model's parts: under a namespace, as ROS 2 resolves a relative name.

A part ``amcl`` of a manager in the root namespace is the node ``/amcl``; in ``/robot1`` it is
``/robot1/amcl``, and a system ``pilot`` is served at ``/robot1/pilot/change_mode``: the way a
launch file's ``namespace=`` puts a whole robot (Nav2's servers with it) under one prefix, so that
robots of a fleet share a ROS domain without sharing names.
"""

from __future__ import annotations

import re

#: rmw_validate_namespace: absolute, segments of letters, digits and underscores, no leading digit.
_NAMESPACE = re.compile(r"/|(/[A-Za-z_][A-Za-z0-9_]*)+")


def valid_namespace(text: str) -> bool:
    """``text`` is a namespace ROS 2 accepts for a node (``/``, ``/robot1``, ``/fleet/robot1``)."""
    return _NAMESPACE.fullmatch(text) is not None


def split_name(part: str, namespace: str = "/") -> tuple[str, str]:
    """``(namespace, name)`` of a model part's node: ``"left/gripper"`` -> ``("/left", "gripper")``;
    under ``/robot1``, ``("/robot1/left", "gripper")``."""
    inner, _, name = part.strip("/").rpartition("/")
    return "/" + "/".join(piece for piece in (namespace.strip("/"), inner) if piece), name


def qualified_name(part: str, namespace: str = "/") -> str:
    """The part's fully qualified name: ``"/left/gripper"``, ``"/amcl"``, ``"/robot1/pilot"``."""
    inner, name = split_name(part, namespace)
    return inner.rstrip("/") + "/" + name
