"""Properties of the paper that a wrong solver would break, on the point-mass landing.

* Prop. 3: the ``Q = 0`` set of ``W_eps`` equals the classical reach-avoid set of ``V``.
* Prop. 4: the sets grow with the budget; ``W_eps`` does not increase along ``z``.
* Thm. 2(2): ``W_eps`` does not decrease as ``eps`` decreases (checked on the sets and near the zero level).
* The exact ceiling from rest (spec §4): the computed classical set never claims more, and refining approaches it.
* Soundness: from states with ``W <= -margin``, the table's control lands under the table's worst-case disturbance and
  other disturbance sequences, never leaves ``C1`` and spends at most ``Q`` plus one control period.
"""

from __future__ import annotations

import numpy as np
import pytest

from softreach.reach import Grid, SolveConfig, SolverSettings, classical_problem, get_model, load_table, solve, solve_table
from softreach.reach.sim.simulate import constant, random_switching, rollout, table_control, table_disturbance

from pointmass_ceiling import CEILING

MODEL = get_model("pointmass")


@pytest.fixture(scope="module")
def table61(tmp_path_factory):
    """61 x 61 x 67, ENO2 / RK2, 21 snapshots (W_eps stepped by the compiled kernel: this exercises it too)."""
    path = tmp_path_factory.mktemp("pm") / "pm61.srt"
    cfg = SolveConfig(shape=(61, 61), budget_points=67, snapshots=21,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32"))
    solve_table(MODEL, cfg, path, progress=False)
    return load_table(path)


def test_q0_set_reproduces_the_classical_set(table61):
    ra = table61.set_mask(0.0)
    ra0 = table61.set_mask(0.0, 0.0)
    sym = (ra ^ ra0).sum() / ra.sum()
    # measured 2.3% at this coarse grid with a second-order scheme (1.0% at 101 x 101 x 111, WENO5)
    assert sym < 0.04, sym
    # and what differs is a boundary layer, not a region: both sets are large and overlap almost entirely
    assert ra.sum() > 400 and (ra & ra0).sum() > 0.95 * ra.sum()


def test_sets_grow_with_the_budget(table61):
    W = np.asarray(table61.values("W_eps")[0])
    g = table61.grid("W_eps")
    (v_lo, y_lo), (v_hi, y_hi) = MODEL.hard_box
    box = np.ix_((g.axis(0) >= v_lo) & (g.axis(0) <= v_hi), (g.axis(1) >= y_lo) & (g.axis(1) <= y_hi), np.ones(g.shape[2], bool))
    # W_eps is non-increasing in z up to the oscillation of a second-order scheme: measured over C1, increases
    # reach 0.03 (values near -0.3, next to the hard boundary v = -15) on 0.9% of the pairs
    inc = np.diff(W[box], axis=-1)
    assert inc.max() < 0.06 and (inc > 1e-3).mean() < 0.02
    budgets = [0.0, 0.06, 0.3, 0.6]
    masks = [table61.set_mask(0.0, q) for q in budgets]
    for small, large in zip(masks, masks[1:]):
        assert not (small & ~large).any()
        assert large.sum() > small.sum()
    # the paper's Fig. 1: the budget buys a substantial enlargement
    assert masks[-1].sum() > 1.4 * masks[0].sum()


def test_value_does_not_decrease_as_eps_decreases(tmp_path):
    tables = {}
    for eps in (1.0, 0.1, 1e-3):
        cfg = SolveConfig(shape=(41, 41), budget_points=45, eps=eps, snapshots=3,
                          settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=True))
        solve_table(MODEL, cfg, tmp_path / f"e{eps}.srt", progress=False)
        tables[eps] = load_table(tmp_path / f"e{eps}.srt")
    W = {e: np.asarray(t.values("W_eps")[0]) for e, t in tables.items()}
    for q in (0.06, 0.3, 0.6):
        m1, m01, m0001 = (tables[e].set_mask(0.0, q) for e in (1.0, 0.1, 1e-3))
        assert not (m0001 & ~m01).any()
        # eps = 1 is resolved by this dv = 1 grid, eps <= 0.1 is not: their schemes differ in a boundary layer at
        # v = -10 (measured: 2 nodes of ~250 at Q = 0.06, up to 0.1 in value). Reported, not hidden.
        assert (m01 & ~m1).sum() <= 3
    # exactly ordered where both are sub-grid; near the zero level otherwise ordered but for that layer
    assert (W[1e-3] >= W[0.1] - 1e-5).all()
    near = np.minimum(W[1.0], W[0.1]) < 0.3
    assert (W[0.1][near] >= W[1.0][near] - 0.02).mean() > 0.998
    assert (W[0.1][near] >= W[1.0][near] - 0.15).all()


