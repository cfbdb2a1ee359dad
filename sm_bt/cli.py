"""The ``sm-bt`` console script.

Subcommands are registered in :data:`COMMANDS`: each is a :class:`Command` with a function that
adds its arguments and a function that runs it and returns the exit code. To add one, write both
functions and append an entry to the table; :func:`main` builds the parser from the table.

Exit codes: 0 success, 1 any failure (a model that does not load, a missing file, ...), 2 usage
errors (argparse). Failures are reported as messages, never as tracebacks.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from sm_bt import bundled, demo, manager_cli, monitor_cli
from sm_bt.model.errors import ModelError
from sm_bt.model.loader import load_model
from sm_bt.model.types import (
    DEFAULT_MODE,
    DONT_CARE,
    EXACT,
    Match,
    Model,
    ModelIssue,
    NodePart,
    ParamValue,
    PartEntry,
    Rule,
    SystemPart,
)

PROG = "sm-bt"


class CliError(Exception):
    """A failure to report as ``sm-bt: error: MESSAGE`` with exit code 1 (no traceback)."""


@dataclass(frozen=True)
class Command:
    """One subcommand: ``add_arguments(parser)`` declares its arguments, ``run(args)`` returns
    the exit code (or raises :class:`CliError`)."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str = ""


# -- loading models ----------------------------------------------------------------------------


def bundled_names() -> tuple[str, ...]:
    """The names of the models shipped with sm_bt (``pilot``, ...)."""
    return bundled.names()


def resolve_model(name: str) -> Path:
    """The file ``name`` refers to: an existing path, else a bundled model (``pilot``).

    Raises :class:`CliError` when it is neither.
    """
    candidate = Path(name)
    if candidate.exists():
        return candidate
    if os.sep not in name and "/" not in name:
        try:
            return bundled.path(name)
        except KeyError:
            pass
    shipped = ", ".join(bundled_names()) or "none"
    raise CliError(f"{name}: no such file, and no bundled model of that name (bundled: {shipped})")


def load(name: str, *, strict: bool = True) -> Model:
    """Load the model ``name`` (path or bundled name); :class:`ModelError` for an invalid model,
    :class:`CliError` for every other failure (missing or unreadable file)."""
    path = resolve_model(name)
    try:
        return load_model(path, strict=strict)
    except ModelError:
        raise
    except IsADirectoryError:
        raise CliError(f"{name}: is a directory, not a model file") from None
    except OSError as error:
        raise CliError(f"{name}: cannot read: {error.strerror or error}") from None
    except UnicodeDecodeError as error:
        raise CliError(f"{name}: not a text file ({error.reason} at byte {error.start})") from None


def _plural(count: int, word: str) -> str:
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def _print_issues(issues: Sequence[ModelIssue], stream: TextIO) -> None:
    for issue in issues:
        print(issue, file=stream)


def _load_or_report(name: str, *, strict: bool) -> Model | None:
    """The model, or ``None`` after printing why it failed to stderr."""
    try:
        return load(name, strict=strict)
    except ModelError as error:
        _print_issues(error.issues, sys.stderr)
        print(f"{name}: failed ({_plural(len(error.issues), 'error')})", file=sys.stderr)
    except CliError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
    return None


def _add_lenient(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--lenient", action="store_true",
        help="accept what the reference implementation accepts where sm_bt is stricter "
             "(an undefined part in a mode becomes a warning)",
    )


# -- check -------------------------------------------------------------------------------------


def _check_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("models", nargs="+", metavar="FILE",
                        help="model file, or the name of a bundled model (" + ", ".join(bundled_names()) + "); "
                             "a mission tree file (.xml) is checked against the models given with it")
    _add_lenient(parser)


def run_check(args: argparse.Namespace) -> int:
    failed = 0
    trees = [name for name in args.models if name.endswith(".xml")]
    models: list[tuple[str, Model]] = []
    for name in args.models:
        if name in trees:
            continue
        model = _load_or_report(name, strict=not args.lenient)
        if model is None:
            failed += 1
            continue
        models.append((name, model))
        print(f"{name}: ok ({_plural(len(model.systems), 'system')}, {_plural(len(model.nodes), 'node')})")
        _print_issues(model.warnings, sys.stdout)
    for tree in trees:
        failed += not _check_tree_file(tree, models)
    return 1 if failed else 0


