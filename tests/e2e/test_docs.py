"""Every example in README.md and in the documentation's pages (docs/**/*.md) runs as written, so
none can rot.

Each fenced block is tested by its language and by the directive in an HTML comment on the line
before it (``<!-- readme-test: ... -->``, the same on every page, invisible on the rendered page):

- ``python``: the blocks of one page run in order in one namespace (as a reader pastes them into
  one session), on the simulated backend; ``ros``: run in a fresh interpreter with the pilot's simulated rclpy nodes
  up; ``pytest``: a test file of a user's own, run by pytest (every test in it must pass);
  ``compile (why)``: compiled only, for what needs software no package index has;
  ``py_trees_ros (why)``: compiled here, and run by ``make interop`` against py_trees_ros's
  sources (tests/interop/interop_py_trees_ros.py);
- ``yaml``: loaded as a model (strictly); ``file PATH``: the file holds exactly the block and
  loads; ``part of PATH``: the block's lines appear in that order in PATH, which loads;
- ``xml``: ``file PATH, checked against MODEL``: the file holds the block and checks clean;
- ``sh``: each line is ``make TARGET`` (a target of the Makefile) or an ``sm-bt`` command line
  that the CLI's parser accepts; ``skip (why)``: not run, with the reason;
- ``text``: ``run`` (or ``run ros MODEL``, with the model's nodes and ``sm-bt manager MODEL`` up): a
  shell transcript; each ``$ command`` is run from the repository's root with the environment's
  ``bin`` on ``PATH``, and its output (stdout and stderr as a terminal shows them) must match
  the lines below it, where ``…`` stands for any text within a line and a line of only ``…``
  for any number of lines; ``layout``: every path named exists.

A block with no test and no reason fails :func:`test_every_block_is_tested_or_says_why_not`.
A failure names the page and the line of the block's opening fence; a traceback from a Python
block gives the page's own line numbers.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest
from ros_processes import ManagerProcess, Starter

import sm_bt
from sm_bt.cli.app import build_parser
from sm_bt.scenario import load_scenario, scenario_setup
from sm_bt.trees.mission_xml import check_tree
from sm_bt.trees.stubs import load_stubs

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
#: Every page with examples: the front page, then the documentation's pages.
PAGES = (README, *sorted((ROOT / "docs").rglob("*.md")))
#: The front page stays a front page.
README_MAX_LINES = 300
BIN = Path(sys.executable).parent
DIRECTIVE = re.compile(r"^<!-- readme-test: (.*) -->$")
#: Directives each language accepts, with what they capture; a block without one uses "".
KINDS: dict[str, list[tuple[str, re.Pattern[str]]]] = {
    "python": [("run", re.compile(r"")), ("ros", re.compile(r"ros \(.+\)")),
               ("compile", re.compile(r"compile \(.+\)")), ("pytest", re.compile(r"pytest")),
               ("py_trees_ros", re.compile(r"py_trees_ros \(.+\)"))],
    "yaml": [("model", re.compile(r"")), ("file", re.compile(r"file (\S+)")),
             ("part", re.compile(r"part of (\S+)")), ("stubs", re.compile(r"stubs file (\S+)")),
             ("scenario", re.compile(r"scenario file (\S+)"))],
    "xml": [("tree", re.compile(r"file (\S+), checked against (\S+)")),
            ("dds profile", re.compile(r"fast dds profile, the one (\S+) uses"))],
    "sh": [("commands", re.compile(r"")), ("skip", re.compile(r"skip \(.+\)"))],
    "text": [("transcript", re.compile(r"run")), ("ros transcript", re.compile(r"run ros (\S+) \(.+\)")),
             ("layout", re.compile(r"layout"))],
}
TRANSCRIPT_TIMEOUT = 120.0


@dataclass(frozen=True)
class Block:
    page: str  # the page's path from the repository's root
    line: int  # of the opening fence, 1-based
    language: str
    text: str
    directive: str

    def __str__(self) -> str:
        return f"{self.page}:{self.line} ({self.language})"

    @property
    def code(self) -> str:
        """The block's text on the lines it has in its page (for tracebacks that name them)."""
        return "\n" * self.line + self.text

    @property
    def kind(self) -> tuple[str, tuple[str, ...]]:
        """(kind, captured values); ``ValueError`` for a directive the language does not take."""
        for kind, pattern in KINDS.get(self.language, []):
            match = pattern.fullmatch(self.directive)
            if match:
                return kind, match.groups()
        raise ValueError(f"{self}: no test for a {self.language or 'plain'} block with directive "
                         f"{self.directive!r} (see {Path(__file__).name} for what each language takes)")


