"""Scale and P3: the manager's cost against the number of nodes, on the simulated backend.

Generated models (:mod:`bench.generated`: N nodes in systems of 10, nested to one root) at
N = 100 ... 10,000. CPU time (``process_time``) of the whole request, from the call until it is
done, includes the simulated nodes' own work (they run in this process, with no delays). After
construction the model and manager are kept out of the garbage collector's passes, as ``sm-bt
manager`` does (:func:`~sm_bt.model.gc_tuning.freeze_long_lived`); construction is timed before.

P3 times the manager's handling of single node events (inference, divergences, request
progress, events to observers), seen at the backend listener: every node report of a
whole-system mode change (the median is the goal's figure), and a fault event that flips one
node's mode and with it every system above it (its worst case). Reports that come at one simulated
instant are one batch, settled once (:meth:`~sm_bt.engine.backend.BackendListener.batch`): each of
them counts as the batch's time over the reports in it. The growth from N = 1,000 to
10,000 comes from managers of both sizes changing modes in turns, in the same minute.
"""

from __future__ import annotations

import functools
import gc
import statistics
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

from bench.figures import Figure
from bench.generated import ROOT, model_text, shape
from sm_bt.engine.backend import BackendListener, NodeReport
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.hierarchy import implied_targets
from sm_bt.engine.holds import DEFAULT_PRIORITY
from sm_bt.engine.inference import infer_all
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.gc_tuning import freeze_long_lived
from sm_bt.model.loader import load_model_text
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model, ParamValue
from sm_bt.sim import SimBackend, SimulatedSystem

SIZES = (100, 250, 500, 1000, 2500, 5000, 10_000)
QUICK_SIZES = (100, 250)
#: Goals of the issue, by figure and N.
REQUEST_GOALS = {1000: 0.5, 10_000: 5.0}
#: A request's admission check with 100 holds at 10,000 nodes (issue 33), microseconds.
ADMISSION_GOAL_US = 10.0
#: Previewing a whole-system change (issue 32), CPU milliseconds.
PREVIEW_GOAL_MS = {1000: 5.0, 10_000: 50.0}
CONSTRUCTION_GOAL = {10_000: 2.0}
EVENT_GOAL_US = {10_000: 50.0}
#: The manager's part of a fault at 10,000 nodes (issue 35), microseconds.
FAULT_GOAL_US = {10_000: 30.0}
FULL_OVER_EVENT_GOAL = 100.0
GROWTH_GOAL = 1.5
FAULT_EVENTS, QUICK_FAULT_EVENTS = 2000, 200
#: Mode changes of each size, taking turns, for the growth of the node event's cost.
GROWTH_ROUNDS = 6


@functools.lru_cache(maxsize=2)
def model(nodes: int) -> Model:
    return load_model_text(model_text(nodes), f"generated-{nodes}.yaml")


class _TimedListener:
    """Passes every report on to the manager's listener, timing each one while ``on``."""

    def __init__(self, listener: BackendListener) -> None:
        self._listener = listener
        self.on = False
        self.times: list[float] = []
        self._batched: int | None = None  # reports in the batch under way

    @contextmanager
    def batch(self) -> Iterator[None]:
        if self._batched is not None:  # within another: counted there
            yield
            return
        self._batched = 0
        start = time.perf_counter()
        try:
            with self._listener.batch():
                yield
        finally:
            elapsed, reports, self._batched = time.perf_counter() - start, self._batched, None
            if self.on and reports:
                self.times += [elapsed / reports] * reports

    def _timed(self, call: Callable[[], None]) -> None:
        if self._batched is not None:
            self._batched += 1
        if not self.on or self._batched is not None:
            call()
            return
        start = time.perf_counter()
        call()
        self.times.append(time.perf_counter() - start)

    def node_appeared(self, node: str, report: NodeReport) -> None:
        self._timed(lambda: self._listener.node_appeared(node, report))

    def node_state(self, node: str, state: State) -> None:
        self._timed(lambda: self._listener.node_state(node, state))

    def node_parameters(self, node: str, changed: Mapping[str, ParamValue]) -> None:
        self._timed(lambda: self._listener.node_parameters(node, changed))

    def node_vanished(self, node: str, reason: str) -> None:
        self._timed(lambda: self._listener.node_vanished(node, reason))


