"""``sm-bt mode ...`` and ``sm-bt state ...``, every example of the documentation, against the reference's
mode manager (micro-ROS/system_modes ``mode_manager``, C++): what a user sees.

The documentation says these commands work against the reference's manager too. This module holds them
to it with the real reference (built by ``tools/reference/build.sh``; ``SM_BT_REFERENCE`` names its
prefix, as ``make interop`` sets it) and the model's simulated nodes, both on the same
reference-compatible model file (:func:`reference.reference_model`: the model without its
``__order__`` lines). It is named ``interop_cli.py``, not ``test_*.py``, so ``make test`` leaves it
out (it needs the reference's build) and ``make interop`` runs it.

The examples are read from README.md and docs/, so a new one is covered as soon as it is written: every
``sm-bt mode ...``/``sm-bt state ...`` line of a ``sh`` block, and every such ``$`` command of a
``text`` transcript, whose output must then also match the lines below it (``…`` standing for
any text). Each runs on the model its block names (``run ros MODEL``), else the pilot, after the
bring-up a user does first (``state set SYSTEM configure --wait``, then ``activate --wait``; a
documented line that is one of these is run as that step), state commands first, then the others in
the pages' order (a transcript in one piece, as written). What each must print follows from the
model and from what the commands before it confirmed: exit 0 and the confirmation line for a
``--wait``, the mode or state confirmed last for a ``get``, the model's modes for a ``list``,
exit 2 with a name that is served for a name that is not.

Where the reference is wrong, its failure is asserted as a user sees it: its ``change_mode``
only activates and deactivates parts (it never sends ``configure`` or ``cleanup``), so a system
mode that wants a configured part ``unconfigured`` (the pilot's ``f_degraded_mode``, for
laser_resender) is never reached. Such an example runs last, with ``--timeout 5``, and must exit
1 with ``not confirmed within 5 s: pilot is in mode ...`` after waiting those 5 s; every other
example must succeed.

Also checked, beyond the documented lines: ``state set`` with every transition on a node (through
its own service: the reference is not asked); on a system, through the reference,
``deactivate --wait`` then ``activate --wait``, after which the pilot is active again, in its
default mode (the reference's ``activate`` means ``__DEFAULT__``); and a node's mode set through
the reference (``mode set controller_server FAST --wait``): confirmed, and really applied to the
node's parameters.

Two races of the reference itself are kept out of the way, as a person at a shell would without
knowing (see :func:`start_reference_fixture` and :meth:`Running._ticked`): it takes its own
``mode_event`` of a node for the node being active, which is wrong when the node is not. So the
nodes start before the reference, and after a confirmed mode change the next command waits for
the reference's tick (1 s timer) that publishes it.

Every ROS process is stopped by its PID (the fixtures and :class:`reference.ReferenceManager` do
it); every command runs with a timeout (the CLI's own, default 10 s).
"""

from __future__ import annotations

import argparse
import re
import shlex
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from reference import ReferenceManager, reference_model
from ros_processes import DISCOVERY_TIMEOUT, NodeProcess, RosContext, Starter, remove_stale_shm_files, wait_until

from sm_bt import bundled
from sm_bt.cli import main
from sm_bt.cli.app import build_parser
from sm_bt.engine.lifecycle import REQUESTABLE_LABELS, TRANSITION_GOALS
from sm_bt.model import load_model
from sm_bt.model.states import State
from sm_bt.model.types import Model, NodePart, SystemPart

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[2]
#: The pages whose examples run here: the README, then the documentation (its generated report aside).
PAGES = [ROOT / "README.md", *sorted(path for path in (ROOT / "docs").rglob("*.md") if path.name != "interop.md")]
#: A block's ``sm-bt manager MODEL`` line names the model its examples run on.
MANAGER_LINE = re.compile(r"^sm-bt manager (\S+)")
FENCE = re.compile(r"^```(\w*)\s*$")
DIRECTIVE = re.compile(r"^<!-- readme-test: (.*) -->$")
#: A transcript's directive that names the model it runs on.
RUN_ROS = re.compile(r"run ros (\S+)")
#: The model of a block that names none: the CLI section's examples are the pilot's.
DEFAULT_MODEL = "pilot"
#: ``--timeout`` given to an example the reference cannot confirm: its wait ends then.
BEYOND_REFERENCE_TIMEOUT = 5
#: The examples the documentation has now (docs/cli.md): the ones found must include them, so that
#: a change of the pages' format cannot leave this module checking nothing.
DOCUMENTED = frozenset({
    "sm-bt mode get pilot",
    "sm-bt mode list pilot",
    "sm-bt mode set pilot f_degraded_mode --wait",
    "sm-bt state set pilot configure --wait",
    "sm-bt mode set pilot f_nrmal_mode",
    "sm-bt mode set pilot f_normal_mode --wait",
})
#: The one example the reference gets wrong (see the module's docstring).
DOCUMENTED_BEYOND_REFERENCE = frozenset({"sm-bt mode set pilot f_degraded_mode --wait"})
#: The bring-up of a system, in order (docs/cli.md's ``state set pilot configure --wait`` is the first).
BRING_UP = ("configure", "activate")
#: The reference publishes what it infers on its 1 s timer: the longest wait for that tick.
TICK_TIMEOUT = 3.0
LOG_TAIL = 30