@cache
def blocks() -> tuple[Block, ...]:
    return tuple(block for page in PAGES for block in page_blocks(page))


def page_blocks(path: Path) -> list[Block]:
    page = path.relative_to(ROOT).as_posix()
    lines = path.read_text(encoding="utf-8").splitlines()
    found: list[Block] = []
    index = 0
    while index < len(lines):
        if lines[index].startswith("```"):
            start = index
            end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("```")), None)
            assert end is not None, f"{page}:{start + 1}: a block that never ends"
            before = DIRECTIVE.match(lines[start - 1]) if start else None
            found.append(Block(page, start + 1, lines[start][3:].strip(), "\n".join(lines[start + 1:end]) + "\n",
                               before.group(1) if before else ""))
            index = end
        index += 1
    return found


def of_kind(*kinds: str) -> list[Block]:
    return [block for block in blocks() if block.language in KINDS and _kind_or_none(block) in kinds]


def _kind_or_none(block: Block) -> str | None:
    try:
        return block.kind[0]
    except ValueError:
        return None


def by_line(values: list[Block]) -> Callable[..., object]:
    return pytest.mark.parametrize("block", values, ids=[f"{block.page}:{block.line}" for block in values])


def test_every_block_is_tested_or_says_why_not() -> None:
    assert len(blocks()) >= 20  # the parser found the pages' blocks
    assert {block.page for block in blocks()} >= {"README.md", "docs/first-model.md", "docs/cli.md"}
    problems = []
    for block in blocks():
        try:
            block.kind  # noqa: B018 - raises for a block nothing tests
        except ValueError as error:
            problems.append(str(error))
    assert not problems, "\n".join(problems)


def test_the_readme_is_a_front_page() -> None:
    lines = len(README.read_text(encoding="utf-8").splitlines())
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines: move the details to a page of docs/"


# -- Python ---------------------------------------------------------------------------------------------


def _front_page_promises(namespace: dict[str, object], output: list[str]) -> None:
    assert "Status.SUCCESS active.FAST" in output


def _first_mission_promises(namespace: dict[str, object], output: list[str]) -> None:
    request = namespace["request"]
    assert isinstance(request, sm_bt.Request) and request.succeeded, request
    assert output.count("active.f_normal_mode") == 2
    assert "[]" in output  # no divergences


#: What the comments of a page's examples promise, beyond running.
PROMISES: dict[str, Callable[[dict[str, object], list[str]], None]] = {
    "README.md": _front_page_promises,
    "docs/first-mission.md": _first_mission_promises,
}
PYTHON_PAGES = list(dict.fromkeys(block.page for block in of_kind("run")))


@pytest.mark.parametrize("page", PYTHON_PAGES)
def test_python_examples_of_a_page_run_in_order_on_the_simulated_backend(
        page: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(ROOT)  # the examples name files relative to the repository, as a reader runs them
    namespace: dict[str, object] = {"__name__": "__docs__"}
    printed = io.StringIO()
    for block in of_kind("run"):
        if block.page == page:
            with contextlib.redirect_stdout(printed):
                exec(compile(block.code, block.page, "exec"), namespace)  # the page's own code
    PROMISES.get(page, lambda namespace, output: None)(namespace, printed.getvalue().splitlines())


def test_the_promises_are_of_pages_with_python_examples() -> None:
    assert set(PROMISES) <= set(PYTHON_PAGES)


@by_line(of_kind("pytest"))
def test_pytest_examples_pass_as_a_users_own_test_file(block: Block, tmp_path: Path) -> None:
    """Run as a user runs them: a test file of their own, pytest started from the repository (the
    example names the model relative to it), nothing of this suite's configuration, the plugin
    found through its entry point."""
    test_file = tmp_path / "test_docs_example.py"
    test_file.write_text(block.text, encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-c", os.devnull,
                           "--rootdir", str(tmp_path), str(test_file)], cwd=ROOT, capture_output=True, text=True,
                          timeout=TRANSCRIPT_TIMEOUT, check=False)
    tests = block.text.count("\ndef test_")
    assert done.returncode == 0 and f"{tests} passed" in done.stdout, f"{block} failed:\n{done.stdout}{done.stderr}"


