"""``sm-bt analyze MODEL [TREE.xml ...]``: the flaws of a well-formed model (:mod:`sm_bt.analysis`).

Prints each finding as ``FILE:LINE: LEVEL: MESSAGE [KIND]`` with an example under it, then the
table of fault runs (with ``--table``), then a tally. ``--json`` prints everything as one JSON
object instead. Exit status 1 when there is an error-level finding (or a file does not load)."""

from __future__ import annotations

import argparse
import json
import sys

from sm_bt.analysis import Analysis, Level, analyze
from sm_bt.cli.common import add_lenient, bundled_names, load_or_report, plural, shipped_nodes
from sm_bt.trees.mission_xml import check_tree


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL",
                        help="a model file, or the name of a bundled model (" + ", ".join(bundled_names()) + ")")
    parser.add_argument("trees", nargs="*", metavar="TREE.xml", help="mission trees that use the model")
    parser.add_argument("--faults", type=int, choices=(0, 1, 2), default=1,
                        help="node faults per run: every single one (1, the default), every pair (2), none (0)")
    parser.add_argument("--table", action="store_true",
                        help="print the plans from each start to each mode of the top systems, and every fault "
                             "run's outcome, too")
    parser.add_argument("--json", action="store_true", help="print the findings and the runs as JSON")
    add_lenient(parser)


def run(args: argparse.Namespace) -> int:
    model = load_or_report(args.model, strict=not args.lenient)
    if model is None:
        return 1
    shipped_nodes()
    issues = [issue for tree in args.trees for issue in check_tree(tree, model=model)]
    if issues:  # the analysis reads trees that load
        for issue in issues:
            print(issue, file=sys.stderr)
        return 1
    analysis = analyze(model, args.trees, faults=args.faults)
    if args.json:
        print(json.dumps(analysis.as_json(), indent=2))
    else:
        print_analysis(analysis, table=args.table)
    return 1 if analysis.errors else 0


def print_analysis(analysis: Analysis, *, table: bool = False) -> None:
    for finding in analysis.findings:
        print(finding)
    if table and analysis.routes:
        print("plans:")
        for start, system, mode, plan in analysis.routes:
            print(f"  from {start}: change_mode {system} {mode}: "
                  + (f"{plan} calls" if isinstance(plan, int) else f"cannot be made: {plan}"))
    if table and analysis.outcomes:
        print("fault runs:")
        for outcome in analysis.outcomes:
            print(f"  {outcome.line()}")
    counts = {level: sum(1 for f in analysis.findings if f.level is level) for level in Level}
    runs = f"; {plural(len(analysis.outcomes), 'fault run')}" if analysis.outcomes else ""
    print(f"{analysis.model.path}: {plural(counts[Level.ERROR], 'error')}, {plural(counts[Level.WARNING], 'warning')}, "
          f"{plural(counts[Level.NOTE], 'note')}{runs}")
