"""The safety filter on a budget-surface table (``Q_min`` on the state grid, sampled-data game): the same
compiled decision, reading ``Q_min - min(z, T - t)`` where a ``W_eps`` table gives ``W_eps``; the same adversaries,
no hard violation and no overspend from certified starts."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.filters import ValueFilter
from softreach.agents.audit import POLICIES, audit
from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table
from softreach.reach.tables.interpolation import interpolate

DT = 0.01


def _solve(tmp_path_factory, name: str, period: float | None):
    path = tmp_path_factory.mktemp("qmin_tables") / name
    cfg = SolveConfig(shape=(41, 41), budget_points=45, control_period=period, budget_surface=True,
                      settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=True))
    solve_table(get_model("pointmass"), cfg, path, progress=False)
    return load_table(path)


@pytest.fixture(scope="module")
def held_qmin(tmp_path_factory):
    return _solve(tmp_path_factory, "pointmass-held-qmin.srt", DT)


@pytest.fixture(scope="module")
def vf(held_qmin):
    return ValueFilter(held_qmin, DT, target_checks=get_model("pointmass").substeps)


def test_held_budget_surface_table_is_certified_and_its_sets_grow(held_qmin, vf):
    assert held_qmin.has_budget_surface and not held_qmin.has_budget
    assert vf.compiled is not None
    x = np.random.default_rng(0).uniform([-15, 0], [15, 18], (3000, 2))
    certified = [vf.certify(0.0, x, q)[0] for q in (0.0, 0.3, 0.6)]
    # more budget never loses a certified state (passing only gets easier with budget)
    assert all((a <= b).all() for a, b in zip(certified, certified[1:]))
    assert certified[0].sum() > 100


def test_no_certificate_in_a_cell_with_a_node_where_no_budget_suffices(held_qmin, vf):
    """``Q_min`` is infinite where no budget suffices, stored at a cap: between such a node and a feasible one the
    interpolant would promise a budget that does not exist, so the certificate must be ``+inf`` on such cells."""
    Q, times, g = np.asarray(held_qmin.values("Q_min")), held_qmin.times("Q_min"), held_qmin.grid("Q_min")
    rng = np.random.default_rng(1)
    k = 40
    t = float(times[k])
    x = rng.uniform([-15, 0], [15, 18], (20000, 2))
    d = vf.value(t, x, 0.6)
    i = np.floor((x - np.asarray(g.lo)) / np.asarray(g.spacing)).astype(int)
    corners = np.stack([Q[k, i[:, 0] + a, i[:, 1] + b] for a in (0, 1) for b in (0, 1)], axis=1)
    infeasible_corner = (corners > (times[-1] - t) + 1e-9).any(axis=1)
    v, _ = interpolate(held_qmin.values("V"), held_qmin.times("V"), held_qmin.grid("V"), np.full(len(x), t), x)
    # certified by Q_min, not by the classical V (read by the compiled interpolant, a rounding away from numpy's)
    by_q = np.isfinite(d) & (d < v - 1e-9 * np.maximum(1.0, np.abs(v)))
    assert by_q.sum() > 50
    assert not (by_q & infeasible_corner).any()


def test_certificate_is_q_min_less_the_usable_budget(held_qmin, vf):
    """The compiled certificate at a state is the definition read from the table's own interpolants:
    ``min(V~, Q~_min - min(z, T - t))``, ``+inf`` at a negative budget and in a cell with a corner where no budget
    suffices; at times near the horizon, where the budget exceeds the time left, only the time left counts. The
    budget surface is read in float32 with its top node rounded up, so the compiled value lies at or above the
    definition, by at most one float32 rounding of ``|Q_min - T|`` (``2**-24 * 2 T``)."""
    Q, times, g = np.asarray(held_qmin.values("Q_min")), held_qmin.times("Q_min"), held_qmin.grid("Q_min")
    T = float(times[-1])
    rng = np.random.default_rng(7)
    N = 4000
    t = np.concatenate([rng.uniform(0.0, T, N // 2), rng.uniform(T - 0.7, T, N // 2)])
    x = rng.uniform([-15, 0], [15, 18], (N, 2))
    z = rng.choice([-0.01, 0.0, 0.05, 0.3, 0.6, 2.0 * T], N)
    got = vf.value(t, x, z)
    q, q_in = interpolate(Q, times, g, t, x)
    v, v_in = interpolate(held_qmin.values("V"), held_qmin.times("V"), held_qmin.grid("V"), t, x)
    want = np.where(q_in & (z >= 0), q - np.minimum(z, np.maximum(T - t, 0.0)), np.inf)
    # cells with a corner where no budget suffices, at both snapshots around t
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    i = np.clip(np.floor((x - np.asarray(g.lo)) / np.asarray(g.spacing)).astype(int), 0, np.asarray(g.shape) - 2)
    bad = np.zeros(N, bool)
    for kk in (k, k + 1):
        for a in (0, 1):
            for b in (0, 1):
                bad |= Q[kk, i[:, 0] + a, i[:, 1] + b] > (T - times[kk]) + 1e-9
    want = np.where(bad, np.inf, want)
    want = np.minimum(want, np.where(v_in & (z >= 0), v, np.inf))
    finite = np.isfinite(want)
    assert finite.sum() > 500 and (~finite).sum() > 500
    assert ((z > T - t) & finite & (want < v)).sum() > 20  # the time-left clamp decides some values
    np.testing.assert_array_equal(np.isfinite(got), finite)
    allowance = 2.0 ** -24 * 2.0 * T
    assert (got[finite] >= want[finite] - 1e-12).all()
    assert (got[finite] <= want[finite] + allowance).all()


def test_audit_from_certified_starts_never_leaves_c1_nor_overspends(vf):
    rows = audit(vf, [0.3, 0.6], starts_per_row=2, kinds=("certified",), policies=POLICIES,
                 winds=("worst_case", "switch_inside", "switch_on_filter"), pieces=4, seed=0, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    raw = [r for r in rows if not r.filtered]
    assert sum(r.episodes for r in filtered) == len(POLICIES) * 3 * 2 * 2
    assert sum(r.hard_violations for r in filtered) == 0, [r.failures for r in filtered if r.hard_violations]
    assert sum(r.overspends for r in filtered) == 0, [r.failures for r in filtered if r.overspends]
    assert sum(r.hard_violations + r.overspends for r in raw) > len(raw)


def test_continuous_budget_surface_table_certifies_as_the_held_one(tmp_path_factory, vf):
    """A budget surface solved in continuous time: the cells certify with it what they certify with the held one
    (they read no table), and the filter replaces actions that would leave what they certify."""
    table = _solve(tmp_path_factory, "pointmass-qmin.srt", None)
    starts = np.random.default_rng(5).uniform([-15, 0], [15, 18], (500, 2))
    with_cells = ValueFilter(table, DT, target_checks=get_model("pointmass").substeps)
    assert table.control_period is None
    ok = with_cells.certify(0.0, starts, 0.3)[0]
    np.testing.assert_array_equal(ok, vf.certify(0.0, starts, 0.3)[0])
    assert 0 < ok.sum() < len(starts)
    # full thrust down, held, is replaced where it would leave what the cells certify
    x = np.random.default_rng(2).uniform([-15, 0], [15, 18], (2000, 2))
    x = x[with_cells.certify(0.0, x, 0.3)[0]]
    applied, info = with_cells.filter(0.0, x, 0.3, np.full((len(x), 1), -60.0))
    assert 0 < info["active"].sum() < len(x) and info["certified"].all()
    assert np.isfinite(applied).all()


def test_starts_certified_by_a_plan_of_their_own(vf):
    """The compiled search for a start's own plan on a budget surface: runs from such starts, the plan handed to the
    first step, keep every promise under adversarial winds."""
    assert vf.compiled is not None
    rows = audit(vf, [0.06, 0.3], starts_per_row=2, kinds=("planned",), policies=("random", "always_max"),
                 winds=("worst_case", "switch_on_filter"), pieces=4, seed=3, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    assert sum(r.episodes for r in filtered) == 2 * 2 * 2 * 2
    assert sum(r.hard_violations + r.overspends for r in filtered) == 0, [r.failures for r in filtered]
    assert sum(r.landed for r in filtered) == sum(r.episodes for r in filtered)
    assert sum(r.uncertified_steps for r in filtered) == 0
