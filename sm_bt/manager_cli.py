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
import gc
import logging
import signal
import sys
import threading
from types import FrameType
from typing import Any, TextIO

from sm_bt.arguments import non_negative, positive_int
from sm_bt.model.types import Model, SystemPart

#: ``--log-level`` choices.
LOG_LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}
#: ROS 2's severity names where they differ from Python's.
_SEVERITY = {"WARNING": "WARN", "CRITICAL": "FATAL"}
#: The logger of the manager's own lines (start-up, service callbacks).
log = logging.getLogger("sm_bt.ros.manager_node")


class RosMissing(Exception):
    """The ROS 2 extra is not installed (the message says how to install it)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or the name of a bundled model")
    parser.add_argument("--node-name", default="__mode_manager",
                        help="name of the manager's ROS node (default __mode_manager, as the reference)")
    parser.add_argument("--grace-period", type=non_negative, default=2.0, metavar="SECONDS",
                        help="how long a divergence lasts before rules and recovery act (default 2)")
    parser.add_argument("--request-timeout", type=non_negative, default=30.0, metavar="SECONDS",
                        help="give up on a request after this long (default 30)")
    parser.add_argument("--recovery-attempts", type=positive_int, default=3,
                        help="restore attempts per node within a minute before giving up (default 3)")
    parser.add_argument("--no-rules", action="store_true", help="do not apply the model's rules")
    parser.add_argument("--no-recovery", action="store_true", help="do not restore nodes that left their target")
    parser.add_argument("--lenient", action="store_true",
                        help="accept what the reference accepts where sm_bt is stricter")
    parser.add_argument("--log-level", choices=tuple(LOG_LEVELS), default="info",
                        help="log to stderr from this level on (default info)")


class RosFormatter(logging.Formatter):
    """ROS 2's console format: ``[SEVERITY] [seconds.micro] [logger]: message``."""

    def format(self, record: logging.LogRecord) -> str:
        severity = _SEVERITY.get(record.levelname, record.levelname)
        line = f"[{severity}] [{record.created:.6f}] [{record.name}]: {record.getMessage()}"
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


class _Handler(logging.StreamHandler):  # type: ignore[type-arg]
    """The handler :func:`configure_logging` installs (so that calling it again replaces it)."""


def configure_logging(level: str, stream: TextIO | None = None) -> None:
    """Log from ``level`` (a ``--log-level`` choice) on to ``stream`` (stderr) in ROS 2's format,
    through the root logger; replaces what an earlier call installed."""
    root = logging.getLogger()
    for handler in [h for h in root.handlers if isinstance(h, _Handler)]:
        root.removeHandler(handler)
    handler = _Handler(sys.stderr if stream is None else stream)
    handler.setFormatter(RosFormatter())
    root.addHandler(handler)
    root.setLevel(LOG_LEVELS[level])


def startup_lines(model: Model) -> list[str]:
    """What the manager serves, in the reference's start-up log format."""
    lines: list[str] = []
    for part in model.systems:
        lines.append(f"- system '{part.name}'")
        lines.extend(f"  - /{part.name}/{name}" for name in ("change_state", "get_state", "get_available_states",
                                                             "change_mode", "get_mode", "get_available_modes"))
    for node in model.nodes:
        lines.append(f"- node '{node.name}'")
        lines.extend(f"  - /{node.name}/{name}" for name in ("change_mode", "get_mode", "get_available_modes"))
    return lines


def serve(model: Model, args: argparse.Namespace, stop: threading.Event) -> None:
    """Run the manager node until ``stop`` is set."""
    from sm_bt.ros.environment import RosUnavailable

    try:
        from sm_bt.ros.runtime import RosRuntime

        runtime = RosRuntime(model, node_name=args.node_name, manager_options={
            "grace_period": args.grace_period, "request_timeout": args.request_timeout,
            "recovery_attempts": args.recovery_attempts, "rules": not args.no_rules,
            "recovery": not args.no_recovery})
    except (RosUnavailable, ImportError) as error:
        raise RosMissing(str(error)) from None
    # The model and the manager's tables live as long as the process: keep them out of the garbage
    # collector's full passes (at 10,000 nodes each pass walked ~700,000 objects, ~0.5 s).
    gc.freeze()
    try:
        _align_node_logger(runtime.node, args.log_level)
        for line in startup_lines(model):
            log.info(line)
        systems = sum(isinstance(p, SystemPart) for p in model.parts.values())
        print(f"mode manager {args.node_name} serving {systems} system(s) and {len(model.nodes)} node(s) of "
              f"{model.path}; Ctrl-C to stop", flush=True)
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
