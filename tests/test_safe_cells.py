"""The verified safe cells (``softreach.reach.safe_cells``): sound against facts of the point mass the cells are
not built from, kept by their own actions under winds that switch inside the period, and kept by the filter from
starts the landing certificate does not cover."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.envs.integrator import integrate_period
from softreach.filters import ValueFilter
from softreach.filters.audit import Row, _policy, _wind, run_episode
from softreach.reach import get_model
from softreach.reach.safe_cells import SafeCells

DT = 0.01
SHAPE = (60, 360)


@pytest.fixture(scope="module")
def vf(pointmass_held_table):
    model = get_model("pointmass")
    plain = ValueFilter(pointmass_held_table, DT, target_checks=model.substeps, safe_cells=None)
    cells = SafeCells.build(plain.lookahead, SHAPE)
    return ValueFilter(pointmass_held_table, DT, target_checks=model.substeps, safe_cells=cells)


def _cells(sc: SafeCells, k: int):
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in sc.shape], indexing="ij"), -1).reshape(-1, 2)
    return sc.lo + idx * sc.width, sc.lo + (idx + 1) * sc.width, sc.m[k].reshape(-1)


def test_no_safe_cell_holds_a_state_that_must_hit_the_ground(vf):
    # descending at v < 0, the best the vehicle can do against the worst wind is u_max - g - d_max upwards: below
    # the stopping altitude v^2 / (2 a) it reaches y < 0 within |v| / a < T, whatever the budget
    p = vf.model.params
    a = p.u_max - p.gravity - p.d_max
    lo, hi, m = _cells(vf.safe_cells, 0)
    safe = m < vf.safe_cells.never
    doomed = (lo[:, 0] < 0) & (lo[:, 1] < lo[:, 0] ** 2 / (2 * a))
    assert not (safe & doomed).any()
    # and the cells are not empty of such starts by accident: near the ground slow cells are safe
    assert (safe & (hi[:, 1] < 1.0) & (np.abs(lo[:, 0]) < 2)).any()


def test_outside_the_soft_band_needs_budget(vf):
    # outside C2 (|v| > 10) the budget drains at once: no such cell is safe with none, and some are with some
    lo, hi, m = _cells(vf.safe_cells, 0)
    band = (lo[:, 0] >= vf.model.params.soft_speed[1]) | (hi[:, 0] <= vf.model.params.soft_speed[0])
    assert band.any() and (m[band] > 0).all()
    assert (m[band] < vf.safe_cells.never).any()


def test_the_stored_action_keeps_the_cells_under_switching_winds(vf):
    sc, model = vf.safe_cells, vf.model
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(400):
        k = int(rng.integers(0, sc.steps))
        lo, hi, m = _cells(sc, k)
        c = int(rng.choice(np.nonzero(m < sc.never)[0]))
        x = rng.uniform(lo[c], hi[c])
        z = (m[c] + rng.uniform(0, 3)) * sc.dz
        assert sc.contains(k * DT, x, z)[0]
        a = sc.candidates[sc.action(k * DT, x)[0]]
        # a wind that switches between the extremes at four random instants of the period
        cuts = np.sort(rng.uniform(0, DT, 4))
        t, xs, spent, left_c1 = k * DT, list(map(float, x)), 0.0, False
        for s0, s1 in zip(np.r_[0, cuts], np.r_[cuts, DT]):
            if s1 - s0 <= 0:
                continue
            b = [float(rng.choice([-1.0, 1.0]) * model.params.d_max)]
            xs, cost, _, _ = integrate_period(model, t, xs, [float(a[0])], b, s1 - s0, 4, vf.eps, 1e-9)
            spent += cost
            t = k * DT + s1
            left_c1 |= float(model.hard_constraint(t, [np.float64(v) for v in xs])) > 0
        assert not left_c1 and z - spent >= -1e-12
        landed = bool(model.landed(t, [np.float64(v) for v in xs]))
        assert landed or sc.contains((k + 1) * DT, np.asarray(xs), z - spent)[0], (k, x, z, a, xs)
        checked += 1
    assert checked == 400


@pytest.mark.parametrize("policy", ["always_min", "always_max", "random", "anti_optimal"])
def test_filter_keeps_safe_starts_outside_the_landing_set_safe(vf, policy):
    # starts the landing certificate does not cover but the safe cells do: C1 and the budget still hold
    rng = np.random.default_rng(7)
    x = rng.uniform([-15, 0], [15, 18], (4000, 2))
    q = 0.06
    safe = vf.safe_cells.contains(0.0, x, q)
    certified, _, _ = vf.certify(0.0, x, q)
    starts = x[safe & ~certified][:3]
    assert len(starts) == 3
    for i, x0 in enumerate(starts):
        for wind in ("worst_case", "switch_inside", "switch_on_filter"):
            row = Row(policy, wind, "safe", True)
            out = run_episode(vf, vf, x0, q, _policy(policy, vf, rng), _wind(wind, vf, rng, 4), 4, 2, row, False)
            assert not out["hard"] and out["budget_used"] <= q + 1e-9, (x0, wind, out)


def test_files_are_checked(vf, tmp_path):
    sc = vf.safe_cells
    path = tmp_path / "cells.npz"
    sc.save(path)
    back = SafeCells.load(path, sc.key)
    assert np.array_equal(back.m, sc.m) and back.shape == sc.shape
    other = dict(sc.key, dt=0.1)
    with pytest.raises(ValueError, match="built for"):
        SafeCells.load(path, other)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a numpy file")
    with pytest.raises(ValueError, match="bad.npz"):
        SafeCells.load(bad)
    with pytest.raises(TypeError, match="safe_cells"):
        ValueFilter(vf.table, DT, safe_cells="yes")
    with pytest.raises(ValueError, match="not for this filter"):
        ValueFilter(vf.table, DT, safe_cells=SafeCells(sc.lo, sc.hi, sc.m, sc.best, sc.candidates, DT, sc.dz,
                                                        sc.horizon, other))
