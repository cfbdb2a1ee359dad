"""Node types a tree file declares in ``<TreeNodesModel>`` (Groot2's palette) that sm_bt has no
class for: declared Actions and Conditions run as stand-ins, so that a mission written for a robot's
own nodes (Nav2's ``ComputePathToPose``, a team's actions) loads, checks and runs on simulated
nodes. A stand-in takes the ports the declaration names, touches no blackboard key, and
succeeds at once, saying what it stands in for in its feedback.
"""

from __future__ import annotations

import types
from typing import Any

import py_trees
from py_trees.common import Status
from py_trees.ports import PortInformation, PortsMixin

from sm_bt.trees.tree_documents import Declared

#: The kinds a stand-in can take the place of (a control or decorator node decides what its
#: children do: that is behaviour to implement, not to stand in for).
STANDS_IN_FOR = frozenset({"Action", "Condition"})


class StandIn(PortsMixin, py_trees.behaviour.Behaviour, register=False):
    """SUCCESS at once, every tick; ``DECLARED`` is what it stands in for."""

    INPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012
    DECLARED: Declared

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        self._subtree_namespace = subtree_namespace  # its ports are read by nobody: no keys registered

    def update(self) -> Status:
        """SUCCESS (a stand-in has nothing to wait for)."""
        declared = self.DECLARED
        self.feedback_message = (f"stand-in for {declared.kind} {declared.node_id} "
                                 f"(declared at {declared.path}:{declared.line})")
        return Status.SUCCESS


def stand_in(declared: Declared) -> type[StandIn]:
    """A :class:`StandIn` class for ``declared`` (an Action or a Condition), with its ports."""
    port = PortInformation(str, required=False)
    body = {"INPUT_PORTS": dict.fromkeys(declared.inputs, port),
            "OUTPUT_PORTS": {name: port for name in declared.outputs if name not in declared.inputs},
            "DECLARED": declared, "__module__": __name__}
    # Not in py_trees' ports registry: a declaration holds for the file that makes it, not for every
    # tree loaded after it.
    return types.new_class(declared.node_id, (StandIn,), {"register": False}, lambda namespace: namespace.update(body))
