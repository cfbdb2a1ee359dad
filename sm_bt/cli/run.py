"""``sm-bt run MODEL TREE.xml``: any model with any mission tree, on simulated nodes.

The tree is ticked at ``--rate`` ticks per (virtual) second, ``--speed`` virtual seconds per wall
second (0: as fast as possible). Nodes the tree declares in ``<TreeNodesModel>`` or only names run
as stand-ins, doing what ``--stubs FILE`` says (succeeding at once otherwise). It narrates on
stderr what the manager does (requests, divergences, rules, recoveries: the manager's own log
lines, stamped with the run's time) and each change of the root's status; it ends when the root
ends, or at ``--until`` seconds, and exits 0 on SUCCESS (or still running at ``--until``), 1 on
FAILURE or when the model, the tree or the stubs have mistakes (all of them said, with lines).
With ``--scenario FILE`` (:mod:`sm_bt.scenario`) its faults happen at their times, its
expectations are judged, and the exit status is theirs: 1 when one failed.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from collections.abc import Callable

import py_trees
from py_trees.common import Status

from sm_bt.cli.arguments import add_view_arguments, non_negative, positive
from sm_bt.cli.common import CliError, load_or_report, report_failed
from sm_bt.scenario import Checks, load_scenario
from sm_bt.sim import SimulatedSystem
from sm_bt.trees.mission_xml import TreeFileError, load_tree
from sm_bt.trees.stubs import Stub, load_stubs

#: The run's own lines and the manager's, on stderr.
log = logging.getLogger("sm_bt.run")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a bundled model's name")
    parser.add_argument("tree", metavar="TREE.xml", help="a mission tree in XML (BehaviorTree.CPP/Groot style)")
    parser.add_argument("--stubs", metavar="FILE", help="what the declared or unknown nodes do (YAML or JSON: "
                                                        "ID: {status: running, for: SECONDS, then: success})")
    parser.add_argument("--rate", type=positive, default=10.0, metavar="HZ",
                        help="ticks per second of the run's (virtual) time (default 10)")
    parser.add_argument("--speed", type=non_negative, default=10.0,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 10)")
    parser.add_argument("--until", type=positive, default=None, metavar="SECONDS",
                        help="stop after this many seconds of the run, if the tree has not ended")
    parser.add_argument("--scenario", metavar="FILE",
                        help="faults on a timeline and what must hold (YAML: events, expect); exit 1 if an "
                             "expectation fails")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")
    add_view_arguments(parser)


class _RunTime(logging.Formatter):
    """``  12.30 s  message``: the run's time, not the wall clock's."""

    def __init__(self, now: Callable[[], float]) -> None:
        super().__init__()
        self.now = now

    def format(self, record: logging.LogRecord) -> str:
        return f"{self.now():8.2f} s  {record.getMessage()}"


def run(args: argparse.Namespace) -> int:
    model = load_or_report(args.model, strict=True)
    if model is None:
        return 1
    stubs: dict[str, Stub] = {}
    if args.stubs:
        stubs, issues = load_stubs(args.stubs)
        if issues:
            return report_failed(args.stubs, issues)
    scenario = None
    if args.scenario:
        scenario, issues = load_scenario(args.scenario, model)
        if issues:
            return report_failed(args.scenario, issues)
    with SimulatedSystem(model, record=False) as system:
        try:
            root = load_tree(args.tree, manager=system.manager, stubs=stubs)
        except TreeFileError as error:
            return report_failed(args.tree, error.issues)
        tree = system.tree(root)
        view = None
        if args.view is not None or args.record:
            from sm_bt.view import attach_view

            try:
                view = attach_view(tree, system.manager, port=args.view, host=args.host, record=args.record)
            except OSError as error:
                raise CliError(f"cannot serve the view on {args.host}:{args.view} or write {args.record}: "
                               f"{error.strerror or error}") from None
            if view.url:
                print(f"view: {view.url}", file=sys.stderr, flush=True)
        try:
            checks = Checks(scenario, system) if scenario is not None else None
            code = _tick(system, tree, args, checks)
            if view is not None and view.url:
                view.stay(lambda line: print(line, file=sys.stderr, flush=True))
            return code
        finally:
            if view is not None:
                view.close()


def ticked(system: SimulatedSystem, tree: py_trees.trees.BehaviourTree, *, rate: float, speed: float,
           until: float | None, checks: Checks | None, narrate: bool) -> Status:
    """Tick until the root ends (or ``until``), applying the scenario's ``checks`` after each tick;
    with ``narrate``, the manager's lines and the root's status on stderr, on the run's time. The
    root's last status."""
    clock = system.clock
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(_RunTime(clock.now))
    watched = [logging.getLogger("sm_bt.manager"), log]
    levels = [logger.level for logger in watched]
    for logger in watched:
        logger.addHandler(handler)
        logger.setLevel(logging.INFO if narrate else logging.CRITICAL)
        logger.propagate = False
    period = 1.0 / rate
    shown: Status | None = None
    try:
        while True:
            tree.tick()
            if checks is not None:
                checks.at(clock.now())
            status = tree.root.status
            if status != shown:
                log.info("%s %s", tree.root.name, status.value)
                shown = status
            if status in (Status.SUCCESS, Status.FAILURE) or (until is not None and clock.now() >= until):
                return status
            system.run(period)
            if speed > 0:
                time.sleep(period / speed)
    finally:
        for logger, level in zip(watched, levels, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)
            logger.propagate = True


def _tick(system: SimulatedSystem, tree: py_trees.trees.BehaviourTree, args: argparse.Namespace,
          checks: Checks | None) -> int:
    """The run, then its summary on stdout; the exit code."""
    status = ticked(system, tree, rate=args.rate, speed=args.speed, until=args.until, checks=checks,
                    narrate=not args.quiet)
    now = system.clock.now()
    stopped = f" (stopped at --until {args.until:g} s)" if status == Status.RUNNING else ""
    print(f"{args.tree}: {status.value} at {now:.2f} s{stopped}")
    if checks is None:
        return 1 if status == Status.FAILURE else 0
    checks.end(str(status.value), now)
    held, failed = len(checks.passed), len(checks.failures)
    print(f"{args.scenario}: {held} of {held + failed} expectations held")
    for failure in checks.failures:
        print(f"  FAILED {failure}")
    return 1 if failed else 0
