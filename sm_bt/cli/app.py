"""``sm-bt``: the table of commands, the parser built from it, and :func:`main`.

Each command lives in a module of its own in this package (``check``, ``modes``, ``demo``,
``monitor``, ``view``, ``plan``, ``daemon``, ``manager``, ``mission``, ``run``, ``test``,
``sim_nodes``, ``remote``) with an ``add_arguments(parser)`` and a ``run(args)`` that returns
the exit code, imported only when its command runs; what commands share is in
:mod:`sm_bt.cli.common` (the program's name, :class:`~sm_bt.cli.common.CliError`, loading a
model by path or bundled name) and
:mod:`sm_bt.cli.arguments` (argument types). To add a command, write its module and add a
:class:`~sm_bt.cli.common.Command` to :data:`COMMANDS`.

Exit codes: 0 success, 1 any failure (a model that does not load, a missing file, ...), 2 usage
errors (argparse). Failures are reported as messages, never as tracebacks.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from sm_bt.cli.common import PROG, CliError, Command, UsageError
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.types import DEFAULT_MODE

#: Every subcommand, in the order ``--help`` lists them. Add new ones here.
COMMANDS: list[Command] = [
    Command("check", "validate model files (exit 1 if any fails to load)", "sm_bt.cli.check",
            description="Load each model strictly and report every error as FILE:LINE: error: MESSAGE."),
    Command("analyze", "find the flaws of a well-formed model (and its trees): reachability, inference, rules, "
            "faults", "sm_bt.cli.analyze",
            description="Explore MODEL (and the trees that use it) for what breaks robots: modes no request reaches, "
                        "modes inference cannot tell apart, rules that go round in a circle or undo a change, "
                        "every single node fault (or pair, --faults 2) from every mode of the top systems run on "
                        "simulated nodes (where each system ends, which rules fire), and what a tree asks for that a "
                        "fault makes unreachable. Each finding as FILE:LINE: LEVEL: MESSAGE [KIND]. Exit status 1 "
                        "when there is an error."),
    Command("modes", "print the systems, modes, rules and node parameters of a model", "sm_bt.cli.modes",
            description="Print the hierarchy of a model: systems (nested ones indented) with their modes and "
                        "rules, then every node with its parameter sets. "
                        f"'{DEFAULT_MODE}' is the reference's default-mode name."),
    Command("plan", "what a change of mode or state would do, offline: stages, calls, parameters, rules",
            "sm_bt.cli.plan",
            description="Preview asking for MODE (or a lifecycle transition) of PART in MODEL, from where --from "
                        "puts the nodes: the stages of the switching order, each node's lifecycle transitions and "
                        "parameter changes (old -> new), the number of calls, the rules that would start or stop "
                        "firing, or why it could not be made. Exit status 1 when it could not."),
    Command("demo", "run the MROS pilot mission tree on simulated nodes (--ros: real rclpy nodes)", "sm_bt.cli.demo",
            description="The pilot mission tree (patrol, laser failure, degraded mode, low battery, recharge) on the "
                        "embedded simulated backend, or with --ros on real rclpy lifecycle nodes in a child process "
                        "managed over ROS 2."),
    Command("run", "run any model with any mission tree (XML) on simulated nodes or ROS 2", "sm_bt.cli.run",
            description="Tick TREE.xml against MODEL on simulated nodes (--ros: on ROS 2, in real time): sm_bt's "
                        "behaviours, BehaviorTree.CPP's and Nav2's control nodes, and nodes declared in "
                        "<TreeNodesModel> or only named, which run as stand-ins doing what --stubs says. Narrates "
                        "what the manager does; exit 0 when the tree succeeds (or still runs at --until), 1 when it "
                        "fails or a file has mistakes."),
    Command("test", "run scenarios (faults and expectations) and judge them, for a team's CI", "sm_bt.cli.test",
            description="Run each SCENARIO with the model, tree and stubs it names, on simulated nodes as fast as "
                        "possible; one line per scenario and each failed expectation, a tally, --junit FILE for CI. "
                        "Exit 1 if a scenario failed."),
    Command("monitor", "show target and actual state/mode of every part as it changes",
            "sm_bt.cli.monitor",
            description="The mode monitor: part, target state, actual state, target mode, actual mode; systems "
                        "then nodes, (*) on inferred values, divergences highlighted. The model's nodes run on "
                        "the embedded simulated backend, or with --ros are the live ROS 2 nodes; --change requests "
                        "are made in turn."),
    Command("view", "replay a recorded run in the browser (tree, modes, timeline)", "sm_bt.cli.view",
            description="Serve the page of `sm-bt demo --view` for a run recorded with --record: the tree, the "
                        "mode table and the run's timeline, with a scrubber over every recorded tick."),
    Command("mode", "get, list or set the mode of a part, from a running manager over ROS 2",
            "sm_bt.cli.remote", add="add_mode_arguments", run_name="run_mode",
            description="Command a running mode manager (sm-bt manager, or the reference's) over the system_modes "
                        "interface: `mode get PART`, `mode list PART`, `mode set PART MODE [--wait]`. Exit status 1 "
                        "when refused, not confirmed in time or no manager answers; 2 for a part or mode that is not "
                        "served."),
    Command("state", "get or change the lifecycle state of a part over ROS 2",
            "sm_bt.cli.remote", add="add_state_arguments", run_name="run_state",
            description="`state get PART`, `state set PART TRANSITION [--wait]`: a system's through the manager, a "
                        "node's through its own lifecycle service."),
    Command("daemon", "start, stop or ask the client daemon that sm-bt mode and state call through",
            "sm_bt.cli.daemon",
            description="The client daemon keeps watching the ROS graph, so that `sm-bt mode` and `sm-bt state` "
                        "find a known manager at once instead of discovering it in every new process (up to "
                        "seconds). Those commands start it when none runs; SM_BT_DAEMON=0 turns that off."),
    Command("manager", "run the mode manager as a ROS 2 node (drop-in for system_modes' mode_manager)",
            "sm_bt.cli.manager",
            description="Serve /{system}/change_state, get_state, get_available_states and /{part}/change_mode, "
                        "get_mode, get_available_modes for every part of MODEL, publish mode_event, "
                        "transition_event and the request topics (latched, as soon as inference changes), and "
                        "manage the nodes through their lifecycle and parameter services. Needs the ros extra."),
    Command("mission", "host a mission tree on ROS 2, the manager embedded (for launch files)",
            "sm_bt.cli.mission",
            description="Tick TREE (a .xml file or package.module:function) on one ROS 2 node that embeds the mode "
                        "manager of MODEL and serves its system_modes interface and the tree's snapshot streams. "
                        "MODEL and TREE may also be the ROS parameters model and tree (--ros-args -p model:=...). "
                        "Exit status 0 when the root succeeds or on SIGINT/SIGTERM, 1 when it fails. Needs the ros "
                        "extra."),
    Command("sim-nodes", "run a model's nodes as simulated ROS 2 lifecycle nodes (stand-ins for a robot)",
            "sm_bt.cli.sim_nodes",
            description="Run the model's nodes as simulated rclpy lifecycle nodes in this process, declaring each "
                        "default mode's parameters. Prints 'READY /a,/b' once their services exist; SIGINT or "
                        "SIGTERM stops it. Faults: the sim.* parameters (sim.transition_delay, sim.fail_next, "
                        "sim.reject_parameters, sim.broken). Needs the ros extra."),
]


class _Version(argparse.Action):
    """``--version``: the installed package's version, looked up only when asked (importlib.metadata
    alone is a fifth of a short command's start)."""

    def __init__(self, option_strings: list[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS,
                         help="show program's version number and exit")

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        from importlib import metadata

        try:
            version = metadata.version("sm-bt")
        except metadata.PackageNotFoundError:
            version = "unknown"
        print(f"{parser.prog} {version}")  # on stdout, as argparse's own version action
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole parser; with ``only``, the arguments of that command alone are declared (the
    others are listed, their modules not imported: a command starts in a third of the time)."""
    parser = argparse.ArgumentParser(
        prog=PROG, description="System modes for py_trees mission trees: check and inspect SMH model files, run the "
                    "demo, watch modes, serve the mode manager on ROS 2.")
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        child = sub.add_parser(command.name, help=command.help, description=command.description or command.help)
        if only is None or command.name == only:
            command.add_arguments(child)
            child.set_defaults(run=command.run)
        _mark(child)
    return parser


def _mark(parser: argparse.ArgumentParser) -> None:
    """Each (sub)command's parser names itself in its defaults, so that an argument it does not
    know is reported by it (its usage, its options), not by the top-level parser."""
    parser.set_defaults(parser=parser)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for child in action.choices.values():
                _mark(child)


def _unknown(parser: argparse.ArgumentParser, extras: list[str]) -> str:
    """What to say of arguments ``parser`` does not take: the closest option of its own."""
    options = [option for action in parser._actions for option in action.option_strings]
    first = next((extra for extra in extras if extra.startswith("-")), extras[0])
    return f"unrecognized arguments: {' '.join(extras)}" + did_you_mean(first.split("=")[0], options)


def main(argv: list[str] | None = None) -> int:
    """Run ``sm-bt`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    words = sys.argv[1:] if argv is None else argv
    # The command is the first word that is not a top-level option (--help, --version take no value).
    parser = build_parser(only=next((word for word in words if not word.startswith("-")), ""))
    try:
        args, extras = parser.parse_known_args(argv)
        if extras:
            getattr(args, "parser", parser).error(_unknown(getattr(args, "parser", parser), extras))
    except SystemExit as stop:  # --help, --version and usage errors
        if stop.code is None or isinstance(stop.code, int):
            return stop.code or 0
        return 1
    try:
        code: int = args.run(args)
    except UsageError as error:
        print(f"{PROG} {args.command}: error: {error}", file=sys.stderr)
        return 2
    except CliError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader went away (`sm-bt modes pilot | head`): stop quietly.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except Exception as error:  # a bug: still no traceback for the user, but say so
        print(f"{PROG}: internal error: {type(error).__name__}: {error} (this is a bug in sm-bt; "
              f"set SM_BT_TRACEBACK=1 to see the traceback)", file=sys.stderr)
        if os.environ.get("SM_BT_TRACEBACK"):
            raise
        return 1
    return code