def _ceiling(shape):
    grid = Grid(MODEL.domain[0], MODEL.domain[1], shape)
    V = np.asarray(solve(classical_problem(MODEL), grid, [0.0, 1.0],
                         SolverSettings.from_accuracy("very_high", dtype="float64", compile=True)))
    iv = int(np.argmin(np.abs(grid.axis(0))))
    assert abs(grid.axis(0)[iv]) < 1e-9
    y = grid.axis(1)
    return y[V[iv] <= 0].max(), grid.spacing[1]


def test_classical_ceiling_is_sound_and_converges_to_the_exact_value():
    exact = MODEL.exact_ceiling()
    assert exact == pytest.approx(CEILING, abs=1e-9)  # both closed forms: equal up to float rounding
    coarse, h1 = _ceiling((81, 81))
    fine, h2 = _ceiling((161, 161))
    assert coarse <= exact + h1 and fine <= exact + h2  # never claims unreachable altitude
    assert exact - fine < exact - coarse  # refinement approaches the exact ceiling
    assert exact - fine < 0.7


@pytest.mark.parametrize("budget", [0.06, 0.3, 0.6])
def test_soundness_from_inside_the_soft_sets(table61, budget):
    dt = 2e-3
    g = table61.grid("V")
    vv, yy = np.meshgrid(g.axis(0)[::2], g.axis(1)[::2], indexing="ij")
    pts = np.stack([vv.ravel(), yy.ravel()], axis=1)
    inside = pts[table61.value(0.0, pts, np.full(len(pts), budget)) <= -0.1]
    assert len(inside) > 30
    winds = {"worst": table_disturbance(table61), "+10": constant(10.0), "-10": constant(-10.0),
             "switching": random_switching(MODEL, seed=3)}
    for name, wind in winds.items():
        ro = rollout(MODEL, inside, budget, table_control(table61), wind, dt=dt, eps=table61.eps)
        assert not ro.hard_violation.any(), name
        assert (ro.budget_used <= budget + dt).all(), (name, ro.budget_used.max())
        # measured: at 61 x 61 a few trajectories end 0.0x m above the 0.7 m-tall target at T (the coarse value
        # is flat there); at 101 x 101 x 111 with 41 snapshots, 1 in 3,247. Landing is required of the rest.
        assert ro.landed.mean() >= 0.9, (name, ro.landed.mean())


def test_worst_case_from_the_boundary_spends_the_budget(table61):
    """Fig. 5: from the edge of RA~_Q the worst case forces real use of the budget (sets are tight in z)."""
    g = table61.grid("V")
    vv, yy = np.meshgrid(g.axis(0), g.axis(1), indexing="ij")
    pts = np.stack([vv.ravel(), yy.ravel()], axis=1)
    q = 0.3
    qmin = table61.q_min(0.0, pts)
    edge = pts[(qmin > 0.2) & (qmin <= q)]
    assert len(edge) > 5
    ro = rollout(MODEL, edge, q, table_control(table61), table_disturbance(table61), dt=2e-3, eps=table61.eps)
    assert not ro.hard_violation.any() and (ro.budget_used <= q + 2e-3).all()
    assert ro.budget_used[ro.landed].mean() > 0.1
