"""``sm-bt plan MODEL PART MODE``: what a change would do, from a configuration given, offline.

Prints the preview (:mod:`sm_bt.engine.preview`) of asking for MODE (or a lifecycle transition)
of PART: the stages, each node's calls and parameter changes, the rules that would start or stop
firing, or why the change could not be made. ``--from`` says where the nodes are: ``unconfigured``
(the default), ``inactive`` or ``active`` for all of them, or parts' targets
(``pilot=active.f_normal_mode``), whose nodes are where those targets put them (the others
unconfigured). Exit status 0 when the change could be made, 1 when not, 2 for a name the model
does not have.
"""

from __future__ import annotations

import argparse
import json

from sm_bt.cli.common import UsageError, load_or_report
from sm_bt.model.errors import RequestError
from sm_bt.model.states import State, StateMode
from sm_bt.model.types import Model

ALL = {"unconfigured": State.UNCONFIGURED, "inactive": State.INACTIVE, "active": State.ACTIVE}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL", help="model file, or a bundled model's name")
    parser.add_argument("part", metavar="PART", help="a system or node of the model")
    parser.add_argument("value", metavar="MODE", help="one of the part's modes (or __DEFAULT__), or a lifecycle "
                                                      "transition (configure, activate, deactivate, cleanup, shutdown)")
    parser.add_argument("--from", dest="start", default="unconfigured", metavar="WHERE",
                        help="where the nodes are: unconfigured (default), inactive or active for all of them, or "
                             "PART=STATE[.MODE],... (each part's nodes where that target puts them; the rest "
                             "unconfigured)")
    parser.add_argument("--json", action="store_true", help="print the preview as JSON")


def run(args: argparse.Namespace) -> int:
    from sm_bt.engine.lifecycle import REQUESTABLE_LABELS
    from sm_bt.engine.preview import configuration, nodes_of
    from sm_bt.sim import SimulatedSystem

    model = load_or_report(args.model, strict=True)
    if model is None:
        return 1
    start = _start(model, args.start)
    config = configuration(model, nodes_of(model, start)) if start else configuration(model, default=ALL[args.start])
    # A manager over simulated nodes that never run: only its names and its preview are used.
    with SimulatedSystem(model, record=False) as system:
        try:
            if args.value in REQUESTABLE_LABELS:
                preview = system.manager.preview_state(args.part, args.value, from_=config)
            else:
                preview = system.manager.preview(args.part, args.value, from_=config)
        except RequestError as error:
            raise UsageError(str(error)) from None
    if args.json:
        print(json.dumps(preview.as_json(), indent=2))
    else:
        print("\n".join(preview.lines()))
    return 0 if preview.possible else 1


def _start(model: Model, text: str) -> dict[str, StateMode]:
    """``--from``: {} for one of :data:`ALL`, else each PART=STATE[.MODE]."""
    if text in ALL:
        return {}
    from sm_bt.model.diagnostics import did_you_mean

    found: dict[str, StateMode] = {}
    for item in filter(None, (piece.strip() for piece in text.split(","))):
        part, equals, value = item.partition("=")
        if not equals:
            raise UsageError(f"--from {text!r}: name unconfigured, inactive, active (for every node), or "
                             f"PART=STATE[.MODE],...{did_you_mean(text, ALL)}")
        if part not in model.parts:
            raise UsageError(f"--from {item}: no part {part!r} in the model{did_you_mean(part, model.parts)}")
        try:
            found[part] = StateMode.parse(value)
        except ValueError as error:
            raise UsageError(f"--from {item}: {error}") from None
        mode = found[part].mode
        if mode is not None and mode not in model.parts[part].modes:
            raise UsageError(f"--from {item}: {part} has no mode {mode!r}")
    if not found:
        raise UsageError(f"--from {text!r}: name unconfigured, inactive, active (for every node), or "
                         "PART=STATE[.MODE],...")
    return found

