"""One membership rule and one start picker: the figures, the evaluation's starts and ``Table.contains`` agree on
what is inside ``RA~_Q``."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.agents import tables as agent_tables
from softreach.reach.cli import plotting, plotting_nd
from softreach.reach.tables import starts


def _nodes(table):
    axes = table.state_axes("W_eps")
    return np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)


@pytest.mark.parametrize("fixture", ["pointmass_table", "dubins_table"])
def test_plot_masks_and_evaluation_membership_are_one_set(fixture, request):
    table = request.getfixturevalue(fixture)
    pts = _nodes(table)
    for t in (0.0, 0.3):
        for q in (0.0, 0.06, 0.3):
            for margin in (0.0, table.paper_proxy_margin()):
                mask = table.set_mask(t, q, margin=margin).ravel()
                np.testing.assert_array_equal(table.contains(t, pts, q, margin=margin), mask)
            if margin == 0.0:
                inside = [agent_tables.in_set(table, x, q, t) for x in pts[:: max(1, len(pts) // 400)]]
                np.testing.assert_array_equal(inside, mask[:: max(1, len(pts) // 400)])
    np.testing.assert_array_equal(table.contains(0.0, pts), table.set_mask(0.0).ravel())


def test_paper_proxy_margin_is_one_millisecond_of_budget(pointmass_table):
    assert pointmass_table.paper_proxy_margin() == pytest.approx(pointmass_table.budget_scale * 1e-3)
    assert pointmass_table.paper_proxy_margin() == pytest.approx(0.05)  # kappa = 50 for the point mass
    # the proxy is stricter than the plain rule and still nested in Q
    plain, proxy = pointmass_table.set_mask(0.0, 0.3), pointmass_table.set_mask(0.0, 0.3, margin=0.05)
    assert proxy.sum() < plain.sum() and not (proxy & ~plain).any()


@pytest.mark.parametrize("fixture", ["pointmass_table", "dubins_table"])
def test_one_start_picker_for_plots_and_evaluation(fixture, request):
    table = request.getfixturevalue(fixture)
    budgets = [0.0, 0.3, 0.6]
    picks = starts.paper_starts(table, budgets)
    assert agent_tables.paper_starts is starts.paper_starts and agent_tables.sample_inside is starts.sample_inside
    as_tuples = [(tuple(x.tolist()), q) for x, q in picks]
    assert plotting.representative_starts(table, budgets) == as_tuples
    if table.model.state_dim == 3:
        assert plotting_nd.pick_starts(table, budgets) == as_tuples
    for x, q in picks:
        assert table.contains(0.0, x, q)[0]  # inside the set the figure draws
    # a start that needs its budget: the largest budget's start lies outside the smallest budget's set
    assert not table.contains(0.0, picks[-1][0], picks[0][1])[0]


def test_sample_inside_draws_inside_the_plotted_set(pointmass_table):
    rng = np.random.default_rng(2)
    for q in (0.0, 0.3):
        xs = np.array([starts.sample_inside(pointmass_table, q, rng) for _ in range(30)])
        assert pointmass_table.contains(0.0, xs, q).all()
        # within half a cell of a node of the mask
        h = np.array([a[1] - a[0] for a in pointmass_table.state_axes("W_eps")])
        nodes = _nodes(pointmass_table)[pointmass_table.set_mask(0.0, q).ravel()]
        near = np.abs(xs[:, None, :] - nodes[None, :, :]) <= 0.5 * h + 1e-12
        assert near.all(axis=2).any(axis=1).all()