# -- the documentation's examples ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Example:
    """One ``sm-bt mode``/``sm-bt state`` command of the documentation."""

    page: Path
    line: int  # 1-based
    argv: tuple[str, ...]  # without the leading "sm-bt"
    model: str  # a bundled model's name or a path from the repository's root
    block: int  # the line of its block's opening fence
    #: The output below a transcript's command (``…``: any text); ``None`` for a line of a ``sh`` block.
    transcript: tuple[str, ...] | None = None

    @property
    def command(self) -> str:
        return shlex.join(("sm-bt", *self.argv))

    def __str__(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}: {self.command}"


def _is_example(argv: Sequence[str]) -> bool:
    return len(argv) > 2 and argv[0] == "sm-bt" and argv[1] in ("mode", "state")


def documented_examples() -> list[Example]:
    """Every ``sm-bt mode``/``sm-bt state`` command of the pages' ``sh`` and ``text`` blocks, in order."""
    return [example for page in PAGES for example in page_examples(page)]


def page_examples(page: Path) -> list[Example]:
    """The examples of one page: each on the model its block names (``run ros MODEL``, or an
    ``sm-bt manager MODEL`` line in it), else the pilot."""
    lines = page.read_text(encoding="utf-8").splitlines()
    examples: list[Example] = []
    index = 0
    while index < len(lines):
        fence = FENCE.match(lines[index])
        if fence is None or not fence.group(1):
            index += 1
            continue
        end = next(at for at in range(index + 1, len(lines)) if lines[at].startswith("```"))
        directive = DIRECTIVE.match(lines[index - 1]) if index else None
        named = RUN_ROS.match(directive.group(1)) if directive else None
        body = lines[index + 1:end]
        served = next((found.group(1) for line in body if (found := MANAGER_LINE.match(line))
                       and not found.group(1).isupper()), None)  # MODEL: a placeholder, not a model
        model = named.group(1) if named else served or DEFAULT_MODEL
        if fence.group(1) == "sh":
            for offset, text in enumerate(body):
                argv = shlex.split(text, comments=True)
                if _is_example(argv):
                    examples.append(Example(page, index + 2 + offset, tuple(argv[1:]), model, index + 1))
        elif fence.group(1) == "text":
            for offset, text in enumerate(body):
                if not text.startswith("$ "):
                    continue
                argv = shlex.split(text[2:])
                if _is_example(argv):
                    following = body[offset + 1:]
                    output = following[:next((at for at, line in enumerate(following) if line.startswith("$ ")),
                                             len(following))]
                    examples.append(Example(page, index + 2 + offset, tuple(argv[1:]), model, index + 1,
                                            tuple(output)))
        index = end + 1
    return examples


def parse(argv: Sequence[str]) -> argparse.Namespace:
    """The CLI's own reading of ``argv``; a failure (not SystemExit) for one it refuses."""
    try:
        return build_parser().parse_args(list(argv))
    except SystemExit:
        raise AssertionError(f"sm-bt {shlex.join(argv)}: the CLI's parser refuses it") from None


def model_file(name: str) -> Path:
    """A model named in the documentation: a path from the repository's root, or a bundled model's name."""
    in_repository = ROOT / name
    return in_repository if in_repository.is_file() else bundled.resolve(name)


