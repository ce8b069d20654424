"""The glider's solved tables (paper §VI-B, issue 3): sets, Q = 0 against the classical set, closed-loop soundness,
metadata, the command line and the Fig. 6-9 plot.

One tiny table (``SHAPE`` x ``NZ`` budget nodes, ENO2 / RK2, eager) is solved once per session; the numbers it is
checked against were measured on it (see the comments), the grid study of ``docs/glider.md`` has the real ones.
"""

from __future__ import annotations

import contextlib
import itertools
import math

import numpy as np
import pytest

from softreach.reach import SolveConfig, SolverSettings, TableError, load_table, solve_table
from softreach.reach.models.glider import Glider
from softreach.reach.sim.simulate import constant, random_switching, rollout, table_control, table_disturbance

import torch

DEG = math.pi / 180.0
#: h 1.5 m, V 2 m/s, gamma 0.5 deg; h = 0, gamma = -3 deg and 0 deg are nodes
SHAPE = (31, 15, 11)
NZ = 21
BUDGETS = (0.0, 5.0, 10.0)


@contextlib.contextmanager
def one_thread():
    """Solve with one torch thread: on a shared 2-core machine two threads are several times slower (eager and
    compiled alike, measured: docs/glider.md)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.fixture(scope="session")
def glider_table(tmp_path_factory):
    path = tmp_path_factory.mktemp("glider") / "glider_tiny.srt"
    cfg = SolveConfig(shape=SHAPE, budget_points=NZ,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=True), snapshots=11)
    with one_thread():
        summary = solve_table(Glider(), cfg, path, progress=False, budgets=BUDGETS)
    table = load_table(path)
    table.solve_summary = summary
    return table


# ------------------------------------------------------------------------------------------------ model defaults
def test_default_grid_puts_every_set_boundary_on_a_node():
    """The default grid's nodes include h = 0 (touchdown band centre) and -0.5 m (its bottom, the ground bound
    of C1), V = 61, 66, 78, 83 m/s and gamma = -3, 0 deg, and the grid box holds C1's box and 40 m starts."""
    m = Glider()
    lo, hi = m.domain
    for i, marks in enumerate([(0.0,), (61.0, 66.0, 78.0, 83.0), (-3 * DEG, 0.0)]):
        axis = np.linspace(lo[i], hi[i], m.default_shape[i])
        for v in marks:
            assert np.min(np.abs(axis - v)) < 1e-9 * max(1.0, abs(v)), (i, v)
    for i in range(3):
        assert lo[i] < m.hard_box[0][i] and m.hard_box[1][i] <= hi[i]
    assert m.hard_box[1][0] >= 40.0
    assert m.default_budgets == BUDGETS
    assert m.default_snapshots >= 11 and m.default_budget_points >= 21


def test_compiled_step_has_no_graph_break():
    """torch.compile traces the glider's whole soft-constrained rate and TVD-RK step as one graph each."""
    import torch._dynamo as dynamo

    from softreach.reach.numerics.grid import Grid, budget_axis
    from softreach.reach.problem import soft_problem
    from softreach.reach.numerics.solver import HamiltonianOperator, tvd_rk_step

    m = Glider()
    z_lo, z_hi, nz = budget_axis(m.horizon, 9)
    grid = Grid(m.domain[0] + (z_lo,), m.domain[1] + (z_hi,), (9, 8, 7, nz))
    settings = SolverSettings.from_accuracy("medium", dtype="float32", compile=True)
    op = HamiltonianOperator(soft_problem(m, 1e-3, m.budget_scale), grid, settings)
    u = op.terminal(m.horizon)
    dynamo.reset()
    rate = dynamo.explain(lambda v: op.rate_lazy(0.0, v))(u)
    assert rate.graph_break_count == 0 and rate.graph_count == 1, rate.break_reasons
    r = op.rate_lazy(0.0, u)[0]
    step = dynamo.explain(lambda v, rr, dt: tvd_rk_step(op, 0.0, v, dt, 2, first_rate=rr))(u, r, torch.tensor(1e-3))
    assert step.graph_break_count == 0, step.break_reasons


