"""``sm-bt demo``: the pilot mission on simulated nodes, or with ``--ros`` on real rclpy nodes.

The demo itself (platforms, world, narration, summary) is :mod:`sm_bt.trees.pilot.demo`; this module is its
command line.
"""

from __future__ import annotations

import argparse
import sys

from sm_bt.cli.arguments import add_view_arguments, non_negative, positive_int
from sm_bt.cli.common import CliError, UsageError
from sm_bt.trees.fleet import DEMO_SPEED as FLEET_SPEED
from sm_bt.trees.mission_xml import TreeFileError
from sm_bt.trees.pilot.demo import DEGRADED_FOR, REPAIR_AT, TREES, Auto, Demo, Options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--tree", type=_tree, metavar="TREE",
                        help="contingencies in the tree (pilot, the default), chosen by a metacontroller "
                             "(metacontrol), left to the model's rule (rules, the default with --rules), or a "
                             "mission tree file in XML (trees/pilot/pilot.xml is the pilot tree; {cycles} in it "
                             "is --cycles)")
    parser.add_argument("--laser-failure-at", type=_time, default=15.0, metavar="SECONDS",
                        help="world time the laser breaks; 'never' for no failure (default 15)")
    parser.add_argument("--laser-repair-at", type=_time, default=Auto.AUTO, metavar="SECONDS",
                        help=f"world time the laser is repaired; 'never' to leave it broken (default {REPAIR_AT:g}; "
                             f"with --ros, once the pilot has been in degraded mode for {DEGRADED_FOR:g} s, as "
                             "on simulated nodes: handling the failure takes real seconds there)")
    parser.add_argument("--cycles", type=positive_int, default=2,
                        help="patrol rounds of the seven waypoints (default 2)")
    parser.add_argument("--speed", type=non_negative, default=None,
                        help="world (virtual) seconds per wall second; 0 runs as fast as possible, "
                             f"simulated only (default {PILOT_SPEED:g}; with --fleet {FLEET_SPEED:g})")
    parser.add_argument("--fleet", action="store_true",
                        help="a fleet's shift instead (models/fleet.yaml): two robots, each the pilot under a "
                             "manager of its own, driven by the fleet's manager; robot1 is cut off from the fleet "
                             "and healed meanwhile (simulated; with --ros each robot is two processes, its nodes "
                             "and its own sm-bt manager, and the cut freezes its manager)")
    parser.add_argument("--rules", action="store_true",
                        help="the model with the laser rule (pilot_rules): the manager itself switches to "
                             "degraded mode when the laser fails, and holds it there against lower-priority "
                             "requests (the tree's energy saving) until the tree sees the scans healthy again")
    parser.add_argument("--quiet", action="store_true", help="print only the summary")
    add_view_arguments(parser)
    parser.add_argument("--ros", action="store_true",
                        help="run on real ROS 2 lifecycle nodes (sm-bt sim-nodes pilot, started "
                             "and stopped by the demo) with the manager on ROS 2, serving the system_modes "
                             "interface meanwhile; mode changes take real time, the world runs --speed "
                             "times faster; needs the ros extra")
    parser.epilog = ("World time is the mission's: the robot's driving, recharging and the laser schedule. "
                     "On simulated nodes it is the manager's virtual clock. With --ros the manager runs in "
                     "real time (its mode changes, grace periods and timeouts take real seconds) while the "
                     "world runs --speed times faster.")


#: The pilot demo's default --speed.
PILOT_SPEED = 35.0
#: The pilot demo's options, which the fleet's shift does not take (with their defaults).
PILOT_ONLY = {"tree": None, "laser_failure_at": 15.0, "laser_repair_at": Auto.AUTO, "cycles": 2, "rules": False}


def _fleet(args: argparse.Namespace) -> int:
    given = [f"--{name.replace('_', '-')}" for name, default in PILOT_ONLY.items() if getattr(args, name) != default]
    if given:
        raise UsageError(f"--fleet runs the fleet's shift: {', '.join(given)} belong to the pilot demo")
    if args.ros and args.speed is not None:
        raise UsageError("--fleet --ros runs in real time: --speed paces the simulated fleet only")
    from sm_bt.trees.fleet.demo import FleetDemo, FleetOptions

    options = FleetOptions(speed=FLEET_SPEED if args.speed is None else args.speed, quiet=args.quiet,
                           view=args.view, view_host=args.host, record=args.record, linger=args.view is not None,
                           ros=args.ros)
    failures: tuple[type[Exception], ...] = ()  # what the platform's set-up may raise, told in a line
    if options.ros:
        from sm_bt.ros.environment import RosUnavailable
        from sm_bt.ros.node_process import NodesError  # needs no rclpy

        failures = (RosUnavailable, NodesError)
    try:
        return FleetDemo(options).run()
    except OSError as error:  # the view's port
        raise CliError(f"cannot serve the view on {options.view_host}:{options.view}: "
                       f"{error.strerror or error} (choose another port: --view PORT, 0 for any)") from None
    except failures as error:
        raise CliError(str(error)) from None


def _tree(text: str) -> str:
    if text in TREES or text.endswith(".xml"):
        return text
    raise argparse.ArgumentTypeError(f"{text!r} is neither a shipped tree ({', '.join(sorted(TREES))}) "
                                     "nor a tree file (.xml)")


def _time(text: str) -> float | None:
    if text == "never":
        return None
    return non_negative(text)


def run(args: argparse.Namespace) -> int:
    if args.fleet:
        return _fleet(args)
    options = Options(laser_failure_at=args.laser_failure_at, laser_repair_at=args.laser_repair_at,
                      cycles=args.cycles, speed=PILOT_SPEED if args.speed is None else args.speed, quiet=args.quiet,
                      tree=args.tree or ("rules" if args.rules else "pilot"), ros=args.ros,
                      rules=args.rules, view=args.view, view_host=args.host, record=args.record,
                      linger=args.view is not None)
    if not options.ros:
        try:
            return Demo(options).run()
        except TreeFileError as error:
            print(error, file=sys.stderr)
            return 1
        except OSError as error:  # the view's port
            raise CliError(f"cannot serve the view on {options.view_host}:{options.view}: "
                           f"{error.strerror or error} (choose another port: --view PORT, 0 for any)") from None
    from sm_bt.ros.environment import RosUnavailable
    from sm_bt.ros.node_process import NodesError  # needs no rclpy

    if not options.speed > 0:
        raise UsageError("--speed must be more than 0 with --ros")
    try:
        return Demo(options).run()
    except (RosUnavailable, NodesError) as error:
        raise CliError(str(error)) from None
    except TreeFileError as error:
        print(error, file=sys.stderr)
        return 1
