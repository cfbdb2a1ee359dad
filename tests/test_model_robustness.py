"""Damaged files never escape as raw exceptions: they load, or raise ModelError with located issues."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from sm_bt.model import ModelError, load_model_text

FIXTURES = [Path(__file__).parent / "models" / name
            for name in ("loader_rules.yaml", "loader_defaultmode.yaml", "loader_namespaced.yaml",
                         "loader_nested.yaml")]
# Values that break the model in different layers: YAML syntax, rcl typing, structure, states.
REPLACEMENTS = ("", "[", "{}", "*a", "ACTIVE.X", "[1, 0.5]", "{a: [b]}")


def mutations(text: str) -> Iterator[tuple[str, str]]:
    lines = text.splitlines(keepends=True)
    for index, line in enumerate(lines):
        before, after = lines[:index], lines[index + 1:]
        yield f"delete line {index + 1}", "".join(before + after)
        yield f"dedent line {index + 1}", "".join([*before, line[2:] if line.startswith("  ") else line, *after])
        if ":" in line:
            key = line.split(":", 1)[0]
            for value in REPLACEMENTS:
                yield f"line {index + 1} value {value!r}", "".join([*before, f"{key}: {value}\n", *after])


@pytest.mark.parametrize("path", FIXTURES, ids=[p.name for p in FIXTURES])
def test_mutated_fixtures_load_or_raise_model_error(path: Path) -> None:
    line_count = path.read_text().count("\n")
    for label, text in mutations(path.read_text()):
        try:
            load_model_text(text, "mutated.yaml", strict=False)
        except ModelError as error:
            assert error.issues, label
            for issue in error.issues:
                assert 0 <= issue.location.line <= line_count + 1, (label, str(issue))
                assert issue.message, label
