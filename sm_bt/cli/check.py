"""``sm-bt check FILE...``: validate model files (and mission trees against them).

Every file is checked, whatever happened to the ones before: a model that fails to load, a tree
with errors, even a bug in sm-bt on one file (reported as an internal error for that file;
``--debug`` adds the traceback). A directory stands for the model and tree files below it. Exit
status 1 if any file failed.

A tree is checked against the model it names in a comment, ``<!-- sm_bt model: pilot -->`` (a
bundled model's name, or a path relative to the tree file), else against ``--model``, else
against every model given with it; each error says which model it is against. A scenario file
(``events:``/``expect:``, :mod:`sm_bt.scenario`) is checked against the model it names, with its
world, and the tree and stubs it names are checked too; a stubs file is checked alone.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import traceback
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import TypeVar

from sm_bt.cli.common import (
    CliError,
    add_lenient,
    bundled_names,
    load_or_report,
    part_counts,
    plural,
    print_issues,
    report_failed,
    shipped_nodes,
)
from sm_bt.model.types import Model, Severity
from sm_bt.trees.stubs import Stub


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("models", nargs="+", metavar="FILE",
                        help="model file, a directory (every .yaml/.yml model and .xml tree below it), or the name "
                             "of a bundled model (" + ", ".join(bundled_names()) + "); a mission tree file (.xml) "
                             "is checked against the models given with it")
    parser.add_argument("--model", metavar="MODEL",
                        help="check the tree files against this model (a file or a bundled name), unless a tree "
                             "names its own (<!-- sm_bt model: NAME -->)")
    parser.add_argument("--stubs", metavar="FILE",
                        help="what the tree files' declared or unknown nodes do when run (YAML or JSON; see sm-bt "
                             "run): checked, and a node a stub names counts as known")
    add_lenient(parser)
    parser.add_argument("--reference", action="store_true",
                        help="also say which constructs of each model the reference manager (micro-ROS/system_modes) "
                             "misreads or handles differently (sm_bt's extensions, ...), with their lines; exit "
                             "status 1 if it cannot read one")
    parser.add_argument("--deep", action="store_true",
                        help="also analyse each model as `sm-bt analyze MODEL` does (every single node fault run on "
                             "simulated nodes, reachability, inference, rules); exit status 1 on an error-level "
                             "finding")
    parser.add_argument("--debug", action="store_true",
                        help="on an internal error (a bug in sm-bt), print its traceback and go on")


MODEL_SUFFIXES = (".yaml", ".yml")
#: How a tree file names its model (a comment, so that BehaviorTree.CPP and Groot2 read the file as ever).
DECLARED_MODEL = re.compile(r"<!--\s*sm_bt model:\s*(\S+)\s*-->")


def _expand(names: Sequence[str]) -> list[str]:
    """Every name, with a directory replaced by the model and tree files below it (sorted)."""
    out: list[str] = []
    for name in names:
        if os.path.isdir(name):
            found = sorted(str(path) for path in Path(name).rglob("*")
                           if path.suffix in (*MODEL_SUFFIXES, ".xml") and path.is_file())
            if not found:
                raise CliError(f"{name}: a directory with no model (.yaml, .yml) or tree (.xml) files")
            out += found
        else:
            out.append(name)
    return out


def _kind(name: str) -> str:
    """What a file is: "tree" (.xml), "scenario", "stubs" or "model", from its top-level keys."""
    if name.endswith(".xml"):
        return "tree"
    import yaml

    from sm_bt.scenario import SETUP

    try:
        document = yaml.safe_load(Path(name).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, RecursionError, ValueError):
        return "model"  # loading it as a model says what is wrong
    if not isinstance(document, dict) or not document:
        return "model"
    if {"events", "expect"} & set(document) and set(document) <= {"events", "expect", *SETUP}:
        return "scenario"
    if all(isinstance(value, dict) and "status" in value for value in document.values()):
        return "stubs"
    return "model"


def run(args: argparse.Namespace) -> int:
    names = _expand(args.models)
    kinds = {name: _kind(name) for name in names}
    trees = [name for name in names if kinds[name] == "tree"]
    models: list[tuple[str, Model]] = []
    failed = 0
    for name in names:
        if kinds[name] == "scenario":
            failed += not _guarded(name, args.debug, partial(_check_scenario, name, args.lenient))
        if kinds[name] == "stubs":
            stubs_ok = _guarded(name, args.debug, partial(_stubs, name)) is not None
            failed += not stubs_ok
            if stubs_ok:
                print(f"{name}: ok (stubs)")
        if kinds[name] != "model":
            continue
        model = _guarded(name, args.debug, partial(load_or_report, name, strict=not args.lenient))
        if model is None:
            failed += 1
            continue
        models.append((name, model))
        print(f"{name}: ok ({part_counts(model)})")
        print_issues(model.warnings, sys.stdout)
        if args.reference:
            failed += not _guarded(name, args.debug, partial(_check_reference, model))
        if args.deep:
            failed += not _guarded(name, args.debug, partial(_analyze, model))
    stubs = _stubs(args.stubs) if args.stubs and trees else {}
    failed += stubs is None
    paired: dict[str, Model] = {}  # models named by trees or --model, loaded once each
    for tree in trees:
        against = _models_of(tree, args, models, paired)
        failed += against is None or not _guarded(tree, args.debug,
                                                  partial(_check_tree_file, tree, against, stubs or {}))
    if len(names) > 1 and (failed or len(names) > len(args.models)):  # a tally where one helps
        print(f"{plural(len(names), 'file')} checked, {failed} failed", file=sys.stderr if failed else sys.stdout)
    return 1 if failed else 0


def _analyze(model: Model) -> bool:
    """``--deep``: the model's analysis (:mod:`sm_bt.analysis`); False when it found an error."""
    from sm_bt.analysis import analyze
    from sm_bt.cli.analyze import print_analysis

    analysis = analyze(model)
    print_analysis(analysis)
    return not analysis.errors