def beyond_reference(model: Model, argv: Sequence[str]) -> bool:
    """Is this a ``mode set SYSTEM MODE --wait`` the reference never confirms?

    Its ``change_mode`` sends only ``activate`` (to a part the mode wants active) and ``deactivate``
    (to every other part): a part the mode wants ``unconfigured`` (or ``finalized``) stays
    configured after the bring-up, so the mode is never reached."""
    args = parse(argv)
    if (args.command, args.action) != ("mode", "set") or not args.wait:
        return False
    system = model.parts.get(args.part)
    if not isinstance(system, SystemPart) or args.mode not in system.modes:
        return False
    return any(entry.target is not None and entry.target.state not in (State.ACTIVE, State.INACTIVE)
               for entry in system.modes[args.mode].entries.values())


@dataclass(frozen=True)
class CliStep:
    """A command to run: a documented example, or (``example`` ``None``) a step of the bring-up."""

    argv: tuple[str, ...]
    example: Example | None = None

    def __str__(self) -> str:
        return str(self.example) if self.example else f"(bring-up) {shlex.join(('sm-bt', *self.argv))}"


def plan(model: Model, examples: Sequence[Example]) -> list[CliStep]:
    """The order the examples of one model run in: the bring-up of every system they name (a
    documented line that is a bring-up step runs as that step), then the state commands, then the
    others in the pages' order (a transcript in one piece), those the reference cannot confirm last."""
    units: list[list[Example]] = []  # a sh line alone, a transcript's commands together
    for example in examples:
        if example.transcript is not None and units and (units[-1][0].page, units[-1][0].block) == \
                (example.page, example.block):
            units[-1].append(example)
        else:
            units.append([example])
    systems = list(dict.fromkeys(parse(example.argv).part.lstrip("/") for example in examples
                                 if isinstance(model.parts.get(parse(example.argv).part.lstrip("/")), SystemPart)))
    steps: list[CliStep] = []
    for system in systems:
        for transition in BRING_UP:
            argv = ("state", "set", system, transition, "--wait")
            readme = next((unit for unit in units if len(unit) == 1 and unit[0].transcript is None
                           and unit[0].argv == argv), None)
            if readme is not None:
                units.remove(readme)
            steps.append(CliStep(argv, readme[0] if readme else None))
    states = [unit for unit in units if all(example.argv[0] == "state" for example in unit)]
    beyond = [unit for unit in units if any(beyond_reference(model, example.argv) for example in unit)]
    others = [unit for unit in units if unit not in states and unit not in beyond]
    for unit in [*states, *others, *beyond]:
        steps.extend(CliStep(example.argv, example) for example in unit)
    return steps


def transcript_pattern(expected: Sequence[str]) -> re.Pattern[str]:
    """A transcript's output lines as a pattern: ``…`` is any text in a line, a line of only ``…``
    any number of lines."""
    pieces = [r"(?:[^\n]*\n)*" if line == "…" else ".*".join(map(re.escape, line.split("…"))) + r"\n"
              for line in expected]
    return re.compile("".join(pieces))


EXAMPLES = documented_examples()
DOCUMENTED_MODELS = sorted({example.model for example in EXAMPLES})


# -- running them against the reference ----------------------------------------------------------------


