"""``sm-bt mode ...`` and ``sm-bt state ...``: command a running mode manager from a shell.

They speak the system_modes interface (:mod:`sm_bt.ros.client`), so they work against
``sm-bt manager`` and the reference's ``mode_manager``, with no ROS install beyond the ``ros``
extra::

    sm-bt mode get pilot                         # pilot: f_normal_mode
    sm-bt mode list pilot                        # the modes the manager offers
    sm-bt mode set pilot f_degraded_mode --wait  # waits for the manager to confirm it
    sm-bt mode hold pilot f_degraded_mode        # holds it until Ctrl-C (sm-bt manager only)
    sm-bt state get pilot
    sm-bt state set pilot configure --wait

Exit status: 0 done (or accepted, without ``--wait``); 1 refused, not confirmed in time, or no
manager answers; 2 a part, mode or transition that is not served (with the closest names).
"""

from __future__ import annotations

import argparse
import contextlib
import time
from contextlib import AbstractContextManager
from typing import Any

from sm_bt.cli.arguments import non_negative, positive
from sm_bt.cli.common import CliError, UsageError
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, TRANSITION_GOALS

DEFAULT_TIMEOUT = 10.0
#: `sm-bt mode hold`'s lease: how long a hold outlives a command that died (renewed every third).
HOLD_LEASE = 5.0
#: Seconds a forced node transition must hold before --wait calls it final: longer than a mode
#: manager's grace period (2 s by default) and its restore.
SETTLE = 5.0


PART_HELP = "a system or node of the running manager's model (`sm-bt mode list` shows a part's modes)"


def _common(parser: argparse.ArgumentParser, *, waits: bool = False) -> None:
    parser.add_argument("--timeout", type=non_negative, default=DEFAULT_TIMEOUT, metavar="SECONDS",
                        help="give up after this long: to find the manager, for each answer"
                             + (", and with --wait for the confirmation" if waits else "")
                             + f" (default {DEFAULT_TIMEOUT:g})")


def add_mode_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    get = actions.add_parser("get", help="print the part's current mode, as the manager infers it")
    get.add_argument("part", metavar="PART", help=PART_HELP)
    listed = actions.add_parser("list", help="print the modes the manager offers for the part")
    listed.add_argument("part", metavar="PART", help=PART_HELP)
    put = actions.add_parser("set", help="ask the manager for a mode of the part")
    put.add_argument("part", metavar="PART", help=PART_HELP)
    put.add_argument("mode", metavar="MODE", help="one of the part's modes (`sm-bt mode list PART`), or __DEFAULT__")
    put.add_argument("--wait", action="store_true",
                     help="wait until the manager confirms the part is in MODE; print how long it took")
    put.add_argument("--dry-run", action="store_true",
                     help="ask sm-bt manager what the change would do, and do nothing: the plan (stages, calls, "
                          "parameters), or why it would be refused (exit 1)")
    _who(put)
    put.add_argument("--queue", action="store_true",
                     help="held back by a hold of a higher priority, wait for it to end (within the manager's "
                          "request timeout) instead of being refused; needs sm-bt manager")
    hold = actions.add_parser("hold", help="hold the part in MODE while this command runs: requests of a lower "
                                           "priority that would change it are refused, naming the holder; Ctrl-C "
                                           "(or --for) releases it, and if the command dies the lease runs out")
    hold.add_argument("part", metavar="PART", help=PART_HELP)
    hold.add_argument("mode", metavar="MODE", help="one of the part's modes, or __DEFAULT__")
    hold.add_argument("--lease", type=positive, default=HOLD_LEASE, metavar="SECONDS",
                      help=f"how long the hold outlives this command's last renewal (default {HOLD_LEASE:g}; "
                           "renewed every third of it)")
    hold.add_argument("--for", dest="hold_for", type=positive, metavar="SECONDS",
                      help="release it after this long (default: at Ctrl-C)")
    _who(hold)
    for child in (get, listed, hold):
        _common(child)
    _common(put, waits=True)
    parser.epilog = ("Needs a mode manager on ROS 2 (`sm-bt manager MODEL`, or the reference's) in this shell's "
                     "ROS_DOMAIN_ID.")


