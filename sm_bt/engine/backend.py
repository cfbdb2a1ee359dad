"""The backend protocol: how the engine talks to lifecycle nodes, simulated or real.

One protocol serves :mod:`sm_bt.sim` and the ROS 2 backend. It is asynchronous: requests return
at once and report their outcome through a callback; what the nodes report (state changes,
parameter changes, appearing, vanishing) comes through a :class:`BackendListener`.

Contract for implementations:

* ``attach`` starts observing the given nodes. For every node that is (or later becomes)
  reachable, the listener gets ``node_appeared`` with the node's *live* state and parameters
  before any other report about it. A node that stops answering gets ``node_vanished`` within a
  bounded time; calls in flight on it then complete with ``ok=False``.
* ``change_state`` and ``set_parameters`` never block and never call ``done`` from inside the
  call itself; ``done`` is called exactly once. A node's state reports (``node_state``) may come
  before or after the ``done`` of the request that caused them.
* ``set_parameters`` is atomic: all values are applied, or none.
* Listener and ``done`` callbacks may come from any thread; the manager serialises them.
* Reports and ``done`` callbacks that arrive together (a simulated instant, say) may be made
  inside ``with listener.batch():``: the manager applies each in order and settles once, at the
  end, rather than once per report.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Protocol

from sm_bt.engine.clock import Clock
from sm_bt.engine.lifecycle import Transition
from sm_bt.model.states import State
from sm_bt.model.types import ParamValue


@dataclass(frozen=True)
class CallResult:
    """Outcome of a request to a node. ``reason`` says why when ``ok`` is false.

    ``refused`` (``change_state`` only): the node did not run the transition because it is not
    valid in the state the node is in. Nothing changed on the node; if the caller planned it from
    the state last reported, that report was out of date (the node moved since, by itself or for
    someone else), and the next report tells where it is.
    """

    ok: bool
    reason: str = ""
    refused: bool = False


Done = Callable[[CallResult], None]


@dataclass(frozen=True)
class NodeReport:
    """What a backend acquired about a node when it (re)appeared.

    ``lifecycle`` is false for a node without lifecycle services (parameters only): its
    ``state`` is then what the backend observes of it as a running process (``active``), and the
    engine marks that state as inferred rather than reported.
    """

    state: State
    parameters: Mapping[str, ParamValue] = field(default_factory=dict)
    lifecycle: bool = True


class BackendListener(Protocol):
    def node_appeared(self, node: str, report: NodeReport) -> None: ...

    def node_state(self, node: str, state: State) -> None: ...

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None: ...

    def node_vanished(self, node: str, reason: str) -> None: ...

    def batch(self) -> AbstractContextManager[None]:
        """Reports and ``done`` callbacks made inside are handled together (see the module)."""
        ...


class Backend(Protocol):
    """What the mode manager needs from the world of nodes."""

    @property
    def clock(self) -> Clock: ...

    def attach(self, nodes: Sequence[str], listener: BackendListener) -> None: ...

    def detach(self) -> None: ...

    def change_state(self, node: str, transition: Transition, done: Done) -> None: ...

    def set_parameters(self, node: str, parameters: Mapping[str, ParamValue], done: Done) -> None: ...