class Rig:
    """A manager over simulated nodes that all start ``state``, its construction timed."""

    def __init__(self, model: Model, state: State) -> None:
        self.backend = SimBackend(model, transition_delay=0.0, error_delay=0.0, parameter_delay=0.0,
                                  initial_state=state, history=False)
        attach = self.backend.attach
        self.listener: _TimedListener | None = None

        def timed_attach(nodes: Sequence[str], listener: BackendListener) -> None:
            self.listener = _TimedListener(listener)
            attach(nodes, self.listener)

        self.backend.attach = timed_attach  # type: ignore[method-assign]
        gc.collect()
        start = time.process_time()
        self.system = SimulatedSystem(model, backend=self.backend, record=False)
        self.construction = time.process_time() - start
        self.manager = self.system.manager

    def drive(self, request: Request) -> None:
        """Run the simulation until ``request`` is done; it must have succeeded."""
        for _ in range(100):
            if request.done:
                break
            self.backend.clock.advance(1.0)
        if not request.succeeded:
            raise RuntimeError(f"{request.description} did not succeed: {request.reason}")


@contextmanager
def _frozen() -> Iterator[None]:
    """As ``sm-bt manager`` runs: what exists now stays out of the collector's passes, and they are rarer."""
    thresholds = gc.get_threshold()
    freeze_long_lived()
    try:
        yield
    finally:
        gc.unfreeze()
        gc.set_threshold(*thresholds)


def _cpu(work: Callable[[], object]) -> float:
    start = time.process_time()
    work()
    return time.process_time() - start


def fault_events(rig: Rig, count: int) -> list[float]:
    """Flip one node in the middle of the model out of its mode and back, ``count`` times."""
    nodes = shape(len(rig.manager.model.nodes))[0].nodes
    index = len(nodes) // 2
    node, settled = nodes[index], 1.0 + index % 7  # its FAST speed (bench.generated)
    assert rig.listener is not None
    rig.listener.times.clear()
    rig.listener.on = True
    for i in range(count):
        rig.backend.set_parameter(node, "speed", 99.0 if i % 2 == 0 else settled)
    rig.listener.on = False
    return list(rig.listener.times)


def _full_inference(rig: Rig) -> float:
    manager = rig.manager
    observations = {node.name: manager.observation(node.name) for node in manager.model.nodes}
    targets = {part: target for part in manager.model.parts if (target := manager.target(part)) is not None}
    times = []
    for _ in range(3):
        start = time.perf_counter()
        infer_all(manager.model, observations, targets)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def _from_active(loaded: Model, faults: int) -> dict[str, Any]:
    """Construction, the mode change, and the node events (of three mode changes, and faults)."""
    rig = Rig(loaded, State.ACTIVE)
    listener = rig.listener
    assert listener is not None
    out: dict[str, Any] = {"construction": rig.construction}
    with _frozen():
        listener.on = True
        # The preview of the change about to be made: the median of a few, nothing sent.
        out["preview"] = statistics.median(_cpu(lambda: rig.manager.preview(ROOT, "FAST")) for _ in range(5))
        out["mode_change"] = _cpu(lambda: rig.drive(rig.manager.change_mode(ROOT, "FAST")))
        rig.drive(rig.manager.change_mode(ROOT, "__DEFAULT__"))
        rig.drive(rig.manager.change_mode(ROOT, "FAST"))
        listener.on = False
        out["change_events"] = list(listener.times)
        out["fault_events"] = fault_events(rig, faults)
        out["full_inference"] = _full_inference(rig)
    return out


def admission(manager: ModeManager, clock: VirtualClock, holds: int = 100, samples: int = 2000) -> float:
    """The median time of a request's admission check against ``holds`` holds (one node each,
    held by a metacontroller): a tree's request for one of those nodes, refused (issue 33)."""
    loaded = manager.model
    nodes = [node.name for node in loaded.nodes][:holds]
    for node in nodes:
        request = manager.hold(node, "FAST", requester="metacontroller").request
        for _ in range(100):
            if request is None or request.done:
                break
            clock.advance(1.0)
    executions = manager._executions  # the check itself: what each user request pays
    wanted = [dict(implied_targets(loaded, node, StateMode(State.ACTIVE, "__DEFAULT__"))) for node in nodes]
    times = []
    with _frozen():
        for index in range(samples):
            targets = wanted[index % len(wanted)]
            start = time.perf_counter()
            refused = executions.holds.refusal(targets, DEFAULT_PRIORITY)
            times.append(time.perf_counter() - start)
            assert refused, "a held node's change is refused"
    return statistics.median(times)


def _bring_up(loaded: Model, *, one_request: bool) -> float:
    rig = Rig(loaded, State.UNCONFIGURED)

    def requests() -> None:
        if one_request:
            rig.drive(rig.manager.change_mode(ROOT, "__DEFAULT__"))
        else:
            rig.drive(rig.manager.change_state(ROOT, "configure"))
            rig.drive(rig.manager.change_state(ROOT, "activate"))

    with _frozen():
        return _cpu(requests)