def add_state_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    get = actions.add_parser("get", help="print the part's lifecycle state")
    get.add_argument("part", metavar="PART", help=PART_HELP)
    put = actions.add_parser("set", help="ask for a lifecycle transition of the part (a system's through the "
                                         "manager, a node's through its own service)")
    put.add_argument("part", metavar="PART", help=PART_HELP)
    put.add_argument("transition", metavar="TRANSITION", help=f"one of {', '.join(REQUESTABLE_LABELS)}")
    put.add_argument("--wait", action="store_true", help="wait until the part is in the state the transition "
                                                         "leads to; print how long it took (with --force, and "
                                                         "what holds once its manager had its say)")
    put.add_argument("--force", action="store_true",
                     help="send it to a node that a mode manager manages: the manager takes a change it did "
                          "not ask for as a fault and puts the node back after its grace period")
    _who(put)
    _common(get)
    _common(put, waits=True)


def _priority(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a priority (a whole number, 0 or more)")
    return value


def _who(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--requester", metavar="NAME",
                        help="who asks (default: the manager's, operator unless `sm-bt manager --requester` says "
                             "otherwise); needs sm-bt manager")
    parser.add_argument("--priority", type=_priority, metavar="N",
                        help="the request's priority against the holds (default: the requester's: rule 100, "
                             "operator 80, metacontroller 60, tree 40); a part held at a higher one refuses it, "
                             "naming the holder; needs sm-bt manager")


def _client(args: argparse.Namespace) -> AbstractContextManager[Any]:
    """The client daemon's when one runs (it knows the graph already); else a client of this
    process's own, and a daemon started for the next command (unless ``SM_BT_DAEMON=0``)."""
    from sm_bt.ros import client_daemon
    from sm_bt.ros.environment import RosUnavailable

    if client_daemon.enabled():
        try:
            return client_daemon.DaemonClient(args.timeout)
        except client_daemon.DaemonUnavailable:
            pass
    try:
        from sm_bt.ros.client import ModeClient

        own = ModeClient(timeout=args.timeout)
    except (RosUnavailable, ImportError) as error:
        raise CliError(str(error)) from None
    if client_daemon.enabled():
        with contextlib.suppress(OSError):
            client_daemon.start_detached()
    return own


def _translated(args: argparse.Namespace, action: Any) -> int:
    """Run ``action(client)``: the client's errors become the CLI's (usage error: exit 2)."""
    from sm_bt.ros.client import ManagerUnreachable, NotConfirmed, UnknownName

    with _client(args) as client:
        try:
            result: int = action(client)
            return result
        except UnknownName as error:
            raise UsageError(str(error)) from None
        except (ManagerUnreachable, NotConfirmed) as error:
            raise CliError(str(error)) from None


def run_mode(args: argparse.Namespace) -> int:
    part = args.part.lstrip("/")

    def get(client: Any) -> int:
        mode = client.get_mode(part)
        print(f"{part}: {mode or '(no mode: not active)'}")
        return 0

    def listed(client: Any) -> int:
        for mode in client.available_modes(part):
            print(mode)
        return 0

    def put(client: Any) -> int:
        client.check_mode(part, args.mode)
        if args.dry_run:
            possible, lines = client.preview_change(part, mode=args.mode)
            print("\n".join(lines))
            return 0 if possible else 1
        asks = args.priority is not None or args.requester is not None or args.queue
        if args.wait:
            client.listen(part, "mode")
        if asks or client.offers(part, "request_change"):
            accepted, reason = client.request_change(part, mode=args.mode, requester=args.requester or "",
                                                     priority=-1 if args.priority is None else args.priority,
                                                     queue=args.queue)
        else:  # the reference's manager: yes or no
            accepted, reason = client.change_mode(part, args.mode), "its log says why"
        if not accepted:
            raise CliError(f"the manager refused mode {args.mode!r} for {part}: {reason}")
        if not args.wait:
            print(f"{part}: change to {args.mode} " + (f"accepted, {reason}" if accepted and reason else "accepted"))
            return 0
        seconds = client.wait_for_mode(part, args.mode, client.sent)
        print(f"{part}: {args.mode} confirmed {seconds:.2f} s after the request")
        return 0

    def held(client: Any) -> int:
        client.check_mode(part, args.mode)
        accepted, reason, number = client.hold_mode(part, args.mode, args.requester or "",
                                                    -1 if args.priority is None else args.priority, args.lease)
        if not accepted:
            raise CliError(f"the manager refused to hold {part} in {args.mode}: {reason}")
        print(f"{part}: held in {args.mode} (hold #{number}, lease {args.lease:g} s); "
              + ("Ctrl-C releases it" if args.hold_for is None else f"released in {args.hold_for:g} s or at Ctrl-C"),
              flush=True)
        ends = None if args.hold_for is None else time.monotonic() + args.hold_for
        try:
            while ends is None or time.monotonic() < ends:
                time.sleep(args.lease / 3 if ends is None else max(0.0, min(args.lease / 3, ends - time.monotonic())))
                accepted, reason, _ = client.hold_mode(part, hold=number)
                if not accepted:
                    raise CliError(f"{part}: no longer held: {reason}")
        except KeyboardInterrupt:
            pass
        client.hold_mode(part, hold=number, release=True)
        print(f"{part}: released", flush=True)
        return 0

    return _translated(args, {"get": get, "list": listed, "set": put, "hold": held}[args.action])


def run_state(args: argparse.Namespace) -> int:
    part = args.part.lstrip("/")

    def get(client: Any) -> int:
        print(f"{part}: {client.get_state(part)}")
        return 0

    def put(client: Any) -> int:
        if args.wait:
            client.listen(part, "state")
        if args.priority is not None or args.requester is not None:  # through sm-bt manager, always
            accepted, reason = client.request_change(part, transition=args.transition, requester=args.requester or "",
                                                     priority=-1 if args.priority is None else args.priority)
            if not accepted:
                raise CliError(f"the manager refused the transition {args.transition!r} for {part}: {reason}")
            return _confirm_state(client, args, part, managed=False)
        managed = client.managed_node(part)
        if managed and not args.force:
            raise CliError(f"{part} is a node that a mode manager manages: it would take a transition it did not ask "
                           "for as a fault and undo it after its grace period. Ask the manager instead (a system's "
                           f"state or mode, or `sm-bt mode set {part} MODE`), or add --force to send it anyway")
        if not client.change_state(part, args.transition):
            raise CliError(f"{part} refused the transition {args.transition!r} (from {client.get_state(part)})")
        return _confirm_state(client, args, part, managed)

    return _translated(args, {"get": get, "set": put}[args.action])


def _confirm_state(client: Any, args: argparse.Namespace, part: str, managed: bool) -> int:
    """After an accepted transition: say so, or with ``--wait`` how long it took to be confirmed
    (and, for a managed node, whether its manager left it there)."""
    if not args.wait:
        print(f"{part}: {args.transition} accepted" + (" (its mode manager may undo it)" if managed else ""))
        return 0
    seconds = client.wait_for_state(part, args.transition, client.sent)
    reached = TRANSITION_GOALS[args.transition]  # confirmed; not asked again: a managed node may be back already
    print(f"{part}: {reached} {seconds:.2f} s after the request")
    if managed:
        final = client.state_after(part, SETTLE)
        if final != reached:
            raise CliError(f"{part}: then {final} again: its mode manager put it back")
        print(f"{part}: still {final} {SETTLE:g} s later")
    return 0
