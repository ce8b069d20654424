"""The glider's cell certificates (``softreach.reach.proof.cell_certificate`` on its box-start interval enclosures): sound
against a fact of the glider the cells are not built from (how fast it can descend), kept by their own plans
under winds that switch inside the 0.1 s period, and kept by the filter against adversarial policies and winds.
The cells are the package's own (``reach/proof/cells/``), the ones a user's filter reads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.agents.audit import Row, _policy, _wind, run_episode
from softreach.reach.proof.kernels import step_index

from cell_plans import assert_landing_cells_nested, cell_boxes, fly_plan_from_a_good_cell

DT = 0.1


@pytest.fixture(scope="module")
def vf(glider_held_table):
    out = ValueFilter(glider_held_table, DT, target_checks=glider_held_table.model.substeps)
    assert out.landing_cells is not None and out.safe_cells is None
    return out


@pytest.mark.parametrize("t", [0.0, 5.0, 9.0, 9.8])
def test_no_landing_cell_is_too_high_to_reach_the_ground_in_time(vf, t):
    # in C1 the glider sinks at most V_max sin(3 deg): a cell above what that reaches by T cannot land
    p = vf.model.params
    reach = p.hard_speed[1] * math.sin(-p.hard_gamma[0]) * (vf.model.horizon - t)
    cells = vf.landing_cells
    lo, _, m = cell_boxes(cells, step_index(t, cells.dt, cells.steps))
    lo = lo[m < vf.landing_cells.never]
    assert len(lo) and (lo[:, 0] <= p.min_altitude + p.touchdown_altitude + reach + 1e-9).all()


def test_landing_cells_grow_with_the_budget(vf):
    assert_landing_cells_nested(vf, (0.0, 5.0, 10.0))


def test_a_cells_plan_keeps_its_promise_under_switching_winds(vf):
    rng = np.random.default_rng(0)
    for _ in range(120):
        fly_plan_from_a_good_cell(vf.landing_cells, vf.model, vf.eps, rng)


@pytest.mark.parametrize("policy", ["always_max", "random"])
def test_filter_lands_every_run_from_landing_cells(vf, policy):
    rng = np.random.default_rng(3)
    lo, hi = (np.asarray(b, float) for b in vf.model.hard_box)
    x = rng.uniform(lo, hi, (20000, 3))
    for q in (0.0, 5.0):
        starts = x[vf.landing_cells.contains(0.0, x, q)][:2]
        assert len(starts) == 2
        for x0 in starts:
            for wind in ("worst_case", "switch_inside", "switch_on_filter"):
                row = Row(policy, wind, "certified", True)
                out = run_episode(vf, vf, x0, q, _policy(policy, vf, rng), _wind(wind, vf, rng, 2), 2,
                                  vf.model.substeps, row, False)
                assert out["landed"] and not out["hard"] and out["budget_used"] <= q + 1e-9, (x0, q, wind, out)
                assert row.uncertified_steps == 0, (x0, q, wind)