@dataclass
class Running:
    """The reference and the simulated nodes on one model, and what the commands so far confirmed
    (the reference's ``get_mode``/``get_state`` must answer it)."""

    model: Model
    reference: ReferenceManager
    nodes: NodeProcess
    capsys: pytest.CaptureFixture[str]
    #: The modes the reference published on each part's ``mode_event``, in order (its timer's ticks).
    published: dict[str, list[str]]
    states: dict[str, str] = field(default_factory=dict)
    modes: dict[str, str] = field(default_factory=dict)

    def log(self) -> str:
        return "\n".join(self.reference.stderr.splitlines()[-LOG_TAIL:])

    def run(self, step: CliStep) -> tuple[int, str, str]:
        """Run ``step`` as ``sm-bt`` would and check what it printed; (exit code, stdout, stderr)."""
        argv = list(step.argv)
        beyond = beyond_reference(self.model, argv)
        if beyond:
            argv += ["--timeout", str(BEYOND_REFERENCE_TIMEOUT)]
        args = parse(argv)
        started = time.monotonic()
        code = main(argv)
        took = time.monotonic() - started
        out, err = self.capsys.readouterr()
        where = (f"{step}{' --timeout ' + str(BEYOND_REFERENCE_TIMEOUT) if beyond else ''}: exit {code} after "
                 f"{took:.2f} s, stdout {out!r}, stderr {err!r}\nthe reference's log ends with:\n{self.log()}")
        if step.example is not None and step.example.transcript is not None:
            assert transcript_pattern(step.example.transcript).fullmatch(out + err), \
                f"not what {step.example.page.name} shows ({step.example.transcript}): {where}"
        part = args.part.lstrip("/")
        check: Callable[[argparse.Namespace, str, int, str, str, float, str], None] = {
            ("mode", "get"): self._mode_get, ("mode", "list"): self._mode_list, ("mode", "set"): self._mode_set,
            ("state", "get"): self._state_get, ("state", "set"): self._state_set}[args.command, args.action]
        if beyond:
            self._beyond(args, part, code, out, err, took, where)
        else:
            check(args, part, code, out, err, took, where)
        return code, out, err

    # -- what each command must print -----------------------------------------------------------------

    def _mode_get(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                  where: str) -> None:
        active = self.states.get(part, "active") == "active"  # not known: it may be
        expected = self.modes.get(part, "") if active else "(no mode: not active)"
        assert (code, err) == (0, ""), where
        if expected:
            assert out == f"{part}: {expected}\n", where
        else:
            assert re.fullmatch(rf"{re.escape(part)}: .+\n", out), where

    def _mode_list(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                   where: str) -> None:
        assert (code, err) == (0, ""), where
        assert sorted(out.splitlines()) == sorted(self.model.parts[part].modes), where

    def _mode_set(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                  where: str) -> None:
        served = list(self.model.parts[part].modes)
        if args.mode not in served:
            assert (code, out) == (2, ""), where
            said = re.fullmatch(rf"sm-bt mode: error: {re.escape(part)} has no mode {re.escape(repr(args.mode))} "
                                r"\((?:did you mean '(?P<close>[^']+)'\?|modes: (?P<all>.+))\)\n", err)
            assert said, where
            assert said["close"] in served if said["close"] else sorted(said["all"].split(", ")) == sorted(served), \
                where
            return
        if not args.wait:
            assert (code, out, err) == (0, f"{part}: change to {args.mode} accepted\n", ""), where
            self._forget(part)
            return
        assert (code, err) == (0, ""), where
        confirmed = re.fullmatch(rf"{re.escape(part)}: {re.escape(args.mode)} confirmed (\d+\.\d\d) s after "
                                 r"the request\n", out)
        assert confirmed and float(confirmed[1]) <= took, where
        self._forget(part)
        self._reached(part, State.ACTIVE, args.mode)
        self._ticked(part, args.mode)

    def _state_get(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                   where: str) -> None:
        assert (code, err) == (0, ""), where
        if part in self.states:
            assert out == f"{part}: {self.states[part]}\n", where
        else:
            assert re.fullmatch(rf"{re.escape(part)}: [a-z]+\n", out), where

    def _state_set(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                   where: str) -> None:
        if args.transition not in TRANSITION_GOALS:
            assert (code, out) == (2, ""), where
            assert err.startswith(f"sm-bt state: error: {args.transition!r} is not a transition ("), where
            return
        if not args.wait:
            assert (code, out, err) == (0, f"{part}: {args.transition} accepted\n", ""), where
            self._forget(part)
            return
        goal = TRANSITION_GOALS[args.transition]
        assert (code, err) == (0, ""), where
        # A forced transition of a node the manager manages: then what held once it had its say.
        held = rf"{re.escape(part)}: still {goal} \d+ s later\n" if args.force else ""
        confirmed = re.fullmatch(rf"{re.escape(part)}: {goal} (\d+\.\d\d) s after the request\n{held}", out)
        assert confirmed and float(confirmed[1]) <= took, where
        self._forget(part)
        system = self.model.parts[part]
        if isinstance(system, SystemPart) and goal == "active":  # the reference: activate is __DEFAULT__
            self._reached(part, State.ACTIVE, system.default_mode)
        elif isinstance(system, SystemPart):  # forwarded to every part
            for name in self._below(part):
                self.states[name] = goal
        self.states[part] = goal

    def _beyond(self, args: argparse.Namespace, part: str, code: int, out: str, err: str, took: float,
                where: str) -> None:
        """The documented failure: not confirmed within the timeout, saying where the part is."""
        assert (code, out) == (1, ""), where
        assert re.fullmatch(rf"sm-bt: error: not confirmed within {BEYOND_REFERENCE_TIMEOUT} s: {re.escape(part)} "
                            rf"is in mode '[^']*', not {re.escape(repr(args.mode))}\n", err), where
        assert took >= BEYOND_REFERENCE_TIMEOUT, where
        self._forget(part)

    # -- what the reference must answer next ----------------------------------------------------------

    def _ticked(self, part: str, mode: str) -> None:
        """Wait for the reference's tick that publishes ``mode`` on the part's ``mode_event`` (at most
        1 s after the change), as a person typing the next command would.

        Until that tick the reference has not taken its own message for the nodes whose parameters
        it just set: it infers their modes from the parameters whatever their state, publishes them
        on their ``mode_event``, hears itself and takes the nodes for active. A node deactivated
        before that tick (``mode set`` then at once ``state set ... deactivate``) is active to it
        for good, and the next ``activate`` is never confirmed (seen in 1 run of 8). The nodes'
        modes are published on the same tick as the system's, or earlier."""
        wait_until(lambda: self.published[part][-1:] == [mode], TICK_TIMEOUT,
                   f"the reference did not publish {part}'s mode {mode} on /{part}/mode_event (published: "
                   f"{self.published[part]})\n{self.log()}", poll=0.02)

    def _below(self, part: str) -> list[str]:
        found = self.model.parts[part]
        below = [] if isinstance(found, NodePart) else list(found.parts)
        return below + [name for child in below for name in self._below(child)]

    def _forget(self, part: str) -> None:
        """A change was asked of ``part``: its systems' modes and everything below it are no longer known."""
        for name in [part, *self._below(part)]:
            self.states.pop(name, None)
            self.modes.pop(name, None)
        for parent in self.model.parents(part):
            self._forget_up(parent)

    def _forget_up(self, system: str) -> None:
        self.states.pop(system, None)
        self.modes.pop(system, None)
        for parent in self.model.parents(system):
            self._forget_up(parent)

    def _reached(self, part: str, state: State, mode: str | None) -> None:
        """``part`` is confirmed in ``state`` (``mode``): so are its parts, by the mode's entries."""
        self.states[part] = state.label
        if state is not State.ACTIVE or mode is None:
            return
        self.modes[part] = mode
        system = self.model.parts[part]
        if isinstance(system, SystemPart):
            for name, entry in system.modes[mode].entries.items():
                if entry.target is not None:
                    self._reached(name, entry.target.state, entry.target.mode)