def _check_tree_file(tree: str, models: list[tuple[str, Model]]) -> bool:
    """Check ``tree`` against every model (or alone, without one); print what was found."""
    import sm_bt.trees.pilot  # noqa: F401 (registers the pilot's actions, which shipped trees use)
    from sm_bt.trees.mission_xml import check_tree

    against: list[tuple[str, Model | None]] = list(models) or [("", None)]
    ok = True
    for name, model in against:
        issues = check_tree(tree, model)
        for issue in issues:
            print(issue, file=sys.stderr)
        ok = ok and not issues
        if not issues:
            print(f"{tree}: ok" + (f" against {name}" if name else " (no model given: parts and modes not checked)"))
    return ok


# -- modes -------------------------------------------------------------------------------------


def _modes_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL",
                        help="model file, or the name of a bundled model (" + ", ".join(bundled_names()) + ")")
    _add_lenient(parser)


def run_modes(args: argparse.Namespace) -> int:
    model = _load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    _print_issues(model.warnings, sys.stderr)
    for line in describe_model(model):
        print(line)
    return 0


def describe_model(model: Model) -> Iterator[str]:
    """The hierarchy of ``model`` as plain-text lines (systems top-down, then every node)."""
    yield f"model {model.path}: {_plural(len(model.systems), 'system')}, {_plural(len(model.nodes), 'node')}"
    shown: set[str] = set()
    for root in model.roots():
        part = model.parts[root]
        if isinstance(part, SystemPart):
            yield ""
            yield from _describe_system(model, part, 0, shown)
    if model.nodes:
        yield ""
        yield "nodes"
    for node in model.nodes:
        yield from _describe_node(model, node, 1)
    yield ""
    yield f"legend: * default mode, (keep) {DONT_CARE} (left as it is), ~ inference matching"


def _describe_system(model: Model, system: SystemPart, depth: int, shown: set[str]) -> Iterator[str]:
    pad = "  " * depth
    if system.name in shown:
        yield f"{pad}system {system.name} (shown above)"
        return
    shown.add(system.name)
    yield f"{pad}system {system.name}"
    yield f"{pad}  parts: {', '.join(system.parts) or '(none)'}"
    yield f"{pad}  modes:"
    for mode in system.modes.values():
        marker = "*" if mode.name == system.default_mode else " "
        yield f"{pad}    {marker} {mode.name}"
        for part in system.parts:
            entry = mode.entries.get(part)
            if entry is not None:
                yield f"{pad}        {part}: {_entry_text(entry)}"
        if len(mode.stages) > 1:
            yield f"{pad}        order: {' -> '.join(', '.join(stage) for stage in mode.stages)}"
    if system.rules:
        yield f"{pad}  rules:"
        for rule in system.rules:
            yield f"{pad}    {_rule_text(rule)}"
    for name in system.parts:
        child = model.parts[name]
        if isinstance(child, SystemPart):
            yield from _describe_system(model, child, depth + 1, shown)


def _describe_node(model: Model, node: NodePart, depth: int) -> Iterator[str]:
    pad = "  " * depth
    parents = model.parents(node.name)
    where = f"part of {', '.join(parents)}" if parents else "in no system"
    yield f"{pad}node {node.name} ({where})"
    yield f"{pad}  modes:"
    for mode in node.modes.values():
        marker = "*" if mode.name == node.default_mode else " "
        yield f"{pad}    {marker} {mode.name}"
        for spec in mode.parameters.values():
            match = "" if spec.match == EXACT else f"  ~ {_match_text(spec.match)}"
            yield f"{pad}        {spec.name}: {format_value(spec.value)}{match}"
    if node.rules:
        yield f"{pad}  rules:"
        for rule in node.rules:
            yield f"{pad}    {_rule_text(rule)}"


def _entry_text(entry: PartEntry) -> str:
    return "(keep)" if entry.target is None else str(entry.target)


def _rule_text(rule: Rule) -> str:
    return (f"{rule.name}: if target {rule.if_target} and {rule.if_part} is {rule.if_part_state} "
            f"-> {rule.new_target}")


def _match_text(match: Match) -> str:
    pieces = []
    if match.tolerance is not None:
        pieces.append(f"tolerance {format_value(match.tolerance)}")
    if match.minimum is not None or match.maximum is not None:
        low = "-inf" if match.minimum is None else format_value(match.minimum)
        high = "inf" if match.maximum is None else format_value(match.maximum)
        pieces.append(f"[{low}, {high}]")
    return ", ".join(pieces)