def _check_reference(model: Model) -> bool:
    """Print what the reference would misread in ``model``; whether it reads it all."""
    from sm_bt.model.reference_compat import reference_issues

    issues = reference_issues(Path(model.path).read_text(encoding="utf-8"), model.path)
    errors = [issue for issue in issues if issue.severity is Severity.ERROR]
    print_issues(issues, sys.stderr if errors else sys.stdout)
    if errors:
        print(f"{model.path}: the reference cannot read it ({plural(len(errors), 'construct')})", file=sys.stderr)
    else:
        print(f"{model.path}: the reference reads it" + (f" ({plural(len(issues), 'difference')} in what it does)"
                                                         if issues else ""))
    return not errors


def _models_of(tree: str, args: argparse.Namespace, given: list[tuple[str, Model]],
               paired: dict[str, Model]) -> list[tuple[str, Model]] | None:
    """The models ``tree`` is checked against: the one it names, else ``--model``, else every one
    given; ``None`` (said why) when the one it names or ``--model`` does not load."""
    try:
        text = Path(tree).read_text(encoding="utf-8", errors="replace")
    except OSError:
        text = ""  # check_tree says what is wrong with the file
    named = DECLARED_MODEL.search(text)
    if named:
        name = named[1] if named[1] in bundled_names() else str(Path(tree).parent / named[1])
    elif args.model:
        name = args.model
    else:
        return given
    if name not in paired:
        model = load_or_report(name, strict=not args.lenient)
        if model is None:
            print(f"{tree}: failed (its model {name} does not load)", file=sys.stderr)
            return None
        paired[name] = model
    return [(name, paired[name])]


def _stubs(path: str) -> dict[str, Stub] | None:
    """The stubs of ``path``, or ``None`` after saying what is wrong with it."""
    from sm_bt.trees.stubs import load_stubs

    stubs, issues = load_stubs(path)
    if issues:
        report_failed(path, issues)
        return None
    return stubs


def _check_scenario(path: str, lenient: bool) -> bool:
    """Check a scenario against the model it names (with its world), and the tree and stubs it
    names; print what was found."""
    from sm_bt.scenario import load_scenario, load_world, scenario_setup

    setup, setup_issues = scenario_setup(path)
    if setup_issues or "model" not in setup:
        report_failed(path, [*setup_issues, *([] if "model" in setup else
                                              [f"{path}: name the model it runs with (model: ...)"])])
        return False
    model = load_or_report(setup["model"], strict=not lenient)
    if model is None:
        print(f"{path}: failed (its model {setup['model']} does not load)", file=sys.stderr)
        return False
    events = None
    if "world" in setup:
        try:
            events = load_world(setup["world"]).events
        except ValueError as error:
            report_failed(path, [f"{path}: {error}"])
            return False
    scenario, issues = load_scenario(path, model, events)
    ok = not issues
    if issues:
        report_failed(path, issues)
    else:
        print(f"{path}: ok (scenario: {plural(len(scenario.events), 'event')}, "
              f"{plural(len(scenario.expectations), 'expectation')}, against {setup['model']})")
    stubs = _stubs(setup["stubs"]) if "stubs" in setup else {}
    if stubs is None:
        return False
    if "tree" in setup:
        ok = _check_tree_file(setup["tree"], [(setup["model"], model)], stubs) and ok
    return ok


def _check_tree_file(tree: str, models: list[tuple[str, Model]], stubs: dict[str, Stub]) -> bool:
    """Check ``tree`` against each of ``models`` (or alone, without one); print what was found."""
    from sm_bt.trees.mission_xml import check_tree

    shipped_nodes()

    against: list[tuple[str, Model | None]] = list(models) or [("", None)]
    ok = True
    for name, model in against:
        issues = check_tree(tree, model, stubs=stubs)
        for issue in issues:
            print(f"{issue} [against {name}]" if len(against) > 1 else issue, file=sys.stderr)
        ok = ok and not issues
        if issues:
            print(f"{tree}: failed ({plural(len(issues), 'error')}" + (f" against {name})" if name else ")"),
                  file=sys.stderr)
        else:
            print(f"{tree}: ok" + (f" against {name}" if name else " (no model given: parts and modes not checked)"))
    return ok


T = TypeVar("T")


def _guarded(name: str, debug: bool, check: Callable[[], T]) -> T | None:
    """``check()``, or ``None`` after reporting an internal error (a bug) for ``name``, so that the
    other files are still checked."""
    try:
        return check()
    except Exception as error:  # a bug in sm-bt: say so, and go on with the next file
        print(f"{name}: internal error: {type(error).__name__}: {error} (this is a bug in sm-bt: please report it "
              "with this file" + ("" if debug else "; --debug shows the traceback") + ")", file=sys.stderr)
        if debug:
            traceback.print_exc(file=sys.stderr)
        return None