def _paired_event_medians(small: int, large: int, rounds: int) -> tuple[float, float]:
    """Median node-event times (s) at two sizes, from mode changes of both managers taking turns,
    so that a slow spell of the machine falls on both sizes rather than on one of them."""
    rigs = [Rig(model(nodes), State.ACTIVE) for nodes in (small, large)]
    times: list[list[float]] = [[], []]
    with _frozen():
        for round_ in range(rounds):
            for rig, kept in zip(rigs, times, strict=True):
                listener = rig.listener
                assert listener is not None
                listener.times.clear()
                listener.on = True
                rig.drive(rig.manager.change_mode(ROOT, "FAST" if round_ % 2 == 0 else "__DEFAULT__"))
                listener.on = False
                kept += listener.times
    return statistics.median(times[0]), statistics.median(times[1])


def measure(nodes: int, faults: int) -> dict[str, Any]:
    """Every scale and P3 figure for one N (seconds)."""
    loaded = model(nodes)
    out = _from_active(loaded, faults)
    out["bring_up_one"] = _bring_up(loaded, one_request=True)
    out["bring_up_two"] = _bring_up(loaded, one_request=False)
    return out


def run(quick: bool) -> list[Figure]:
    sizes = QUICK_SIZES if quick else SIZES
    figures: list[Figure] = []
    medians: dict[int, float] = {}
    for nodes in sizes:
        got = measure(nodes, QUICK_FAULT_EVENTS if quick else FAULT_EVENTS)
        systems = len(shape(nodes)[0].systems)
        common = {"N": nodes, "systems": systems, "gc": "frozen after construction (as sm-bt manager)"}
        for key, name in (("mode_change", "whole-system mode change"),
                          ("bring_up_one", "bring-up, one change_mode"),
                          ("bring_up_two", "bring-up, configure + activate")):
            figures.append(Figure("scale", f"{name}, N={nodes}", got[key], "s", REQUEST_GOALS.get(nodes),
                                  details=common))
        figures.append(Figure("preview", f"preview of a whole-system mode change, N={nodes}", got["preview"] * 1e3,
                              "ms", PREVIEW_GOAL_MS.get(nodes), details=common))
        figures.append(Figure("scale", f"ModeManager construction, N={nodes}", got["construction"], "s",
                              CONSTRUCTION_GOAL.get(nodes), details={"N": nodes, "gc": "as is"}))
        change = statistics.median(got["change_events"]) * 1e6
        fault = statistics.median(got["fault_events"]) * 1e6
        medians[nodes] = change
        events = {**common, "events": len(got["change_events"]),
                  "p90_us": round(sorted(got["change_events"])[int(0.9 * len(got["change_events"]))] * 1e6, 1)}
        figures.append(Figure("P3", f"node event during a mode change, median, N={nodes}", change, "µs",
                              EVENT_GOAL_US.get(nodes), details=events))
        flipped = {**common, "events": len(got["fault_events"]), "parts_flipped": 1 + _depth(nodes)}
        figures.append(Figure("P3", f"fault event flipping a node and its systems, median, N={nodes}", fault, "µs",
                              FAULT_GOAL_US.get(nodes), details=flipped))
        if nodes == sizes[-1]:
            full = got["full_inference"] * 1e6
            for label, value in (("node event during a mode change", change), ("fault event", fault)):
                figures.append(Figure("P3", f"full re-inference / {label}, N={nodes}", full / value, "x",
                                      FULL_OVER_EVENT_GOAL if nodes == 10_000 else None, op=">=",
                                      details={"full_us": round(full, 1)}))
    if not quick:
        rig = Rig(model(sizes[-1]), State.ACTIVE)
        admission_s = admission(rig.manager, rig.backend.clock)
        figures.append(Figure("holds", f"admission check of a request, 100 holds, N={sizes[-1]}", admission_s * 1e6,
                              "µs", ADMISSION_GOAL_US, details={"holds": 100, "samples": 2000}))
    if 1000 in medians and 10_000 in medians:
        small, large = _paired_event_medians(1000, 10_000, GROWTH_ROUNDS)
        figures.append(Figure("P3", "node event growth, N=10000 / N=1000", large / small, "x", GROWTH_GOAL,
                              details={"N=1000_us": round(small * 1e6, 1), "N=10000_us": round(large * 1e6, 1),
                                       "how": f"{GROWTH_ROUNDS} mode changes of each size, taking turns"}))
    return figures


def _depth(nodes: int) -> int:
    """How many systems are above a node in the generated model."""
    depth, level = 0, nodes
    while level > 1:
        level = -(-level // 10)
        depth += 1
    return depth