@by_line(of_kind("compile", "py_trees_ros"))
def test_python_examples_that_need_other_software_compile(block: Block) -> None:
    compile(block.code, block.page, "exec")


@by_line(of_kind("ros"))
def test_ros_python_examples_run_against_the_simulated_rclpy_nodes(block: Block, node_processes: Starter) -> None:
    node_processes("pilot")
    done = subprocess.run([sys.executable, "-c", block.code], cwd=ROOT, capture_output=True, text=True,
                          timeout=TRANSCRIPT_TIMEOUT, check=False)
    assert done.returncode == 0, f"{block} failed:\n{done.stdout}{done.stderr}"
    assert "Normal: SUCCESS" in done.stdout, done.stdout


# -- models and trees -----------------------------------------------------------------------------------


@by_line(of_kind("model"))
def test_yaml_examples_load_as_models(block: Block, tmp_path: Path) -> None:
    path = tmp_path / "example.yaml"
    path.write_text(block.text, encoding="utf-8")
    sm_bt.load_model(path)


@by_line(of_kind("file"))
def test_yaml_examples_are_the_files_they_show_and_load(block: Block) -> None:
    (path,) = block.kind[1]
    assert (ROOT / path).read_text(encoding="utf-8") == block.text, f"{block} differs from {path}"
    sm_bt.load_model(ROOT / path)


@by_line(of_kind("stubs"))
def test_stubs_examples_are_the_files_they_show_and_read_clean(block: Block) -> None:
    (path,) = block.kind[1]
    assert (ROOT / path).read_text(encoding="utf-8") == block.text, f"{block} differs from {path}"
    assert load_stubs(ROOT / path)[1] == []


@by_line(of_kind("scenario"))
def test_scenario_examples_are_the_files_they_show_and_read_clean_against_their_model(block: Block) -> None:
    (path,) = block.kind[1]
    assert (ROOT / path).read_text(encoding="utf-8") == block.text, f"{block} differs from {path}"
    setup, issues = scenario_setup(ROOT / path)
    assert issues == [] and load_scenario(ROOT / path, sm_bt.load_model(sm_bt.models.path(setup["model"])))[1] == []


@by_line(of_kind("part"))
def test_yaml_fragments_are_parts_of_models_that_load(block: Block) -> None:
    (path,) = block.kind[1]
    remaining = iter((ROOT / path).read_text(encoding="utf-8").splitlines())
    missing = [line for line in block.text.splitlines() if not any(line == other for other in remaining)]
    assert not missing, f"{block}: not in {path} in this order: {missing}"
    sm_bt.load_model(ROOT / path)


@by_line(of_kind("tree"))
def test_xml_examples_are_the_files_they_show_and_check_clean(block: Block) -> None:
    path, model = block.kind[1]
    assert (ROOT / path).read_text(encoding="utf-8") == block.text, f"{block} differs from {path}"
    assert check_tree(ROOT / path, sm_bt.load_model(sm_bt.models.path(model))) == []


@by_line(of_kind("dds profile"))
def test_fast_dds_profiles_are_the_ones_the_tests_use(block: Block) -> None:
    """What the page advises is what the tests measured with: the block's writer settings are
    in the profile that the named module gives its processes."""
    (path,) = block.kind[1]
    import xml.etree.ElementTree as ElementTree

    namespace = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
    advised = ElementTree.fromstring(block.text.encode("utf-8")).find(f"{namespace}data_writer")
    assert advised is not None and advised.get("is_default_profile") == "true", f"{block}: no default data_writer"
    module = (ROOT / path).read_text(encoding="utf-8")
    used_text = re.search(r'FAST_DDS_PROFILE = """\\\n(.*?)"""', module, re.S)
    assert used_text is not None, f"{path} has no FAST_DDS_PROFILE"
    used = ElementTree.fromstring(used_text.group(1).encode("utf-8")).find(f"{namespace}data_writer")
    assert used is not None, f"{path}'s profile has no data_writer"
    times = f"{namespace}times"
    assert ElementTree.tostring(advised.find(times)) == ElementTree.tostring(used.find(times))


