"""``sm-bt daemon start|stop|status|run``: the client daemon that ``sm-bt mode`` and ``sm-bt state``
call through (:mod:`sm_bt.ros.client_daemon`).

Those commands start it themselves when none runs (``SM_BT_DAEMON=0`` turns that off), so a
person rarely needs this command: ``status`` says whether one runs, ``stop`` ends it, ``run``
serves in the foreground (for a service manager, or to watch its log).
"""

from __future__ import annotations

import argparse
import time

from sm_bt.cli.arguments import positive
from sm_bt.cli.common import PROG, CliError

#: How long ``start`` waits for a new daemon to answer.
START_WAIT = 10.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    start = actions.add_parser("start", help="start the daemon for this shell's ROS settings, in the background")
    run = actions.add_parser("run", help="serve in the foreground, logging to stderr (Ctrl-C stops it)")
    for child in (start, run):
        child.add_argument("--idle", type=positive, default=3600.0, metavar="SECONDS",
                           help="exit after this long without a command (default 3600)")
    actions.add_parser("stop", help="stop the daemon for this shell's ROS settings")
    actions.add_parser("status", help="say whether a daemon serves this shell's ROS settings (exit 1 if not)")
    parser.epilog = ("One daemon per user and per ROS setting (ROS_DOMAIN_ID, ROS_AUTOMATIC_DISCOVERY_RANGE, "
                     "ROS_STATIC_PEERS, the RMW and its profile files): it watches that ROS graph so that `sm-bt "
                     "mode` and `sm-bt state` find a known manager at once.")


def run(args: argparse.Namespace) -> int:
    from sm_bt.ros import client_daemon

    path = client_daemon.socket_path()
    if args.action == "run":
        from sm_bt.ros.console_log import configure_logging
        from sm_bt.ros.environment import RosUnavailable

        configure_logging("info")
        try:
            return client_daemon.serve(idle=args.idle, path=path,
                                       ready=lambda where: print(f"READY {where}", flush=True))
        except RosUnavailable as error:
            raise CliError(str(error)) from None
    if args.action == "start":
        return _start(path, args.idle)
    try:
        answer = client_daemon.ask(args.action, path)
    except client_daemon.DaemonUnavailable:
        if args.action == "stop":
            print(f"{PROG} daemon: none runs for these ROS settings")
            return 0
        print(f"{PROG} daemon: none runs for these ROS settings ({path})")
        return 1
    if args.action == "stop":
        print(f"{PROG} daemon: stopped (pid {answer['pid']})")
        return 0
    settings = ", ".join(f"{name}={value}" for name, value in answer["settings"].items()) or "ROS's defaults"
    print(f"{PROG} daemon: running (pid {answer['pid']}, up {answer['uptime']:.0f} s, {answer['served']} "
          f"commands served; exits after {answer['idle_exit']:g} s without one)\n  settings: {settings}\n"
          f"  socket: {path}")
    return 0


def _start(path: object, idle: float) -> int:
    from sm_bt.ros import client_daemon

    try:
        answer = client_daemon.ask("status")
        print(f"{PROG} daemon: already running (pid {answer['pid']})")
        return 0
    except client_daemon.DaemonUnavailable:
        pass
    pid = client_daemon.start_detached(idle)
    give_up = time.monotonic() + START_WAIT
    while time.monotonic() < give_up:
        try:
            client_daemon.ask("status")
            print(f"{PROG} daemon: started (pid {pid})")
            return 0
        except client_daemon.DaemonUnavailable:
            time.sleep(0.1)
    raise CliError(f"the daemon (pid {pid}) did not answer within {START_WAIT:g} s: its log is "
                   f"{client_daemon.socket_path().with_suffix('.log')}")