@pytest.fixture(name="start_reference")
def start_reference_fixture(node_processes: Starter, ros_context: RosContext, capsys: pytest.CaptureFixture[str],
                            tmp_path: Path) -> Iterator[Callable[[str], Running]]:
    """``start(model)``: the model's simulated nodes, then the reference's manager, on the model as the
    reference reads it; the reference is stopped by PID at teardown (the nodes by ``node_processes``).

    The nodes come first, as on a robot whose nodes run before its manager: the reference then
    misses the parameters they declare at their start. Started the other way round, it may hear
    them, and at its next 1 s tick it infers each node's mode from them (``active.__DEFAULT__``,
    whatever the node's state), publishes that on the node's ``mode_event``, hears its own
    message and takes the node for active. When that tick falls after ``configure``, the nodes
    stay "active" to it and ``activate`` (its ``__DEFAULT__``: all parts inactive) is never
    confirmed: seen in 1 run of 5. That is the reference's fault, not the CLI's."""
    started: list[ReferenceManager] = []

    def start(name: str) -> Running:
        path = reference_model(str(model_file(name)), tmp_path)
        nodes = node_processes(str(path))
        reference = ReferenceManager(path)
        started.append(reference)  # before start(): one that never serves is stopped too
        reference.start()
        from system_modes_msgs.msg import ModeEvent

        model = load_model(path)
        published: dict[str, list[str]] = {part: [] for part in model.parts}
        subscriptions = [ros_context.node.create_subscription(
            ModeEvent, f"/{part}/mode_event", lambda event, part=part: published[part].append(event.goal_mode.label),
            10) for part in model.parts]
        wait_until(lambda: all(subscription.get_publisher_count() for subscription in subscriptions),
                   DISCOVERY_TIMEOUT, "the reference's mode_event publishers not discovered")
        return Running(model, reference, nodes, capsys, published)

    yield start
    for reference in started:
        reference.stop()
    remove_stale_shm_files()


def bring_up(running: Running, system: str) -> None:
    for transition in BRING_UP:
        running.run(CliStep(("state", "set", system, transition, "--wait")))


# -- the tests -----------------------------------------------------------------------------------------


