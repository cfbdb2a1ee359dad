"""``sm-bt test SCENARIO...``: run each scenario with the model, tree and stubs it names, and judge it.

A scenario file names what it runs (``model: pilot``, ``tree: mission.xml``, ``stubs:
stubs.yaml``, relative to the scenario's own file; ``until: SECONDS``, default 600) besides its
``events`` and ``expect`` (:mod:`sm_bt.scenario`). Each runs on simulated nodes as fast as
possible, or with ``--ros`` on ROS 2 in real time (``sm-bt run --ros``); one line per scenario,
each failed expectation below it, then a tally, as pytest prints
them. ``--junit FILE`` writes JUnit XML for a team's CI; the recording of a failed scenario's run is
kept in ``--runs DIR`` for ``sm-bt view``. Exit 0 when every scenario passed.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import tempfile
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from sm_bt.cli.common import CliError, UsageError, load, shipped_nodes
from sm_bt.cli.run import add_ros_arguments
from sm_bt.model.errors import ModelError

#: How long a scenario runs at most when it does not say (seconds of the run).
UNTIL = 600.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenarios", nargs="+", metavar="SCENARIO", help="scenario files (YAML)")
    parser.add_argument("--junit", metavar="FILE", help="also write the results as JUnit XML to FILE")
    parser.add_argument("--runs", metavar="DIR", default="sm-bt-test-runs",
                        help="where the recording of each failed scenario is kept, for sm-bt view "
                             "(default ./sm-bt-test-runs)")
    add_ros_arguments(parser)


@dataclass
class Outcome:
    """One scenario's result: its failures (empty when it passed), how many expectations held."""

    path: str
    failures: list[str] = field(default_factory=list)
    held: int = 0
    seconds: float = 0.0  # wall time
    summary: str = ""
    recording: str = ""  # kept when it failed
    failed_at: float = 0.0  # the run's time of its first failure

    @property
    def passed(self) -> bool:
        return not self.failures


def run(args: argparse.Namespace) -> int:
    if args.attach and not args.ros:
        raise UsageError("--attach goes with --ros (it manages real nodes over ROS 2)")
    began = time.monotonic()
    outcomes = [_one(path, Path(args.runs), ros=args.ros, attach=args.attach) for path in args.scenarios]
    for outcome in outcomes:
        print(f"{'PASSED' if outcome.passed else 'FAILED'} {outcome.path}: {outcome.summary}")
        for failure in outcome.failures:
            print(f"  {failure}")
        if outcome.recording:
            print(f"  the run: sm-bt view {outcome.recording} --at {outcome.failed_at:.1f}")
    passed = sum(outcome.passed for outcome in outcomes)
    failed = len(outcomes) - passed
    print(f"{passed} passed, {failed} failed in {time.monotonic() - began:.2f} s")
    if args.junit:
        _junit(outcomes, args.junit)
    return 1 if failed else 0


def _one(path: str, runs: Path, *, ros: bool = False, attach: bool = False) -> Outcome:
    from sm_bt.cli.run import mission_system, ticked
    from sm_bt.scenario import Checks, SimulatedWorld, load_scenario, load_world, scenario_setup
    from sm_bt.trees.mission_xml import TreeFileError, load_tree
    from sm_bt.trees.stubs import load_stubs
    from sm_bt.view import attach_view

    outcome = Outcome(path)
    began = time.monotonic()
    setup, issues = scenario_setup(path)
    missing = [name for name in ("model", "tree") if name not in setup]
    if issues or missing:
        outcome.failures = [str(issue) for issue in issues] + [f"{path}: name the {name} to run it with ({name}: ...)"
                                                                for name in missing]
        outcome.summary = "cannot run it"
        return outcome
    try:
        model = load(setup["model"])
    except (ModelError, CliError) as error:
        outcome.failures, outcome.summary = [f"the model {setup['model']}: {error}"], "cannot run it"
        return outcome
    world: SimulatedWorld | None = None
    if "world" in setup:
        try:
            world = load_world(setup["world"])
        except ValueError as error:
            outcome.failures, outcome.summary = [f"{path}: {error}"], "cannot run it"
            return outcome
    stubs, stub_issues = load_stubs(setup["stubs"]) if "stubs" in setup else ({}, [])
    scenario, scenario_issues = load_scenario(path, model, world.events if world is not None else None)
    if stub_issues or scenario_issues:
        outcome.failures = [str(issue) for issue in (*stub_issues, *scenario_issues)]
        outcome.summary = "cannot run it"
        return outcome
    until = float(setup.get("until", UNTIL))
    with mission_system(model, setup["model"], ros=ros, attach=attach, scenario=scenario,
                        say=lambda line: None) as system:
        shipped_nodes()
        try:
            root = load_tree(setup["tree"], manager=system.manager, stubs=stubs)
        except TreeFileError as error:
            outcome.failures, outcome.summary = [str(issue) for issue in error.issues], "cannot run it"
            return outcome
        tree = system.tree(root, **(world.attach(system) if world is not None else {}))
        with tempfile.TemporaryDirectory(prefix="sm-bt-test-") as scratch:
            recording = Path(scratch) / (Path(path).stem + ".jsonl")
            view = attach_view(tree, system.manager, port=None, record=recording)
            checks = Checks(scenario, system, world, on_failure=lambda text: view.note("expectation", text))
            try:
                with contextlib.redirect_stderr(io.StringIO()):
                    status = ticked(system, tree, rate=10.0, speed=0.0, until=until, checks=checks, narrate=False,
                                    world=world)
                checks.end(str(status.value), system.clock.now())
            finally:
                view.close()
            outcome.failures, outcome.held = list(checks.failures), len(checks.passed)
            if outcome.failures:  # kept; a passed scenario's run leaves nothing behind
                runs.mkdir(parents=True, exist_ok=True)
                outcome.recording = str(shutil.move(recording, runs / recording.name))
                outcome.failed_at = checks.first_failure_at or 0.0
        outcome.summary = (f"{outcome.held} of {outcome.held + len(outcome.failures)} expectations held; the tree "
                           f"{status.value} at {system.clock.now():.2f} s")
    outcome.seconds = time.monotonic() - began
    return outcome


def _junit(outcomes: list[Outcome], path: str) -> None:
    suite = ET.Element("testsuite", name="sm-bt test", tests=str(len(outcomes)),
                       failures=str(sum(not outcome.passed for outcome in outcomes)),
                       time=f"{sum(outcome.seconds for outcome in outcomes):.3f}")
    for outcome in outcomes:
        case = ET.SubElement(suite, "testcase", classname="scenario", name=outcome.path, time=f"{outcome.seconds:.3f}")
        if not outcome.passed:
            failure = ET.SubElement(case, "failure", message=outcome.failures[0])
            failure.text = "\n".join(outcome.failures)
    Path(path).write_text(ET.tostring(suite, encoding="unicode") + "\n", encoding="utf-8")