# -- shell ----------------------------------------------------------------------------------------------


def _make_targets() -> set[str]:
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    return {match.group(1) for match in re.finditer(r"^([\w.-]+):", makefile, re.M)}


@by_line(of_kind("commands"))
def test_shell_examples_name_make_targets_or_valid_sm_bt_command_lines(block: Block) -> None:
    parser = build_parser()
    for line in block.text.splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        if words[0] == "make":
            assert set(words[1:]) <= _make_targets(), f"{block}: {line!r}: no such make target"
        else:
            assert words[0] == "sm-bt", f"{block}: {line!r} is neither make nor sm-bt"
            try:
                parser.parse_args(words[1:])
            except SystemExit:
                pytest.fail(f"{block}: sm-bt does not accept {line!r}")


def matches(expected: list[str], actual: list[str]) -> bool:
    """``actual`` lines against ``expected`` ones with ``…`` wildcards (see the module's docstring)."""

    @cache
    def at(i: int, j: int) -> bool:
        if i == len(expected):
            return j == len(actual)
        if expected[i].strip() == "…":
            return any(at(i + 1, k) for k in range(j, len(actual) + 1))
        pattern = ".*".join(re.escape(part) for part in expected[i].split("…"))
        return j < len(actual) and re.fullmatch(pattern, actual[j]) is not None and at(i + 1, j + 1)

    return at(0, 0)


def run_transcript(block: Block) -> None:
    commands: list[tuple[str, list[str]]] = []
    for line in block.text.splitlines():
        if line.startswith("$ "):
            commands.append((line[2:], []))
        else:
            assert commands, f"{block}: output before the first command"
            commands[-1][1].append(line)
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}",
           "PYTHONUNBUFFERED": "1"}  # stdout and stderr in the order a terminal shows them
    env.pop("NO_COLOR", None)
    for command, expected in commands:
        if command.startswith("sm-bt demo") and "--speed" not in command:
            command += " --speed 0"  # unpaced: pacing changes only the wall time, which the pages leave out
        done = subprocess.run(["bash", "-c", command], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, timeout=TRANSCRIPT_TIMEOUT, check=False)
        actual = [line.rstrip() for line in done.stdout.splitlines()]
        assert matches(expected, actual), (f"{block}: `{command}` (exit {done.returncode}) printed\n"
                                           + "\n".join(actual) + f"\n\nand {block.page} shows\n" + "\n".join(expected))


@pytest.mark.long
@by_line(of_kind("transcript"))
def test_transcripts_print_what_the_page_shows(block: Block) -> None:
    run_transcript(block)


@by_line(of_kind("ros transcript"))
def test_ros_transcripts_print_what_the_page_shows(
        block: Block, start_manager: Callable[..., ManagerProcess], node_processes: Starter) -> None:
    (model,) = block.kind[1]
    manager = start_manager(model=model)
    node_processes(model)
    manager.ready()
    run_transcript(block)


@by_line(of_kind("layout"))
def test_the_layout_names_paths_that_exist(block: Block) -> None:
    named = [line.split()[0] for line in block.text.splitlines() if line and not line.startswith(" ")]
    assert len(named) >= 10
    assert [name for name in named if not (ROOT / name).exists()] == []


def test_the_wildcard_matcher_can_fail() -> None:
    assert matches(["a …", "…", "z"], ["a b", "c", "d", "z"])
    assert matches(["…"], [])
    assert not matches(["a …", "z"], ["a b", "c", "z"])
    assert not matches(["x"], ["x", "y"])
    assert not matches(["a.c"], ["abc"])  # no regular expressions in the pages' text
