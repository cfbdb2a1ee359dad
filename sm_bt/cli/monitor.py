"""``sm-bt monitor MODEL``: the mode monitor over a model's nodes, optionally driving requests.

By default the model's nodes run on the embedded simulated backend, on a virtual clock paced by
``--speed``. With ``--ros`` the monitor watches live ROS 2 nodes instead: a manager on ROS
(:class:`~sm_bt.ros.runtime.RosRuntime`, serving nothing, without rules or recovery) only observes
them, in real time, and makes the ``--change`` requests if there are any. Each ``--change`` is
requested in turn and waited for; the table (or, with ``--json``, one JSON line) is shown whenever
the parts change, at most once per step: in place on a terminal, appended otherwise.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager, ExitStack, nullcontext
from dataclasses import dataclass
from typing import Any, TextIO, cast

from rich.console import Console

from sm_bt import bundled
from sm_bt.cli.arguments import non_negative, positive_int
from sm_bt.cli.common import PROG, UsageError, check_request, load_or_report
from sm_bt.engine.clock import Clock
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.gc_tuning import freeze_long_lived
from sm_bt.model.types import Model
from sm_bt.monitor import Monitor, Selection, terminal_console
from sm_bt.sim import SimulatedSystem

STEP = 0.1  # virtual seconds per clock advance: appended output changes at most this often
LIVE_STEP = 0.02  # finer in place, where intermediate states (configuring, ...) cost no lines
SETTLE = 1.0  # virtual seconds watched after the last request, without --duration
DISCOVERY = 5.0  # --ros: wall seconds to wait for the model's nodes before the requests
# --ros --change: wall seconds to look for another manager's services after the nodes were found
# (a manager's endpoints are discovered independently of, and can arrive after, the nodes'; on a
# loaded machine 1.5 s missed one, and two managers would undo each other's changes)
MANAGER_LOOKOUT = 3.0
#: Once one is found, how long the list of parts it serves must stay the same to be complete.
MANAGER_SETTLE = 0.25
ROS_NODE_NAME = "sm_bt_monitor"  # not the reference manager's name: a manager may run alongside
_EPSILON = 1e-9
#: Rows shown at most by default when the table is appended (a pipe, a file, --once).
APPENDED_ROWS = 100
#: Lines of an in-place table that are not rows (title, header, sections, legend, summary), and the
#: fewest rows it shows on a short terminal.
TABLE_LINES, MIN_ROWS = 10, 5


@dataclass(frozen=True)
class Change:
    """One ``--change PART=VALUE``: a lifecycle transition label or a mode name."""

    part: str
    value: str

    @property
    def is_transition(self) -> bool:
        return self.value in REQUESTABLE_LABELS

    def start(self, manager: ModeManager) -> Request:
        if self.is_transition:
            return manager.change_state(self.part, self.value)
        return manager.change_mode(self.part, self.value)


def parse_change(text: str) -> Change:
    """``PART=VALUE`` (argparse type: a malformed one is a usage error)."""
    part, equals, value = text.partition("=")
    if not equals or not part.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"{text!r} is not PART=MODE or PART=TRANSITION")
    return Change(part.strip(), value.strip())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL",
                        help="model file, or the name of a bundled model (" + ", ".join(bundled.names()) + ")")
    parser.add_argument("--change", action="append", type=parse_change, default=[], metavar="PART=MODE",
                        help="request a change, then wait for it (repeatable, in order): a mode name, or one "
                             f"of the lifecycle transitions {', '.join(REQUESTABLE_LABELS)}")
    parser.add_argument("--duration", type=non_negative, metavar="SECONDS",
                        help="seconds to watch in all, virtual (wall with --ros) (default: until the requests "
                             "are done, plus 1)")
    parser.add_argument("--speed", type=non_negative, default=10.0,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 10; "
                             "simulated nodes only)")
    parser.add_argument("--ros", action="store_true",
                        help="watch the model's live ROS 2 nodes instead of simulated ones (in ROS_DOMAIN_ID); "
                             "needs the ros extra")
    parser.add_argument("--json", action="store_true",
                        help="print JSON Lines snapshots on stdout instead of the table (one per change); "
                             "their times ('time', a divergence's 'since') are seconds since the start of "
                             "the run (virtual seconds on simulated nodes)")
    parser.add_argument("--changes", action="store_true",
                        help="with --json: each line after the first has only the rows that changed since the "
                             "line before (and under 'left' the parts no longer shown)")
    parser.add_argument("--part", action="append", default=[], metavar="PATTERN", dest="parts",
                        help="show only the parts whose names match (shell-style: *, ?, [abc]; repeatable)")
    parser.add_argument("--diverging", action="store_true", help="show only the parts that diverge from their target")
    parser.add_argument("--rows", type=positive_int, metavar="N",
                        help="show at most N parts, errors first, then other divergences, then the rest (default: "
                             f"what fits on a terminal, {APPENDED_ROWS} when appended to a pipe or a file, all "
                             "with --json); a line under the table says how many there are")
    parser.add_argument("--once", action="store_true", help="print one table (or snapshot) at the end, and exit")
    parser.add_argument("--lenient", action="store_true",
                        help="accept what the reference implementation accepts where sm_bt is stricter")
    parser.epilog = ("Without --ros the model's nodes run on the embedded simulated backend. With --ros a "
                     f"manager on ROS 2 (node {ROS_NODE_NAME}; no services, no rules, no recovery) watches "
                     f"the live nodes in real time, waits up to {DISCOVERY:g} s for them to show up, and makes "
                     "the --change requests through their lifecycle and parameter services.")


def run(args: argparse.Namespace) -> int:
    if args.changes and not args.json:
        raise UsageError("--changes is for --json lines (a table always shows what is there now)")
    model = load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    for change in args.change:
        check_request(model, change.part, change.value, "--change", args.model)
    for pattern in args.parts:
        if not Selection((pattern,)).names(model.parts):
            raise UsageError(f"--part {pattern}: matches no part of {args.model}"
                             f"{did_you_mean(pattern, model.parts) or ' (parts: ' + _some(model.parts) + ')'}")
    for warning in model.warnings:
        print(warning, file=sys.stderr)
    advance: Callable[[float], None]
    with ExitStack() as stack:
        graph = None
        if args.ros:
            runtime = _ros_runtime(model, stack)
            if runtime is None:
                return 1
            manager, graph = runtime.manager, runtime.node
            advance = time.sleep
        else:
            system = stack.enter_context(SimulatedSystem(model, record=False))
            manager = system.manager
            advance = _paced(system.run, args.speed)
        freeze_long_lived()  # the model and the manager live as long as the process (sm_bt.model.gc_tuning)
        output = sys.stdout if args.json else terminal_console()
        monitor = Monitor(manager, output, title=args.model, epoch=manager.clock.now(), changes=args.changes,
                          selection=Selection(tuple(args.parts), args.diverging, _rows(args, output)))
        stack.callback(monitor.close)
        watch = _Watch(manager, manager.clock, advance, monitor, show=not args.once)
        return _watch(args, model, watch, monitor, graph)


def _some(names: Iterable[str], shown: int = 10) -> str:
    names = list(names)
    return ", ".join(names[:shown]) + (f", ... ({len(names):,} in all)" if len(names) > shown else "")


def _rows(args: argparse.Namespace, output: Console | TextIO) -> int | None:
    """At most how many rows to show: ``--rows``, else what fits (see its help)."""
    if args.rows is not None or not isinstance(output, Console):
        return cast(int | None, args.rows)
    if output.is_terminal and not args.once:  # in place: a table taller than the screen scrolls away
        return max(MIN_ROWS, output.size.height - TABLE_LINES)
    return APPENDED_ROWS


def _ros_runtime(model: Model, stack: ExitStack) -> Any:
    """A :class:`~sm_bt.ros.runtime.RosRuntime` with an observing manager (serving nothing, no rules,
    no recovery), closed by ``stack``; ``None`` (said why) without ROS."""
    from sm_bt.ros.environment import RosUnavailable, require_ros

    try:
        require_ros()
        from sm_bt.ros.runtime import RosRuntime

        runtime = RosRuntime(model, node_name=ROS_NODE_NAME, serve=False,
                             manager_options={"rules": False, "recovery": False})
    except (RosUnavailable, ImportError) as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return None
    stack.callback(runtime.close)
    from sm_bt.ros.remote_targets import RemoteTargets

    # Next to a running manager, its targets (it announces them on its request topics).
    stack.callback(RemoteTargets(runtime.node, runtime.manager, model).close)
    return runtime


def _paced(advance: Callable[[float], None], speed: float) -> Callable[[float], None]:
    """Advance a virtual clock, then sleep so that it runs ``speed`` times wall time (0: no sleep)."""

    def step(seconds: float) -> None:
        advance(seconds)
        if speed > 0:
            time.sleep(seconds / speed)

    return step


def _watch(args: argparse.Namespace, model: Model, watch: _Watch, monitor: Monitor, graph: Any = None) -> int:
    """Show, make the requests in turn, show; ``graph``: the ROS node to look at the graph with."""
    manager = watch.manager
    failed = 0
    with watch.view():
        watch.show()
        deadline = None if args.duration is None else manager.clock.now() + args.duration
        if args.ros:
            started = time.monotonic()
            missing = watch.discover([node.name for node in model.nodes], deadline)
            if missing and len(missing) == len(model.nodes):
                from sm_bt.ros.environment import describe_discovery

                print(f"{PROG}: error: nothing answered: none of the model's {len(missing)} nodes was reachable "
                      f"within {time.monotonic() - started:.1f} s ({describe_discovery()}); start them, or check "
                      "the domain and discovery settings", file=sys.stderr)
                return 1
            if missing:
                print(f"{PROG}: warning: not reachable after {DISCOVERY:g} s: {', '.join(missing)}",
                      file=sys.stderr)
            # Discovery that was slow for the nodes (a loaded machine, a slow link) is slow for a
            # manager's services too: look out for them at least twice as long as the nodes took.
            lookout = max(MANAGER_LOOKOUT, 2 * (time.monotonic() - started))
            served = _served_by_a_manager(graph, model, lookout) if args.change else []
            if served:  # two managers acting on the same nodes would undo each other's changes
                first = args.change[0]
                how = "state" if first.is_transition else "mode"
                print(f"{PROG}: error: a mode manager already serves {', '.join(served)} (/{served[0]}/change_mode): "
                      "next to it, sm-bt monitor --ros only watches; make the changes through that manager, e.g. "
                      f"`sm-bt {how} set {first.part} {first.value} --wait`", file=sys.stderr)
                return 1
        for change in args.change:
            problem = watch.request(change, deadline)
            if problem:
                print(f"{PROG}: error: {problem}", file=sys.stderr)
                failed += 1
        watch.until(deadline if deadline is not None else manager.clock.now() + SETTLE)
        if args.once:
            monitor.print_table()
        else:
            watch.show()
    return 1 if failed else 0


def _served_by_a_manager(node: Any, model: Model, lookout: float = MANAGER_LOOKOUT) -> list[str]:
    """The model's parts whose ``change_mode`` another process serves, looked for on the ROS graph
    for up to ``lookout`` wall seconds (empty when none appears)."""
    give_up = time.monotonic() + lookout
    parts: list[str] = []
    grew = 0.0
    while True:
        served = {name[1:-len("/change_mode")] for name, types in node.get_service_names_and_types()
                  if name.endswith("/change_mode") and "system_modes_msgs/srv/ChangeMode" in types}
        now = time.monotonic()
        found = [part for part in model.parts if part in served]
        if len(found) > len(parts):  # a manager's services are discovered one by one: name them all
            parts, grew = found, now
        if (parts and now - grew >= MANAGER_SETTLE) or now >= give_up:
            return parts
        time.sleep(0.05)


class _Watch:
    """Lets time pass in steps (``advance``: a paced virtual clock, or real time) and refreshes the view."""

    def __init__(self, manager: ModeManager, clock: Clock, advance: Callable[[float], None], monitor: Monitor, *,
                 show: bool) -> None:
        self.manager = manager
        self.clock = clock
        self.advance = advance
        self.monitor = monitor
        self.showing = show
        output = monitor.output
        self.in_place = show and isinstance(output, Console) and output.is_terminal
        self.step_size = LIVE_STEP if self.in_place else STEP

    def view(self) -> AbstractContextManager[object]:
        """A live, in-place table on a terminal; otherwise output is appended as it changes."""
        return self.monitor.live() if self.in_place else nullcontext()

    def show(self) -> None:
        if self.showing:
            self.monitor.refresh()

    def step(self, end: float) -> None:
        seconds = min(self.step_size, end - self.clock.now())
        self.advance(max(seconds, 0.0))
        self.show()

    def discover(self, nodes: list[str], deadline: float | None) -> list[str]:
        """Wait up to :data:`DISCOVERY` s (and the deadline) until the manager reaches ``nodes``;
        the ones it does not reach."""
        end = self.clock.now() + DISCOVERY
        if deadline is not None:
            end = min(end, deadline)
        while True:
            missing = [node for node in nodes if not self.manager.observation(node).reachable]
            if not missing or self.clock.now() >= end - _EPSILON:
                return missing
            self.step(end)

    def until(self, end: float) -> None:
        while self.clock.now() < end - _EPSILON:
            self.step(end)

    def request(self, change: Change, deadline: float | None) -> str:
        """Request ``change`` and wait for it; return why it failed, or ``""``."""
        label = f"{change.part}={change.value}"
        if deadline is not None and self.clock.now() >= deadline - _EPSILON:
            return f"{label}: not requested, --duration ran out"
        request = change.start(self.manager)
        # The manager's request timeout bounds the wait when there is no deadline.
        while not request.done and (deadline is None or self.clock.now() < deadline - _EPSILON):
            self.step(deadline if deadline is not None else self.clock.now() + self.step_size)
        if not request.done:
            return f"{label}: not done when --duration ran out ({request.feedback})"
        if not request.succeeded:
            return f"{label} failed: {request.reason}"
        return ""