# ------------------------------------------------------------------------------------------------ the table
def test_table_records_the_glider(glider_table):
    model = glider_table.model
    assert isinstance(model, Glider)
    assert model.params == Glider().params
    glider_table.check_compatible(Glider())
    with pytest.raises(TableError, match="wind_max"):
        glider_table.check_compatible(Glider(wind_max=5000.0))
    assert glider_table.budget_scale == Glider().budget_scale
    assert glider_table.grid("W_eps").shape[:3] == SHAPE
    assert glider_table.solve_summary["budgets"] == list(BUDGETS)


def test_sets_grow_with_budget(glider_table):
    masks = [glider_table.set_mask(0.0, q) for q in BUDGETS]
    measures = [glider_table.set_measure(0.0, q) for q in BUDGETS]
    assert measures[0] > 0
    for small, big in zip(masks, masks[1:]):
        # W_eps does not increase with z, so the sets are nested; the scheme keeps that up to a few boundary nodes
        # (measured: 0 of RA~_0 outside RA~_5, 1 of RA~_5 outside RA~_10 on this grid)
        assert (small & ~big).sum() <= max(2, 0.02 * small.sum())
    # strictly larger, by well over one node (measured on this grid: 82, 275 and 302 nodes)
    cell = glider_table.cell_volume("W_eps")
    assert measures[1] > measures[0] + 10 * cell and measures[2] > measures[1] + 10 * cell
    # the budget lets higher states land
    axis = glider_table.state_axes("W_eps")[0]
    tops = [axis[np.nonzero(m.any(axis=(1, 2)))[0].max()] for m in masks]
    assert tops[0] <= tops[1] <= tops[2] and tops[2] > tops[0]


def test_sets_respect_the_hard_constraint(glider_table):
    """No node outside C1 is in any set (the value is at least c1)."""
    m = glider_table.model
    full = np.meshgrid(*glider_table.state_axes("W_eps"), indexing="ij")
    outside = np.asarray(m.hard_constraint(0.0, full)) > 0
    for q in BUDGETS:
        assert not (glider_table.set_mask(0.0, q) & outside).any()
    assert not (glider_table.set_mask(0.0) & outside).any()


def _next_to(mask: np.ndarray, other: np.ndarray, edge: bool) -> np.ndarray:
    """The nodes of ``mask`` with a node of ``other`` one step away along some axes (``edge``: whether the grid's
    edge counts as ``other``)."""
    padded = np.pad(other, 1, constant_values=edge)
    near = np.zeros(padded.shape, bool)
    for shift in itertools.product((-1, 0, 1), repeat=mask.ndim):
        near |= np.roll(padded, shift, axis=tuple(range(mask.ndim)))
    return mask & near[(slice(1, -1),) * mask.ndim]


def test_q0_set_inside_the_classical_set_and_apart_only_at_its_boundary(glider_table):
    """Prop. 3: RA~_0 = RA. This grid does not resolve the equality: RA is one or two cells thick here (all but 2
    of its 180 nodes touch its boundary), and RA~_0, read at half a budget cell (Table.set_mask), keeps 82 of them
    (the grid study of docs/glider.md measures the equality on finer grids). What holds at one cell, checked:

    * RA~_0 claims no node that RA rejects unless that node touches RA (one cell);
    * every node RA~_0 loses touches RA's boundary, and RA's interior (the nodes that do not) is all kept;
    * the nodes with V below half of V's minimum are kept."""
    ra = glider_table.set_mask(0.0)
    ra0 = glider_table.set_mask(0.0, 0.0)
    assert ra.sum() > 50
    boundary = _next_to(ra, ~ra, edge=True)
    assert not (ra0 & ~ra & ~_next_to(~ra, ra, edge=False)).any()
    assert not (ra & ~ra0 & ~boundary).any()
    interior = ra & ~boundary
    assert interior.any() and not (interior & ~ra0).any()
    V = np.asarray(glider_table.values("V")[0], dtype=float)
    deep = V <= 0.5 * V.min()
    assert deep.sum() >= 5 and not (deep & ~ra0).any()


# ------------------------------------------------------------------------------------------------ soundness
def _starts(table, q, n, margin, seed=0):
    rng = np.random.default_rng(seed)
    g = table.grid("W_eps")
    lo, hi = np.array(g.lo[:3]), np.array(g.hi[:3])
    x = lo + rng.random((50_000, 3)) * (hi - lo)
    w = table.value(0.0, x, np.full(len(x), max(q, table.budget_resolution)))
    return x[np.nonzero(w <= -margin)[0][:n]]


