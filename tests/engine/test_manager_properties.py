"""Property-based tests of the mode manager over simulated nodes (issue 10, "How to prove it").

Hypothesis draws scenarios (see ``scenario.py``: models, options, timed requests and faults, a
tree of behaviours, a final request after healing) and every scenario must keep the invariants
I1-I8 stated there. ``make test`` runs a few hundred scenarios; ``make stress`` (the ``stress``
hypothesis profile) 25 times as many, over 11,000. A failure prints the scenario as Python:
shrink it (``SM_BT_HYPOTHESIS_PROFILE=shrink``) and keep it as a plain test in
``test_manager_regressions.py``.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis_profiles import examples
from model_generator import FIXED_MODELS, GeneratedModel, fixed_model, generated_models
from scenario import (
    Scenario,
    cascade_scenarios,
    check,
    fixed_models,
    hung_scenarios,
    random_models,
    scenarios,
)

from sm_bt.model.types import NodePart, SystemPart


@examples(30)
@given(generated_models())
def test_generated_models_load_strictly(generated: GeneratedModel) -> None:
    """Every generated model loads (strict) and has the shape the generator promises."""
    model = generated.load()
    assert 1 <= len(model.nodes) <= 8
    assert 1 <= len(model.systems) <= 7 and len(model.roots()) == 1
    assert all(1 <= len(n.modes) <= 3 for n in model.nodes if isinstance(n, NodePart))
    assert all(1 <= len(s.modes) <= 4 for s in model.systems if isinstance(s, SystemPart))
    if generated.cascade:
        rules = {rule.name: rule for system in model.systems for rule in system.rules}
        sub, parent = rules["cascade_sub"], rules["cascade_parent"]
        assert parent.if_part == sub.system and parent.if_part_state == sub.new_target


def test_fixed_models_load() -> None:
    for name in FIXED_MODELS:
        assert fixed_model(name).parts


@examples(150)
@given(scenarios(fixed_models()))
def test_scenarios_on_the_fixed_models(scenario: Scenario) -> None:
    """I1-I6 on the pilot, pilot_rules, actuation, nested and Nav2-like models, with every fault."""
    check(scenario)


@examples(80)
@given(scenarios(random_models()))
def test_scenarios_on_generated_models(scenario: Scenario) -> None:
    """I1-I6 on generated models (nested systems, rules, cascades, plain nodes), every fault."""
    check(scenario)


@examples(80)
@given(scenarios(fixed_models() | random_models(), movers=False))
def test_scenarios_where_only_the_manager_moves_nodes(scenario: Scenario) -> None:
    """I1-I6, I4 in particular: without triggers, outside parameter changes, crashes and restarts,
    no request fails because of a call the manager itself has in flight."""
    check(scenario)


@examples(60)
@given(scenarios(fixed_models() | random_models(), tree=True, max_steps=6))
def test_scenarios_with_a_tree_of_behaviours(scenario: Scenario) -> None:
    """I1-I7 with a py_trees tree of sm_bt behaviours (with timeouts) ticked every 0.1 s."""
    check(scenario)


@examples(60)
@given(cascade_scenarios())
def test_rules_cascade_through_nested_systems(scenario: Scenario) -> None:
    """I8 (and I1-I6): a sub-system's rule re-targets it; the parent's rule that reads the
    sub-system's mode reacts (issue 10, item 2)."""
    check(scenario)


@examples(30)
@given(hung_scenarios(fixed_models() | random_models()))
def test_recovery_gives_up_on_a_hung_node(scenario: Scenario) -> None:
    """I6 (and I1-I5): a node hung in a transition costs recovery its attempts; then recovery stops
    and the divergence is reported as an error (issue 10, item 3)."""
    check(scenario)
