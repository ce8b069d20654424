"""Figures and reports a reader can trust: sets drawn from their level functions, intervals inside the range of
the quantity, the task named in the model's own words, and a demo report that leads with its result."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.agents.evaluate import EvalSpec, EvaluationResult, evaluate
from softreach.agents.statistics import mean_ci
from softreach.reach.model_report import LANDING_WORDS, TaskWords


@pytest.mark.parametrize("budget", [None, 0.0, 0.06, 0.3])
def test_set_level_zero_sublevel_is_the_set(pointmass_table, budget):
    level = pointmass_table.set_level(0.0, budget)
    mask = pointmass_table.set_mask(0.0, budget)
    assert level.shape == mask.shape
    assert np.array_equal(level <= 0, mask)
    # a level function, not a mask: it takes many values, so its zero contour is interpolated between nodes
    assert len(np.unique(level)) > 10 * 2


def test_set_contour_is_not_a_staircase(pointmass_table):
    """The drawn outline of RA~_Q: a contour of a boolean mask has every vertex on a node line or half-way
    between two nodes; the level function's contour puts vertices anywhere along the cell edges."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softreach.reach.cli.plotting import contour_level

    axes = pointmass_table.state_axes("W_eps")
    X, Y = np.meshgrid(axes[0], axes[1], indexing="ij")
    fig, ax = plt.subplots()
    cs = ax.contour(X, Y, contour_level(pointmass_table.set_level(0.0, 0.3)), levels=[0.0])
    verts = np.concatenate([p.vertices for p in cs.get_paths()])
    plt.close(fig)
    hx, hy = axes[0][1] - axes[0][0], axes[1][1] - axes[1][0]
    # position of each vertex in units of half a cell: integers for a mask's contour
    fx = (verts[:, 0] - axes[0][0]) / (0.5 * hx)
    fy = (verts[:, 1] - axes[1][0]) / (0.5 * hy)
    on_half = np.isclose(fx, np.round(fx), atol=1e-6) & np.isclose(fy, np.round(fy), atol=1e-6)
    assert len(verts) > 20 and on_half.mean() < 0.5


def test_intervals_stay_inside_the_range():
    # a duration of zero in most episodes: the Student-t interval alone reaches below zero
    values = [0.0] * 9 + [1.0]
    free = mean_ci(values)
    assert free["low"] < 0
    cut = mean_ci(values, lower=0.0)
    assert cut["low"] == 0.0 and cut["high"] == free["high"] and cut["mean"] == free["mean"]
    rate = mean_ci([1.0] * 5 + [0.0], lower=0.0, upper=1.0)
    assert rate["high"] == 1.0 and rate["low"] > 0


def test_generic_model_is_not_said_to_land(dubins_table):
    from softreach.agents.report_text import comparison_table, summary_lines, task_words

    assert type(dubins_table.model).words == TaskWords()
    res = evaluate(EvalSpec(model="dubins", policy="random", table=str(dubins_table.path), wind="random",
                            episodes=2, starts="uniform", seed=0))
    assert task_words(res) == TaskWords()
    text = "\n".join(summary_lines(res)) + comparison_table([("random", res)])
    for word in ("land", "touchdown", "sink"):
        assert word not in text.lower(), (word, text)
    assert "success rate" in text and "time to target" in text
    # the landings keep their words, and the JSON keys stay the same for every model
    assert "landing_rate" in res.aggregates and LANDING_WORDS.success == "landing rate"


def _result(key: str, hard: int, n: int, landed: int) -> tuple[str, str, EvaluationResult]:
    from softreach.agents.statistics import wilson

    agg = {"hard_violation_rate": wilson(hard, n), "over_budget_rate": wilson(0, n),
           "landing_rate": wilson(landed, n)}
    return key, key, EvaluationResult(config={"model": "pointmass"}, episodes=[], aggregates=agg)


def test_demo_report_leads_with_its_result():
    from softreach.agents.demo import headline

    lines = headline([_result("filtered", 0, 60, 60), _result("unfiltered", 17, 60, 40),
                      _result("optimal", 0, 60, 59)])
    first = lines[0]
    assert first.startswith("**Under the filter the learned policy had 0 hard violations and 0 overspends in 60")
    assert "without the filter, 17 of 60 episodes left `C1`" in first and "59 of 60" in first
    text = " ".join(lines)
    assert "proof" in text and "rule of three" in text and f"{3 / 60:.2g}" in text
    assert "one training seed" in text
    assert "one training seed" not in " ".join(headline([_result("filtered", 0, 60, 60)], training_seeds=3))
    assert math.isclose(3 / 60, 0.05)
