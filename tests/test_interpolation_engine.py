"""One interpolation engine (``reach/tables/interpolation.py``) behind ``Table`` and the filter's ``TableField``: both give
the numbers of an independent reference interpolant, agree with each other, and wrap or clamp the same way."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from softreach.filters import TableField
from softreach.reach.numerics.grid import Grid
from softreach.reach.tables.interpolation import Interpolant, interpolate
from softreach.reach.tables.query import Table


def _reference(values, times, grid, t, x):
    """Multilinear interpolation of one query in plain Python: clamp (or wrap) each coordinate, then sum the
    ``2^(D+1)`` corners in time and space."""
    k = min(max(int(np.searchsorted(times, t, side="right")) - 1, 0), len(times) - 2)
    wt = min(max((t - times[k]) / (times[k + 1] - times[k]), 0.0), 1.0)
    cells = []
    for a in range(grid.ndim):
        n, h, lo = grid.shape[a], grid.spacing[a], grid.lo[a]
        if grid.periodic[a]:
            s = ((x[a] - lo) / h) % n
            i = math.floor(s)
            cells.append((i % n, (i + 1) % n, s - i))
        else:
            s = (min(max(x[a], lo), grid.hi[a]) - lo) / h
            i = min(int(s), n - 2)
            cells.append((i, i + 1, s - i))
    out = 0.0
    for dk, wk in ((0, 1 - wt), (1, wt)):
        for corner in itertools.product((0, 1), repeat=grid.ndim):
            w, idx = wk, []
            for (i0, i1, f), c in zip(cells, corner):
                w *= f if c else 1 - f
                idx.append(i1 if c else i0)
            out += w * float(values[(k + dk, *idx)])
    return out


def _reference_gradient(values, times, grid, t, x, a):
    """The central difference of the reference over one spacing, both ends shifted inwards at a grid edge."""
    x = [min(max(v, lo), hi) if not p else v for v, lo, hi, p in zip(x, grid.lo, grid.hi, grid.periodic)]
    h = grid.spacing[a]
    plus, minus = list(x), list(x)
    plus[a] += h
    minus[a] -= h
    if not grid.periodic[a]:
        shift = max(0.0, grid.lo[a] - minus[a]) - max(0.0, plus[a] - grid.hi[a])
        plus[a] += shift
        minus[a] += shift
    t = min(max(t, times[0]), times[-1])
    return (_reference(values, times, grid, t, plus) - _reference(values, times, grid, t, minus)) / (plus[a] - minus[a])


def _queries(table: Table, rng, N=300):
    """Points inside, beyond every edge (clamped or wrapped), on nodes, and at budgets above and below the grid."""
    g = table.grid("W_eps")
    lo, hi, h = np.array(g.lo), np.array(g.hi), np.array(g.spacing)
    X = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), size=(N, g.ndim))
    X[: N // 3] = np.clip(X[: N // 3], lo, hi)
    X[N // 3: N // 2] = lo + np.round((X[N // 3: N // 2] - lo) / h) * h  # on nodes (and on the far edges)
    t = rng.uniform(-0.1, table.horizon + 0.1, N)
    t[: N // 2] = np.clip(t[: N // 2], 0.0, table.horizon)
    t[N // 2: N // 2 + 20] = table.times()[rng.integers(0, len(table.times()), 20)]
    return t, X


@pytest.fixture(params=["pointmass_table", "dubins_table"])
def table(request):
    return request.getfixturevalue(request.param)


def test_table_matches_an_independent_reference(table):
    g, times, W = table.grid("W_eps"), table.times("W_eps"), table.values("W_eps")
    n = g.ndim - 1
    t, X = _queries(table, np.random.default_rng(3))
    inside_grid = np.all([(X[:, a] >= g.lo[a]) & (X[:, a] <= g.hi[a]) | g.periodic[a] for a in range(n)], axis=0)
    inside = inside_grid & (t >= 0) & (t <= table.horizon) & (X[:, n] >= g.lo[n])
    val = table.value(t, X[:, :n], X[:, n])
    grad = table.gradient(t, X[:, :n], X[:, n], outside="nearest")
    assert np.array_equal(np.isfinite(val), inside)
    scale = float(np.abs(W).max())
    for i in range(len(t)):
        ref = _reference(W, times, g, t[i], X[i])
        if inside[i]:
            assert val[i] == pytest.approx(ref, abs=1e-12 * scale)
        for a in range(g.ndim):
            assert grad[i, a] == pytest.approx(_reference_gradient(W, times, g, t[i], X[i], a), abs=1e-9 * scale)


@pytest.mark.parametrize("layout", ["stacked", "stencil"])
def test_table_field_and_table_agree(table, layout):
    field = TableField(table, layout=layout)
    n = field.n
    t, X = _queries(table, np.random.default_rng(4))
    val, grad, loc = field.value_and_gradient(t, X)
    ref_val = table.value(t, X[:, :n], X[:, n])
    ref_grad = table.gradient(t, X[:, :n], X[:, n], outside="nearest")[:, :n]
    assert np.array_equal(np.isfinite(val), np.isfinite(ref_val))
    fin = np.isfinite(val)
    np.testing.assert_allclose(val[fin], ref_val[fin], rtol=0, atol=1e-12)
    np.testing.assert_allclose(grad, ref_grad, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(field.value(t, X), val)
    # the scalar path: the same numbers, or None where it leaves the query to the batch path
    answered = 0
    for i in range(len(t)):
        one = field.single(float(t[i]), X[i].tolist())
        if one is None:
            continue
        answered += 1
        assert (one[0] == pytest.approx(val[i], abs=1e-12)) if math.isfinite(val[i]) else one[0] == math.inf
        np.testing.assert_allclose(one[1], grad[i], rtol=0, atol=1e-12)
    assert answered > (len(t) // 2 if layout == "stacked" else len(t) // 5)  # the stencil leaves edge cells


def test_periodic_axis_wraps_and_is_never_outside(dubins_table):
    g = dubins_table.grid("W_eps")
    period = g.hi[2] - g.lo[2]
    rng = np.random.default_rng(5)
    x = rng.uniform(g.lo[:3], g.hi[:3], size=(50, 3))
    z = np.full(50, 0.3)
    for turns in (-2, 1, 3):
        shifted = x + np.array([0.0, 0.0, turns * period])
        np.testing.assert_allclose(dubins_table.value(0.2, shifted, z), dubins_table.value(0.2, x, z), atol=1e-12)
        np.testing.assert_allclose(dubins_table.gradient(0.2, shifted, z), dubins_table.gradient(0.2, x, z), atol=1e-9)


def test_single_snapshot_and_two_node_axes():
    """A field of one snapshot answers only at its time; a two-node axis differentiates across its one cell."""
    grid = Grid((0.0, 0.0), (1.0, 2.0), (2, 5))
    values = np.random.default_rng(6).normal(size=(1,) + grid.shape)
    engine = Interpolant(values, [0.5], grid, gradient_axes=(0, 1))
    X = np.array([[0.3, 1.1], [0.3, 1.1]])
    v, inside = interpolate(values, np.array([0.5]), grid, np.array([0.5, 0.6]), X)
    assert inside.tolist() == [True, False]
    _, grad, _ = engine.value_and_gradient(np.array([0.5]), X[:1])
    assert grad[0, 0] == pytest.approx(_two_node_slope(values[0], 1.1 / grid.spacing[1]) / grid.spacing[0])


def _two_node_slope(V, s):
    """d/dx of the interpolant on a two-node x axis: the difference of the two x rows at y-coordinate ``s``."""
    i = int(s)
    f = s - i
    return (1 - f) * (V[1, i] - V[0, i]) + f * (V[1, i + 1] - V[0, i + 1])


def test_slice_is_the_point_query_at_the_nodes(pointmass_table):
    """``Table.slice`` (what ``set_mask`` thresholds) is the interpolant at the grid's nodes."""
    axes = pointmass_table.state_axes("W_eps")
    mesh = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)
    for t, z in ((0.0, 0.3), (0.37, 0.012), (1.0, 5.0)):
        sl = pointmass_table.slice("W_eps", t, z).ravel()
        pt = pointmass_table.value(t, mesh, np.full(len(mesh), z))
        np.testing.assert_allclose(sl, pt, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="time span"):
        pointmass_table.slice("W_eps", pointmass_table.horizon + 1.0, 0.3)
    assert not hasattr(Table, "_slice")


