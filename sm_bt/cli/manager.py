"""``sm-bt manager MODEL``: the mode manager as a ROS 2 node (a drop-in for the reference's).

Serves the reference's services and topics for every part of the model (see
:mod:`sm_bt.ros.manager_node`) and manages the nodes through the ROS 2 backend, until SIGINT or
SIGTERM. Needs the ``ros`` extra; without it, says how to install it.

It logs to stderr, at INFO unless ``--log-level`` says otherwise, in the format of ROS 2's
console output (``[INFO] [1700000000.123456] [sm_bt.manager]: message``): one line per thing an
operator needs (a node appearing or vanishing, a request starting, failing or refused, a rule
firing, a recovery attempt, recovery giving up); per-call detail is DEBUG. This is the only place
sm_bt configures logging: as a library it stays silent unless the application does.
"""

from __future__ import annotations

import argparse
import logging
import signal
import threading
from types import FrameType
from typing import Any

from sm_bt.cli.arguments import namespace, non_negative, positive_int
from sm_bt.cli.common import CliError, load_or_report
from sm_bt.model.errors import Error
from sm_bt.model.gc_tuning import freeze_long_lived
from sm_bt.model.types import Model, SystemPart
from sm_bt.ros.console_log import LOG_LEVELS, configure_logging

#: The logger of the manager's own lines (start-up, service callbacks).
log = logging.getLogger("sm_bt.ros.manager_node")


class RosMissing(Error):
    """The ROS 2 extra is not installed (the message says how to install it)."""


#: Start-up lines logged at most (a large model's would be hundreds of thousands).
STARTUP_LINES = 1000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or the name of a bundled model")
    parser.add_argument("--node-name", default="__mode_manager",
                        help="name of the manager's ROS node (default __mode_manager, as the reference)")
    parser.add_argument("--namespace", type=namespace, default="/", metavar="NS",
                        help="the robot's namespace: its nodes are looked for under it (/robot1/amcl), its parts "
                             "served under it (/robot1/pilot/change_mode), as a robot of a fleet (default /)")
    parser.add_argument("--grace-period", type=non_negative, default=2.0, metavar="SECONDS",
                        help="how long a divergence lasts before rules and recovery act (default 2)")
    parser.add_argument("--request-timeout", type=non_negative, default=30.0, metavar="SECONDS",
                        help="give up on a request after this long (default 30)")
    parser.add_argument("--recovery-attempts", type=positive_int, default=3,
                        help="restore attempts per node within a minute before giving up (default 3)")
    parser.add_argument("--on-failure", type=_policy, default="stay", metavar="POLICY",
                        help="what a request that fails leaves behind: stay (the nodes where the failure left them; "
                             "the default), rollback (every node it moved put back where it was) or mode:NAME (that "
                             "mode of the request's part asked for)")
    parser.add_argument("--requester", default="operator", metavar="NAME",
                        help="who the requests through the system_modes interface come from: their priority "
                             "against the parts' holds (default operator, priority 80)")
    parser.add_argument("--serve", choices=("all", "systems"), default="all",
                        help="whose system_modes interface to serve: every part's, as the reference (default), "
                             "or the systems' only (a plant of hundreds of nodes: each node's is 15 DDS endpoints)")
    parser.add_argument("--receive-room", action="store_true",
                        help="a Fast DDS shared-memory port of 8,192 samples for this process, for a plant of "
                             "hundreds of nodes (docs/ros-interface.md, \"Receive room\": it also sizes the ports "
                             "shared with other processes)")
    parser.add_argument("--no-rules", action="store_true", help="do not apply the model's rules")
    parser.add_argument("--no-recovery", action="store_true", help="do not restore nodes that left their target")
    parser.add_argument("--lenient", action="store_true",
                        help="accept what the reference accepts where sm_bt is stricter")
    parser.add_argument("--log-level", choices=tuple(LOG_LEVELS), default="info",
                        help="log to stderr from this level on (default info)")


