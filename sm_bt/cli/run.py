"""``sm-bt run MODEL TREE.xml``: any model with any mission tree, on simulated nodes or on ROS 2.

The tree is ticked at ``--rate`` ticks per (virtual) second, ``--speed`` virtual seconds per wall
second (0: as fast as possible). Nodes the tree declares in ``<TreeNodesModel>`` or only names run
as stand-ins, doing what ``--stubs FILE`` says (succeeding at once otherwise). It narrates on
stderr what the manager does (requests, divergences, rules, recoveries: the manager's own log
lines, stamped with the run's time) and each change of the root's status; it ends when the root
ends, or at ``--until`` seconds, and exits 0 on SUCCESS (or still running at ``--until``), 1 on
FAILURE or when the model, the tree or the stubs have mistakes (all of them said, with lines).
With ``--scenario FILE`` (:mod:`sm_bt.scenario`) its faults happen at their times, its
expectations are judged, and the exit status is theirs: 1 when one failed. With ``--ros`` the
model's nodes are simulated rclpy lifecycle nodes in child processes (``--attach``: the real nodes,
already running) and the run is in real time (:class:`~sm_bt.ros.mission_system.RosSystem`).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import time
from collections.abc import Callable, Iterator

import py_trees
from py_trees.common import Status

from sm_bt.cli.arguments import add_view_arguments, non_negative, positive
from sm_bt.cli.common import CliError, UsageError, load_or_report, report_failed, shipped_nodes
from sm_bt.model.types import Model
from sm_bt.scenario import Checks, MissionSystem, Scenario, SimulatedWorld, load_scenario, load_world, scenario_setup
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
    parser.add_argument("--speed", type=non_negative, default=None,
                        help="virtual seconds per wall second; 0 runs as fast as possible (default 10; with --ros "
                             "the run is in real time)")
    parser.add_argument("--until", type=positive, default=None, metavar="SECONDS",
                        help="stop after this many seconds of the run, if the tree has not ended")
    parser.add_argument("--scenario", metavar="FILE",
                        help="faults on a timeline and what must hold (YAML: events, expect); exit 1 if an "
                             "expectation fails")
    parser.add_argument("--world", metavar="MODULE:NAME",
                        help="the simulated world the tree's own actions need (the pilot's: "
                             "sm_bt.trees.pilot.world:PilotWorld); default: the scenario's world:")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")
    add_ros_arguments(parser)
    add_view_arguments(parser)


def add_ros_arguments(parser: argparse.ArgumentParser) -> None:
    """``--ros`` and ``--attach``: the run on ROS 2 (``sm-bt run``, ``sm-bt test``)."""
    parser.add_argument("--ros", action="store_true",
                        help="run on ROS 2 in real time: the model's nodes as simulated rclpy lifecycle nodes in "
                             "child processes (sm-bt sim-nodes), the manager embedded, serving the system_modes "
                             "interface meanwhile; needs the ros extra")
    parser.add_argument("--attach", action="store_true",
                        help="with --ros: manage the model's real nodes, already running in this shell's "
                             "ROS_DOMAIN_ID, instead of starting simulated ones (faults other than set_parameter "
                             "need simulated nodes)")


@contextlib.contextmanager
def mission_system(model: Model, model_name: str, *, ros: bool, attach: bool, scenario: Scenario | None,
                   say: Callable[[str], None]) -> Iterator[MissionSystem]:
    """Simulated nodes, or with ``ros`` the model's nodes on ROS 2 (those the scenario crashes,
    ends or restarts each in a process of its own); :class:`CliError` when ROS cannot start them."""
    if not ros:
        with SimulatedSystem(model, record=False) as simulated:
            yield simulated
        return
    from sm_bt.ros.environment import RosUnavailable
    from sm_bt.ros.node_process import NodesError

    try:
        from sm_bt.ros.mission_system import RosSystem

        system = RosSystem(model, model_name, attach=attach,
                           separate=scenario.own_processes() if scenario is not None else (), say=say)
    except (RosUnavailable, NodesError, ImportError) as error:
        raise CliError(str(error)) from None
    with system:
        yield system


class _RunTime(logging.Formatter):
    """``  12.30 s  message``: the run's time, not the wall clock's."""

    def __init__(self, now: Callable[[], float]) -> None:
        super().__init__()
        self.now = now

    def format(self, record: logging.LogRecord) -> str:
        return f"{self.now():8.2f} s  {record.getMessage()}"


def run(args: argparse.Namespace) -> int:
    speed = _speed(args)
    model = load_or_report(args.model, strict=True)
    if model is None:
        return 1
    stubs: dict[str, Stub] = {}
    if args.stubs:
        stubs, issues = load_stubs(args.stubs)
        if issues:
            return report_failed(args.stubs, issues)
    world: SimulatedWorld | None = None
    reference = args.world or (scenario_setup(args.scenario)[0].get("world") if args.scenario else None)
    if reference:
        try:
            world = load_world(reference)
        except ValueError as error:
            raise CliError(str(error)) from None
    scenario = None
    if args.scenario:
        scenario, issues = load_scenario(args.scenario, model, world.events if world is not None else None)
        if issues:
            return report_failed(args.scenario, issues)

    def say(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    with mission_system(model, args.model, ros=args.ros, attach=args.attach, scenario=scenario, say=say) as system:
        shipped_nodes()
        try:
            root = load_tree(args.tree, manager=system.manager, stubs=stubs)
        except TreeFileError as error:
            return report_failed(args.tree, error.issues)
        tree = system.tree(root, **(world.attach(system) if world is not None else {}))
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
            on_failure = (lambda text: view.note("expectation", text)) if view is not None else None
            checks = Checks(scenario, system, world, on_failure) if scenario is not None else None
            code = _tick(system, tree, args, speed, checks, world)
            if view is not None and view.url:
                view.stay(lambda line: print(line, file=sys.stderr, flush=True))
            return code
        finally:
            if view is not None:
                view.close()


def _speed(args: argparse.Namespace) -> float:
    """The run's --speed: 10 by default; with --ros the run is in real time (ticks are not paced
    on top of the time that passes)."""
    if args.attach and not args.ros:
        raise UsageError("--attach goes with --ros (it manages real nodes over ROS 2)")
    if not args.ros:
        return 10.0 if args.speed is None else float(args.speed)
    if args.speed is not None and args.speed != 1:
        raise UsageError("--speed is for simulated nodes: with --ros the run is in real time (the nodes' "
                         "transitions and the manager's timeouts take real seconds)")
    return 0.0


def ticked(system: MissionSystem, tree: py_trees.trees.BehaviourTree, *, rate: float, speed: float,
           until: float | None, checks: Checks | None, narrate: bool, world: SimulatedWorld | None = None) -> Status:
    """Tick until the root ends (or ``until``), applying the scenario's ``checks`` after each tick
    and letting the ``world`` advance after each step of time; with ``narrate``, the manager's
    lines and the root's status on stderr, on the run's time. The root's last status."""
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
            if world is not None:
                world.advance()
            if speed > 0:
                time.sleep(period / speed)
    finally:
        for logger, level in zip(watched, levels, strict=True):
            logger.removeHandler(handler)
            logger.setLevel(level)
            logger.propagate = True


def _tick(system: MissionSystem, tree: py_trees.trees.BehaviourTree, args: argparse.Namespace, speed: float,
          checks: Checks | None, world: SimulatedWorld | None) -> int:
    """The run, then its summary on stdout; the exit code."""
    status = ticked(system, tree, rate=args.rate, speed=speed, until=args.until, checks=checks,
                    narrate=not args.quiet, world=world)
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
