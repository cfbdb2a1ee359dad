"""What every ``sm-bt`` command shares: the program's name, its error type, the table entry of a
command, and finding and loading a model by path or bundled name."""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from sm_bt import bundled
from sm_bt.model.errors import Error, ModelError
from sm_bt.model.loader import load_model
from sm_bt.model.types import Model, ModelIssue

PROG = "sm-bt"


class CliError(Error):
    """A failure to report as ``sm-bt: error: MESSAGE`` with exit code 1 (no traceback)."""


class UsageError(CliError):
    """A value on the command line that cannot be right (an unknown part, mode or transition),
    found once the model is loaded: ``sm-bt COMMAND: error: MESSAGE``, exit code 2 as argparse's."""


def check_request(model: Model, part: str, value: str, option: str, model_name: str = "") -> None:
    """Raise :class:`UsageError` unless ``part`` is in ``model`` and ``value`` is one of its modes
    or a lifecycle transition, with the closest names ("did you mean ...?"). ``model_name``: the
    model as the user named it (default: its path)."""
    from sm_bt.engine.lifecycle import REQUESTABLE_LABELS
    from sm_bt.model.diagnostics import did_you_mean

    if part not in model.parts:
        raise UsageError(f"{option} {part}={value}: no part {part!r} in {model_name or model.path}"
                         f"{did_you_mean(part, model.parts) or ' (parts: ' + ', '.join(model.parts) + ')'}")
    modes = tuple(model.parts[part].modes)
    if value not in modes and value not in REQUESTABLE_LABELS:
        hint = did_you_mean(value, (*modes, *REQUESTABLE_LABELS)) or (
            f" (modes: {', '.join(modes)}; transitions: {', '.join(REQUESTABLE_LABELS)})")
        raise UsageError(f"{option} {part}={value}: {value!r} is neither a mode of {part} nor a transition{hint}")


@dataclass(frozen=True)
class Command:
    """One subcommand, implemented in ``module`` (imported only when the command runs or its
    arguments are declared): its ``add_arguments(parser)`` declares the arguments, its ``run(args)``
    returns the exit code (or raises :class:`CliError`). ``add`` and ``run_name`` name other
    functions of the module for a module of several commands."""

    name: str
    help: str
    module: str
    description: str = ""
    add: str = "add_arguments"
    run_name: str = "run"

    @property
    def add_arguments(self) -> Callable[[argparse.ArgumentParser], None]:
        found: Callable[[argparse.ArgumentParser], None] = getattr(importlib.import_module(self.module), self.add)
        return found

    @property
    def run(self) -> Callable[[argparse.Namespace], int]:
        found: Callable[[argparse.Namespace], int] = getattr(importlib.import_module(self.module), self.run_name)
        return found


def shipped_nodes() -> None:
    """Register the pilot's actions (``<BatteryToBlackboard>``, ``<NavigateTo>``, ...) in py_trees'
    ports registry, for every command that reads a tree file: the shipped trees use them."""
    import sm_bt.trees.pilot  # noqa: F401


# -- loading models ----------------------------------------------------------------------------


def bundled_names() -> tuple[str, ...]:
    """The names of the models shipped with sm_bt (``pilot``, ...)."""
    return bundled.names()


def resolve_model(name: str) -> Path:
    """The file ``name`` refers to: an existing path, else a bundled model (``pilot``).

    Raises :class:`CliError` when it is neither.
    """
    candidate = bundled.resolve(name)
    if candidate.exists():
        return candidate
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


def plural(count: int, word: str) -> str:
    return f"{count} {word}" if count == 1 else f"{count} {word}s"


def part_counts(model: Model) -> str:
    """``1 system, 4 nodes`` (and ``, 2 remote parts`` where it has some)."""
    remote = sum(node.remote is not None for node in model.nodes)
    text = f"{plural(len(model.systems), 'system')}, {plural(len(model.nodes) - remote, 'node')}"
    return text + (f", {plural(remote, 'remote part')}" if remote else "")


def print_issues(issues: Sequence[ModelIssue], stream: TextIO) -> None:
    for issue in issues:
        print(issue, file=stream)


def report_failed(name: str, issues: Sequence[object]) -> int:
    """Print each of a file's mistakes, then ``NAME: failed (N errors)``, on stderr; 1, the exit code."""
    for issue in issues:
        print(issue, file=sys.stderr)
    print(f"{name}: failed ({plural(len(issues), 'error')})", file=sys.stderr)
    return 1


def load_or_report(name: str, *, strict: bool) -> Model | None:
    """The model, or ``None`` after printing why it failed to stderr."""
    try:
        return load(name, strict=strict)
    except ModelError as error:
        print_issues(error.issues, sys.stderr)
        print(f"{name}: failed ({plural(len(error.issues), 'error')})", file=sys.stderr)
    except CliError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
    return None


def add_lenient(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--lenient", action="store_true",
        help="accept what the reference implementation accepts where sm_bt is stricter "
             "(an undefined part in a mode becomes a warning)",
    )
