"""``sm-bt monitor MODEL``: the mode monitor over a model's nodes, optionally driving requests.

There is no ROS backend yet, so the model's nodes run on the embedded simulated backend, on a
virtual clock paced by ``--speed``. Each ``--change`` is requested in turn and waited for; the
table (or, with ``--json``, one JSON line) is shown whenever the parts change, at most once per
virtual step: in place on a terminal, appended otherwise.
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

from rich.console import Console

from sm_bt import bundled
from sm_bt.arguments import non_negative
from sm_bt.engine.clock import VirtualClock
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.monitor import Monitor, terminal_console
from sm_bt.sim import SimBackend

STEP = 0.1  # virtual seconds per clock advance: appended output changes at most this often
LIVE_STEP = 0.02  # finer in place, where intermediate states (configuring, ...) cost no lines
SETTLE = 1.0  # virtual seconds watched after the last request, without --duration
_EPSILON = 1e-9


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
                        help="virtual seconds to watch in all (default: until the requests are done, plus 1)")
    parser.add_argument("--speed", type=non_negative, default=10.0,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 10)")
    parser.add_argument("--json", action="store_true",
                        help="print JSON Lines snapshots on stdout instead of the table (one per change)")
    parser.add_argument("--once", action="store_true", help="print one table (or snapshot) at the end, and exit")
    parser.add_argument("--lenient", action="store_true",
                        help="accept what the reference implementation accepts where sm_bt is stricter")
    parser.epilog = ("The nodes run on the embedded simulated backend. Watching live ROS nodes (--ros) "
                     "comes with the ROS backend.")


def run(args: argparse.Namespace) -> int:
    from sm_bt.cli import PROG, _load_or_report  # not at the top: sm_bt.cli imports this module

    model = _load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    for warning in model.warnings:
        print(warning, file=sys.stderr)
    backend = SimBackend(model)
    manager = ModeManager(model, backend)
    monitor = Monitor(manager, sys.stdout if args.json else terminal_console(), title=args.model)
    watch = _Watch(manager, backend.clock, monitor, speed=args.speed, show=not args.once)
    failed = 0
    try:
        with watch.view():
            watch.show()
            deadline = None if args.duration is None else manager.clock.now() + args.duration
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
    finally:
        monitor.close()
        manager.close()
    return 1 if failed else 0


class _Watch:
    """Advances the virtual clock in steps, pacing it to wall time and refreshing the view."""

    def __init__(self, manager: ModeManager, clock: VirtualClock, monitor: Monitor, *, speed: float,
                 show: bool) -> None:
        self.manager = manager
        self.clock = clock
        self.monitor = monitor
        self.speed = speed
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
        self.clock.advance(seconds)
        self.show()
        if self.speed > 0:
            time.sleep(seconds / self.speed)

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
