"""``sm-bt sim-nodes MODEL``: the model's nodes as simulated rclpy lifecycle nodes, in this process.

Prints ``READY /a,/b`` once their services exist; SIGINT or SIGTERM stops it (exit 0). Faults are
the nodes' ``sim.*`` parameters (:mod:`sm_bt.ros.sim_nodes`). Uses the user's discovery settings:
these stand in for a robot's nodes.
"""

from __future__ import annotations

import argparse

from sm_bt.cli.arguments import namespace, non_negative
from sm_bt.cli.common import CliError, UsageError, load_or_report


def _names(text: str) -> list[str]:
    return [name.strip() for name in text.split(",") if name.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="model file, or a bundled model name (pilot, actuation)")
    parser.add_argument("--only", type=_names, metavar="NAME,...", help="run only these nodes (default: all)")
    parser.add_argument("--namespace", type=namespace, default="/", metavar="NS",
                        help="put every node under this namespace, as a robot of a fleet (/robot1/amcl; default /)")
    parser.add_argument("--state", choices=("unconfigured", "inactive", "active"), default="unconfigured",
                        help="bring the lifecycle nodes to this state before READY")
    parser.add_argument("--parameters-only", type=_names, default=[], metavar="NAME,...",
                        help="run these nodes as plain nodes: parameters, no lifecycle services")
    parser.add_argument("--transition-delay", type=non_negative, default=0.0, metavar="SECONDS",
                        help="seconds every transition takes (the nodes' first sim.transition_delay; default 0)")
    parser.add_argument("--single-threaded", action="store_true",
                        help="one executor thread for all the nodes, as in a component container: a node in a "
                             "transition holds up the others (default: a thread per node)")


def run(args: argparse.Namespace) -> int:
    from sm_bt.ros import environment

    environment.prepare(local_only=False)  # stand-ins for a robot's nodes: the user's discovery settings
    try:
        environment.require_ros()
    except environment.RosUnavailable as error:
        raise CliError(str(error)) from None
    from sm_bt.ros.sim_nodes import RefusedName, run_nodes, select_nodes

    # As every command: a model that does not load is exit 1 (each error on a line of its own),
    # names that are not the model's nodes a usage error (exit 2).
    model = load_or_report(args.model, strict=True)
    if model is None:
        return 1
    try:
        select_nodes(model, args.only, args.parameters_only)
    except ValueError as error:  # names that are not nodes of the model
        raise UsageError(str(error)) from None
    try:
        run_nodes(model, args.only, initial_state=args.state, parameters_only=args.parameters_only,
                  transition_delay=args.transition_delay, single_threaded=args.single_threaded,
                  namespace=args.namespace)
    except RefusedName as error:  # a part or parameter name ROS refuses
        raise CliError(f"{args.model}: {error}") from None
    except KeyboardInterrupt:  # a signal before our handlers were installed
        return 130
    return 0