def test_a_query_gives_the_same_bits_alone_and_in_a_batch(table):
    """The filter decides the same alone and batched: no reduction may reorder a query's sum with the batch size."""
    field = TableField(table)
    t, X = _queries(table, np.random.default_rng(7), N=64)
    val, grad, _ = field.value_and_gradient(t, X)
    raw = table.value(t, X[:, :-1], X[:, -1])
    for i in range(0, 64, 7):
        v1, g1, _ = field.value_and_gradient(t[i:i + 1], X[i:i + 1])
        assert v1[0] == val[i] or (np.isnan(v1[0]) and np.isnan(val[i]))
        np.testing.assert_array_equal(g1[0], grad[i])
        assert table.value(t[i], X[i, :-1], X[i, -1])[0] == raw[i]


@pytest.mark.parametrize("times", [np.linspace(0.0, 1.0, 101), np.array([0.0, 0.05, 0.3, 0.31, 0.9, 2.0])],
                         ids=["even", "uneven"])
def test_the_compiled_snapshot_is_the_searchsorted_one(times):
    """The compiled decision's snapshot interval and weight (``kernels.snapshot``, which guesses the interval from
    evenly spaced snapshots before it walks) are those of ``np.searchsorted``, at every snapshot time, between them,
    around them by a rounding, and outside the span."""
    from softreach.reach.proof.kernels import snapshot

    rng = np.random.default_rng(3)
    t = np.concatenate([times, np.nextafter(times, -np.inf), np.nextafter(times, np.inf),
                        rng.uniform(times[0] - 0.5, times[-1] + 0.5, 500), [np.nan, -np.inf, np.inf]])
    for ti in t:
        k = min(max(int(np.searchsorted(times, ti, side="right")) - 1, 0), len(times) - 2)
        wt = min(max((ti - times[k]) / (times[k + 1] - times[k]), 0.0), 1.0) if math.isfinite(ti) else None
        got_k, got_wt = snapshot(times, ti)
        assert got_k == k, ti
        if wt is not None:
            assert got_wt == wt, ti
