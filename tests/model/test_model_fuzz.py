"""The loader against fuzzed model files: every input is a Model or a ModelError with real lines.

Two hypothesis campaigns (strategies and oracle in ``model_fuzz``): SMH-shaped documents with
structural damage, and byte-level mutations of the shipped and fixture models. ``make test``
runs 500 documents and 1,500 mutated files (a document costs ten times a mutation); ``make stress``
50,000 of each and prints the counts by outcome. A crash found here is kept as a plain regression
test in ``test_model_robustness.py`` with its smallest input.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import given
from hypothesis_profiles import examples
from model_fuzz import (
    OUTCOMES,
    VALID_MODELS,
    Alias,
    Map,
    Node,
    Scalar,
    Seq,
    check_load,
    emit,
    mutated_models,
    smh_documents,
    summary,
)

from sm_bt.model import load_model_text

DOCUMENTS, MUTATIONS = 250, 750  # files of each campaign in `make test`; 50,000 each in `make stress`

#: The campaigns that ran in this process (the tally is the process's: run alone, or where a worker
#: did not get the whole module, the test of what they reached runs what is missing).
CAMPAIGNS_RUN: set[str] = set()


@pytest.fixture(scope="module")
def target(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz") / "fuzzed.yaml"


@examples(DOCUMENTS, stress=50_000)
@given(data=smh_documents())
def test_structured_documents_load_or_raise_model_error(target: Path, data: bytes) -> None:
    check_load(data, target)
    CAMPAIGNS_RUN.add("structured")


@examples(MUTATIONS, stress=50_000)
@given(data=mutated_models())
def test_mutated_models_load_or_raise_model_error(target: Path, data: bytes) -> None:
    check_load(data, target)
    CAMPAIGNS_RUN.add("mutated")


@examples(50)
@given(tree=VALID_MODELS)
def test_valid_models_written_by_the_fuzzer_load(tree: Node) -> None:
    """The structured campaign's starting points are valid: damage is what breaks them."""
    load_model_text(emit(tree), "valid.yaml")


def test_the_campaigns_reach_every_outcome(target: Path) -> None:
    """A fuzzer that only ever produced syntax errors would prove little: both campaigns together
    produce models, models with warnings and many kinds of ModelError."""
    # Alone, or in a worker that did not run both: run the missing campaigns first.
    if "structured" not in CAMPAIGNS_RUN:
        test_structured_documents_load_or_raise_model_error(target)
    if "mutated" not in CAMPAIGNS_RUN:
        test_mutated_models_load_or_raise_model_error(target)
    print(summary())
    assert OUTCOMES["crash"] == 0
    assert OUTCOMES["model"] > 0 and OUTCOMES["model with warnings"] > 0
    kinds = [kind for kind in OUTCOMES if kind.startswith("error: ")]
    assert len(kinds) >= 20, sorted(kinds)
    assert any("YAML syntax error" in kind for kind in kinds) and any("not UTF-N" in kind for kind in kinds)


# -- the writer of the structured campaign, checked against PyYAML ---------------------------------------


def test_emit_writes_yaml_that_reads_back_as_the_tree() -> None:
    tree = Map([(Scalar("a"), Map([(Scalar("type"), Scalar("node")),
                                   (Scalar("parts"), Scalar("x y", style="lines")),
                                   (Scalar("list"), Seq([Scalar("1"), Scalar("it's", style="single")])),
                                   (Scalar("flow"), Map([(Scalar("k"), Scalar("a: b"))], flow=True)),
                                   (Scalar("odd"), Scalar("\x00\n#", style="plain"))]))])
    assert yaml.safe_load(emit(tree)) == {"a": {"type": "node", "parts": "x y", "list": [1, "it's"],
                                                "flow": {"k": "a: b"}, "odd": "\x00\n#"}}


def test_emit_writes_anchors_aliases_and_tags() -> None:
    tree = Map([(Scalar("a"), Scalar("1", anchor="x", tag="!!str")), (Scalar("b"), Alias("x")),
                (Scalar("c"), Seq([Scalar("q")], anchor="y"))])
    assert emit(tree) == "a: &x !!str 1\nb: *x\nc: &y\n  - q\n"
    assert yaml.safe_load(emit(tree)) == {"a": "1", "b": "1", "c": ["q"]}
