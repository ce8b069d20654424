"""``softreach evaluate --starts certified``: the starts of the filter's guarantee, and the guarantee from them."""

from __future__ import annotations

import numpy as np
import pytest
from cell_plans import without_cells

from softreach.agents.evaluate import EvalSpec, evaluate
from softreach.filters import ValueFilter

#: the paper's proxy for a budget kept (spec §2, paper §VI-A: ``W_eps + 1e-3 <= 0``): one millisecond, in seconds
BUDGET_TOL = 1e-3


class BangBang:
    """Full thrust up or down, switching at random: it leaves the set from anywhere unless corrected."""

    name = "bang-bang"

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)

    def act(self, env, obs):
        return np.array([self.rng.choice([-1.0, 1.0])], dtype=np.float32)


@pytest.mark.parametrize("wind", ["adversarial", "random"])
def test_filtered_from_certified_starts_is_safe(pointmass_held_table, wind):
    path = str(pointmass_held_table.path)
    spec = dict(table=path, budget=0.3, wind=wind, episodes=6, starts="certified", seed=11)
    safe = evaluate(EvalSpec(policy="bang-bang", filter=path, **spec), policy_obj=BangBang(0))
    raw = evaluate(EvalSpec(policy="bang-bang", **spec), policy_obj=BangBang(0))
    vf = ValueFilter(pointmass_held_table, 0.01)
    starts = np.array([r["start_state"] for r in safe.episodes])
    assert vf.certify(0.0, starts, np.full(len(starts), 0.3))[0].all()
    assert [r["start_state"] for r in raw.episodes] == [r["start_state"] for r in safe.episodes]
    assert safe.aggregates["hard_violation_rate"]["count"] == 0
    assert safe.aggregates["budget_used"]["max"] <= 0.3 + BUDGET_TOL
    # the same starts are not safe by themselves: the filter did the work
    assert raw.aggregates["hard_violation_rate"]["count"] + raw.aggregates["over_budget_rate"]["count"] > 0


def test_certified_starts_need_cells(pointmass_table_path, monkeypatch):
    from softreach.reach import load_table

    # the point mass has cells, which certify whatever table ranks: a continuous-time table gives certified starts
    spec = EvalSpec(policy="random", table=str(pointmass_table_path), budget=0.3, episodes=2, starts="certified")
    starts = np.array([r["start_state"] for r in evaluate(spec).episodes])
    assert ValueFilter(load_table(pointmass_table_path), 0.01).certify(0.0, starts, 0.3)[0].all()
    # a model without cells has no certificate: refused, naming what to add
    without_cells(monkeypatch)
    with pytest.raises(ValueError, match=r"cell_shape = \(cells per state axis"):
        evaluate(spec)


def test_certified_starts_wrapper(pointmass_held_table):
    from softreach.agents.envs import make_env

    env = make_env("pointmass", filter_table=pointmass_held_table, certified_starts=True)
    starts = []
    for seed in range(5):
        _, info = env.reset(seed=seed)
        assert info["certified"], info["certified_reason"]
        starts.append(env.unwrapped.state.copy())
    assert len({tuple(s) for s in starts}) == 5  # drawn, not one fixed state
    _, info = env.reset(seed=0, options={"state": [0.0, 30.0 / 2], "budget": 0.0})  # explicit options win
    assert env.unwrapped.state[1] == 15.0
    with pytest.raises(ValueError, match="filter"):
        make_env("pointmass", certified_starts=True)


def test_documents_without_later_aggregates_still_validate(tmp_path, pointmass_held_table):
    """``time_to_land`` joined the evaluation schema later: documents written before it stay valid, and a
    document missing a field that was always there still fails, naming it."""
    from softreach.agents.report import evaluation_document, validate_evaluation

    res = evaluate(EvalSpec(policy="random", table=str(pointmass_held_table.path), budget=0.3, episodes=2,
                            starts="inside", seed=0))
    doc = evaluation_document(res)
    assert "time_to_land" in doc["aggregates"]
    del doc["aggregates"]["time_to_land"]
    validate_evaluation(doc)
    del doc["aggregates"]["control_effort"]
    with pytest.raises(ValueError, match="control_effort"):
        validate_evaluation(doc)