def format_value(value: ParamValue) -> str:
    """A parameter value as it would be written in a model file, typed unambiguously: strings
    quoted, booleans ``true``/``false``, doubles with a decimal point or exponent."""
    if isinstance(value, tuple):
        return "[" + ", ".join(format_value(item) for item in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return ".nan" if math.isnan(value) else (".inf" if value > 0 else "-.inf")
    return repr(value)


# -- manager ---------------------------------------------------------------------------------


def run_manager(args: argparse.Namespace) -> int:
    manager_cli.configure_logging(args.log_level)  # stderr, ROS 2's format; the library never does this
    model = _load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    stop = threading.Event()
    manager_cli.install_stop_handlers(stop)
    try:
        manager_cli.serve(model, args, stop)
    except manager_cli.RosMissing as error:
        raise CliError(str(error)) from None
    return 0


# -- view --------------------------------------------------------------------------------------


def _view_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="FILE.jsonl", help="a run recorded with `sm-bt demo --record FILE.jsonl`")
    parser.add_argument("--port", type=int, default=8765, help="port to serve on (default 8765; 0: any free port)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")


def run_view(args: argparse.Namespace) -> int:
    from sm_bt.view import read_recording
    from sm_bt.view.server import ViewServer

    try:
        frames = read_recording(args.recording)
    except OSError as error:
        raise CliError(f"cannot read {args.recording}: {error.strerror or error}") from None
    except ValueError as error:
        raise CliError(str(error)) from None
    try:
        server = ViewServer(args.host, args.port, frames=frames)
    except OSError as error:
        raise CliError(f"cannot serve on {args.host}:{args.port}: {error.strerror or error} (try --port 0)") from None
    except RuntimeError as error:
        raise CliError(str(error)) from None
    print(f"{args.recording}: {len(frames)} frame(s); open {server.url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0


# -- the table and main ------------------------------------------------------------------------

#: Every subcommand, in the order ``--help`` lists them. Add new ones here.
COMMANDS: list[Command] = [
    Command("check", "validate model files (exit 1 if any fails to load)", _check_arguments, run_check,
            description="Load each model strictly and report every error as FILE:LINE: error: MESSAGE."),
    Command("modes", "print the systems, modes, rules and node parameters of a model", _modes_arguments,
            run_modes, description="Print the hierarchy of a model: systems (nested ones indented) with "
                                   f"their modes and rules, then every node with its parameter sets. "
                                   f"'{DEFAULT_MODE}' is the reference's default-mode name."),
    Command("demo", "run the MROS pilot mission tree on simulated nodes (--ros: real rclpy nodes)", demo.add_arguments,
            demo.run,
            description="The pilot mission tree (patrol, laser failure, degraded mode, low battery, recharge) on the "
                        "embedded simulated backend, or with --ros on real rclpy lifecycle nodes in a child process "
                        "managed over ROS 2."),
    Command("monitor", "show target and actual state/mode of every part as it changes",
            monitor_cli.add_arguments, monitor_cli.run,
            description="The mode monitor: part, target state, actual state, target mode, actual mode; systems "
                        "then nodes, (*) on inferred values, divergences highlighted. The model's nodes run on "
                        "the embedded simulated backend, or with --ros are the live ROS 2 nodes; --change requests "
                        "are made in turn."),
    Command("view", "replay a recorded run in the browser (tree, modes, timeline)", _view_arguments, run_view,
            description="Serve the page of `sm-bt demo --view` for a run recorded with --record: the tree, the "
                        "mode table and the run's timeline, with a scrubber over every recorded tick."),
    Command("manager", "run the mode manager as a ROS 2 node (drop-in for system_modes' mode_manager)",
            manager_cli.add_arguments, run_manager,
            description="Serve /{system}/change_state, get_state, get_available_states and /{part}/change_mode, "
                        "get_mode, get_available_modes for every part of MODEL, publish mode_event, "
                        "transition_event and the request topics (latched, as soon as inference changes), and "
                        "manage the nodes through their lifecycle and parameter services. Needs the ros extra."),
]


def _version() -> str:
    from importlib import metadata

    try:
        return metadata.version("sm-bt")
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description="System modes for py_trees mission trees: check and inspect SMH model files, run the "
                    "demo, watch modes, serve the mode manager on ROS 2.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        child = sub.add_parser(command.name, help=command.help, description=command.description or command.help)
        command.add_arguments(child)
        child.set_defaults(run=command.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``sm-bt`` with ``argv`` (default ``sys.argv[1:]``); return the exit code."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # --help, --version and usage errors
        if stop.code is None or isinstance(stop.code, int):
            return stop.code or 0
        return 1
    try:
        code: int = args.run(args)
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


if __name__ == "__main__":
    sys.exit(main())
