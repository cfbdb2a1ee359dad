"""Node types a tree file declares in ``<TreeNodesModel>`` (Groot2's palette) that sm_bt has no
class for: declared Actions and Conditions run as stand-ins, so that a mission written for a robot's
own nodes (Nav2's ``ComputePathToPose``, a team's actions) loads, checks and runs on simulated
nodes. A stand-in takes the ports the declaration names, touches no blackboard key, does what
its stub says (:mod:`sm_bt.trees.stubs`; without one, it succeeds at once), and says in its
feedback what it stands in for.
"""

from __future__ import annotations

import time
import types
from collections.abc import Callable
from typing import Any

import py_trees
from py_trees.common import Status
from py_trees.ports import PortInformation, PortsMixin

from sm_bt.trees.stubs import Stub
from sm_bt.trees.tree_documents import Declared

#: The kinds a stand-in can take the place of (a control or decorator node decides what its
#: children do: that is behaviour to implement, not to stand in for).
STANDS_IN_FOR = frozenset({"Action", "Condition"})


class StandIn(PortsMixin, py_trees.behaviour.Behaviour, register=False):
    """What ``STUB`` says (SUCCESS at once without one); ``DECLARED`` is what it stands in for.

    * ``setup(clock=...)``: the clock its ``for`` is measured on (an object with ``now()``: the
      manager's, so that a simulated run's virtual time counts); else ``time.monotonic``
    * ``update``: the stub's status; RUNNING for the stub's seconds, then its ``then``
    """

    INPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, Any] = {}  # noqa: RUF012
    DECLARED: Declared
    STUB: Stub | None = None

    def __init__(self, name: str, *args: Any, **kwargs: Any) -> None:
        super().__init__(name, *args, **kwargs)
        self._now: Callable[[], float] = time.monotonic
        self._started = 0.0

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        self._subtree_namespace = subtree_namespace  # its ports are read by nobody: no keys registered

    def setup(self, **kwargs: Any) -> None:
        clock = kwargs.get("clock")
        if clock is not None:
            self._now = clock.now

    def initialise(self) -> None:
        self._started = self._now()

    def update(self) -> Status:
        declared, stub = self.DECLARED, self.STUB
        status = Status.SUCCESS if stub is None else stub.status
        if stub is not None and status == Status.RUNNING and stub.seconds is not None \
                and self._now() - self._started >= stub.seconds:
            status = stub.then
        what = f"stand-in for {declared.kind} {declared.node_id} (declared at {declared.path}:{declared.line})" \
            if stub is None else f"stand-in for {declared.node_id} ({stub.path}:{stub.line}: {stub.describe()})"
        self.feedback_message = what
        return status


def stand_in(declared: Declared, stub: Stub | None = None) -> type[StandIn]:
    """A :class:`StandIn` class for ``declared`` (an Action or a Condition), with its ports, doing
    what ``stub`` says."""
    port = PortInformation(str, required=False)
    body = {"INPUT_PORTS": dict.fromkeys(declared.inputs, port),
            "OUTPUT_PORTS": {name: port for name in declared.outputs if name not in declared.inputs},
            "DECLARED": declared, "STUB": stub, "__module__": __name__}
    # Not in py_trees' ports registry: a declaration holds for the file that makes it, not for every
    # tree loaded after it.
    return types.new_class(declared.node_id, (StandIn,), {"register": False}, lambda namespace: namespace.update(body))