def test_the_documentation_has_mode_and_state_examples_and_each_runs_on_a_model_that_has_its_part() -> None:
    commands = {example.command for example in EXAMPLES}
    assert commands, "the documentation has no `sm-bt mode`/`sm-bt state` example"
    assert commands >= DOCUMENTED, f"not found in the documentation: {sorted(DOCUMENTED - commands)}"
    transcript = {example.command for example in EXAMPLES if example.transcript is not None}
    # Read as a transcript's commands, so that what they print is compared with the page too.
    assert transcript >= {"sm-bt mode set pilot f_nrmal_mode", "sm-bt mode set pilot f_normal_mode --wait"}
    for name in DOCUMENTED_MODELS:
        model = load_model(model_file(name))
        examples = [example for example in EXAMPLES if example.model == name]
        for example in examples:
            assert parse(example.argv).part.lstrip("/") in model.parts, f"{example}: not a part of {name}"
        steps = plan(model, examples)
        assert sorted((step.example.page, step.example.line) for step in steps if step.example) == \
            sorted((e.page, e.line) for e in examples), name
        assert all(step.argv[:2] == ("state", "set") for step in steps[:len(BRING_UP)]), steps
    beyond = {example.command for example in EXAMPLES
              if beyond_reference(load_model(model_file(example.model)), example.argv)}
    assert beyond == DOCUMENTED_BEYOND_REFERENCE, "a new example the reference cannot confirm: is that right?"


@pytest.mark.long
@pytest.mark.parametrize("name", DOCUMENTED_MODELS)
def test_every_documented_example_does_against_the_reference_what_its_page_says(
        name: str, start_reference: Callable[[str], Running]) -> None:
    running = start_reference(name)
    steps = plan(running.model, [example for example in EXAMPLES if example.model == name])
    for step in steps:
        running.run(step)


def test_state_set_takes_a_node_through_every_transition_by_its_own_service_next_to_the_reference(
        start_reference: Callable[[str], Running]) -> None:
    running = start_reference("pilot")
    outputs = [running.run(CliStep(("state", "set", "controller_server", transition, "--wait", "--force")))[1]
               for transition in REQUESTABLE_LABELS]
    # Each line says the state the node's own get_state answers once the transition is done.
    assert [output.split()[1] for output in outputs] == ["inactive", "active", "inactive", "unconfigured",
                                                         "finalized"], outputs
    asked = [line for line in running.reference.stderr.splitlines() if "changing state of controller_server" in line]
    assert not asked, f"the reference was asked instead of the node: {asked}"


def test_a_system_deactivated_and_activated_through_the_reference_is_active_again_in_its_default_mode(
        start_reference: Callable[[str], Running]) -> None:
    running = start_reference("pilot")
    bring_up(running, "pilot")
    running.run(CliStep(("mode", "set", "pilot", "f_normal_mode", "--wait")))  # amcl and others active
    running.run(CliStep(("state", "set", "pilot", "deactivate", "--wait")))
    assert running.run(CliStep(("state", "get", "amcl")))[1] == "amcl: inactive\n"  # the node itself went down
    running.run(CliStep(("state", "set", "pilot", "activate", "--wait")))
    assert running.run(CliStep(("state", "get", "pilot")))[1] == "pilot: active\n"
    assert running.run(CliStep(("mode", "get", "pilot")))[1] == "pilot: __DEFAULT__\n"


def test_a_node_mode_set_through_the_reference_is_confirmed_and_applied_to_the_node(
        start_reference: Callable[[str], Running], ros_context: RosContext) -> None:
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    running = start_reference("pilot")
    bring_up(running, "pilot")
    running.run(CliStep(("mode", "set", "pilot", "f_normal_mode", "--wait")))  # controller_server active
    running.run(CliStep(("mode", "set", "controller_server", "FAST", "--wait")))
    assert any("changing mode of controller_server to FAST" in line
               for line in running.reference.stderr.splitlines()), running.log()
    assert running.run(CliStep(("mode", "get", "controller_server")))[1] == "controller_server: FAST\n"
    controller = running.model.parts["controller_server"]
    assert isinstance(controller, NodePart)
    wanted: dict[str, Any] = controller.modes["FAST"].values()
    response = ros_context.call(GetParameters, "/controller_server/get_parameters",
                                GetParameters.Request(names=list(wanted)))
    assert dict(zip(wanted, map(parameter_value_to_python, response.values), strict=True)) == wanted
