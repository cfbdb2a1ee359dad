"""Argument types shared by the CLI's subcommands: a bad value is a usage error (exit 2) with a
message that says what is expected, never a traceback."""

from __future__ import annotations

import argparse
import math


def non_negative(text: str) -> float:
    """A finite number of seconds (or a speed), 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number, 0 or more")
    return value


def positive(text: str) -> float:
    """A finite number (a rate, seconds) more than 0."""
    value = non_negative(text)
    if value == 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be more than 0")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} must be 1 or more")
    return value


def port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port {port} is not between 0 and 65535")
    return port


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    """``--view [PORT]``, ``--host`` and ``--record``: a run's live view and its recording."""
    parser.add_argument("--view", type=port, nargs="?", const=8765, default=None, metavar="PORT",
                        help="serve a live view of the tree, the modes and the run at http://127.0.0.1:PORT/ "
                             "(default port 8765; 0: any free port); it stays until Ctrl-C after the run")
    parser.add_argument("--host", default="127.0.0.1", metavar="HOST",
                        help="with --view: the address it listens on (default 127.0.0.1: this machine only), "
                             "as `sm-bt view --host`")
    parser.add_argument("--record", metavar="FILE.jsonl",
                        help="write the view's frames to FILE.jsonl; `sm-bt view FILE.jsonl` replays them")


def namespace(text: str) -> str:
    """A ROS 2 namespace for a robot's nodes and manager: ``/robot1`` (``/`` is the root)."""
    from sm_bt.ros.names import valid_namespace

    if not valid_namespace(text):
        raise argparse.ArgumentTypeError(f"{text!r} is not a ROS 2 namespace: write it absolute, with letters, "
                                         "digits and underscores, e.g. /robot1")
    return text