def _policy(text: str) -> str:
    from sm_bt.engine.rollback import check_policy

    try:
        return check_policy(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def startup_lines(model: Model, nodes: bool = True, namespace: str = "/") -> list[str]:
    """What the manager serves, in the reference's start-up log format (``nodes``: theirs too)."""
    from sm_bt.ros.names import qualified_name

    lines: list[str] = []
    for part in model.systems:
        lines.append(f"- system '{part.name}'")
        base = qualified_name(part.name, namespace)
        lines.extend(f"  - {base}/{name}" for name in ("change_state", "get_state", "get_available_states",
                                                         "change_mode", "get_mode", "get_available_modes"))
    for node in model.nodes if nodes else ():
        if node.remote is not None:  # its manager serves it
            lines.append(f"- remote part '{node.name}': {node.remote.fqn}, served by its own manager")
            continue
        lines.append(f"- node '{node.name}'")
        base = qualified_name(node.name, namespace)
        lines.extend(f"  - {base}/{name}" for name in ("change_mode", "get_mode", "get_available_modes"))
    return lines


def serve(model: Model, args: argparse.Namespace, stop: threading.Event) -> None:
    """Run the manager node until ``stop`` is set."""
    from sm_bt.ros.environment import RosUnavailable, manager_profile

    try:
        from sm_bt.model.remote_parts import MixedModel
        from sm_bt.ros.runtime import RosRuntime

        # Announced often, so that clients find it at once; with room for a large change's burst of
        # answers and events if asked for (docs/ros-interface.md).
        with manager_profile(room=args.receive_room) as profile:
            runtime = RosRuntime(model, node_name=args.node_name, requester=args.requester,
                                 serve_nodes=args.serve == "all", namespace=args.namespace, manager_options={
                "grace_period": args.grace_period, "request_timeout": args.request_timeout,
                "recovery_attempts": args.recovery_attempts, "rules": not args.no_rules,
                "recovery": not args.no_recovery, "on_failure": args.on_failure})
    except (RosUnavailable, ImportError) as error:
        raise RosMissing(str(error)) from None
    except MixedModel as error:
        raise CliError(str(error)) from None
    # The model and the manager's tables live as long as the process: keep them out of the garbage
    # collector's passes (at 10,000 nodes each full pass walked ~700,000 objects, ~0.5 s).
    freeze_long_lived()
    try:
        _align_node_logger(runtime.node, args.log_level)
        from sm_bt.ros.environment import describe_discovery

        log.info("discovery: %s", describe_discovery())  # the first thing to check when nodes are not found
        log.info("transports: %s", "the middleware's, as this environment sets them" if profile is None else
                 f"Fast DDS with sm_bt's {'receive room' if args.receive_room else 'announcements'} ({profile})")
        lines = startup_lines(model, nodes=args.serve == "all", namespace=args.namespace)
        for line in lines[:STARTUP_LINES]:
            log.info(line)
        if len(lines) > STARTUP_LINES:
            log.info("... and %d more lines of services", len(lines) - STARTUP_LINES)
        systems = sum(isinstance(p, SystemPart) for p in model.parts.values())
        remote = sum(node.remote is not None for node in model.nodes)
        nodes = (f"over {remote} remote part(s)" if remote else f"and {len(model.nodes)} node(s)"
                 if args.serve == "all" else f"(not their {len(model.nodes)} node(s))")
        print(f"mode manager {args.node_name} serving {systems} system(s) {nodes} of {model.path}; Ctrl-C to stop",
              flush=True)
        stop.wait()
    finally:
        runtime.close()


def _align_node_logger(node: Any, level: str) -> None:
    """What rclpy itself logs for the manager's node (on stderr too) follows ``--log-level``."""
    # rcutils' severities have Python's values (DEBUG 10, INFO 20, WARN 30, ERROR 40).
    node.get_logger().set_level(LOG_LEVELS[level])


def install_stop_handlers(stop: threading.Event) -> None:
    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def run(args: argparse.Namespace) -> int:
    configure_logging(args.log_level)  # stderr, ROS 2's format; the library never does this
    model = load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    stop = threading.Event()
    install_stop_handlers(stop)
    try:
        serve(model, args, stop)
    except RosMissing as error:
        raise CliError(str(error)) from None
    return 0