def test_starts_inside_land_safely_within_budget(glider_table):
    """States with W_eps(0, x, Q) <= -margin for Q = 0, 5, 10, flown with budget Q by the table's control against
    the worst-case wind, a constant headwind and randomly switching wind, land by the horizon, never
    leave C1 and spend at most Q (+1 ms). Margin 0.02: along worst-case closed loops from inside the sets of this
    table W_eps changes by at most 0.011-0.025 per 0.02 s control period and rises by at most 0.012 (measured
    with benchmarks/bench_glider.py's value_change_per_period); the sets are only 0.07-0.15 deep here."""
    table = glider_table
    xs, qs = [], []
    for q in BUDGETS:
        x = _starts(table, q, 10, margin=0.02, seed=int(q))
        assert len(x) >= 8
        xs.append(x)
        qs += [q] * len(x)
    x, q = np.concatenate(xs), np.array(qs)
    # (a constant tailwind, the fourth sequence of benchmarks/bench_glider.py, mostly is the worst case here)
    for dist in (table_disturbance(table), constant([-1e4]), random_switching(table.model, seed=3, hold=0.5)):
        ro = rollout(table.model, x, q, table_control(table), dist, dt=0.02, eps=table.eps)
        assert not ro.hard_violation.any(), x[ro.hard_violation]
        assert ro.landed.all(), x[~ro.landed]
        assert np.all(ro.budget_used <= q + 1e-3), (ro.budget_used - q).max()


def test_a_start_outside_every_set_fails_under_worst_case_wind(glider_table):
    """The check above can fail: 40 m up at 70 m/s is outside every set (too high to land in 10 s), and the
    closed loop indeed does not land by the horizon."""
    table = glider_table
    x = np.array([[40.0, 70.0, -1.5 * DEG]])
    assert table.value(0.0, x, 10.0)[0] > 0
    ro = rollout(table.model, x, 10.0, table_control(table), table_disturbance(table), dt=0.02, eps=table.eps)
    assert not ro.landed[0]


# ------------------------------------------------------------------------------------------------ plot and CLI
def test_pick_starts_lie_in_their_sets(glider_table):
    from softreach.reach.cli.plotting_nd import pick_starts

    starts = pick_starts(glider_table, BUDGETS)
    assert [q for _, q in starts] == list(BUDGETS)
    prev = None
    for x, q in starts:
        assert glider_table.value(0.0, [x], max(q, glider_table.budget_resolution))[0] < 0
        if prev is not None:  # a start that needs its budget: outside the smaller set (on the grid)
            assert glider_table.value(0.0, [x], max(prev, glider_table.budget_resolution))[0] > 0
        prev = q


def test_plot_sets_nd_writes_a_png(glider_table, tmp_path):
    from softreach.reach.cli.plotting_nd import plot_sets_nd

    out = plot_sets_nd(glider_table, BUDGETS, tmp_path / "glider.png", dt=0.02, slices=[-1.5 * DEG])
    assert out.exists() and out.stat().st_size > 20_000
    import matplotlib.image as mpimg

    img = mpimg.imread(out)
    assert img.shape[1] > 2 * img.shape[0]  # four panels side by side
    with pytest.raises(ValueError, match="three-state"):
        from softreach.reach import get_model

        class Fake:
            model = get_model("pointmass")
            has_budget = True

        plot_sets_nd(Fake(), BUDGETS, tmp_path / "x.png")


def test_cli_solve_and_plot(tmp_path, capsys):
    from softreach.cli import main

    table = tmp_path / "g.srt"
    with one_thread():
        rc = main(["solve", "glider", "--grid", "16", "15", "11", "--budget-points", "12", "--accuracy", "low",
                   "--compile", "no", "--quiet", "--snapshots", "3", "--out", str(table)])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "Q=5" in out and "Q=10" in out  # the glider's default budgets
    fig = tmp_path / "g.png"
    rc = main(["plot", str(table), "--out", str(fig), "--from", f"3,72,{-1.5 * DEG}:5"])
    assert rc == 0 and fig.exists()
