"""The filter's batched core: agreement with the Table API, the computed margin, both rules, special cases."""

from __future__ import annotations


import numpy as np
import pytest

from softreach.filters import (AFTER_HORIZON, BLEND, FALLBACK, NONFINITE, OPTIMAL, OUTSIDE, PASS, ValueFilter,
                               smooth_rule, switch_rule)
from softreach.reach import TableError, get_model, load_table

DT = 0.01  # the point-mass environment's control period


@pytest.fixture(scope="module")
def vfilter(pointmass_table):
    return ValueFilter(pointmass_table, DT)


def random_queries(rng, n, table, spread=1.1):
    """States, budgets and times over (and a little beyond) the table's grid and time span."""
    g = table.grid("W_eps")
    lo, hi = np.array(g.lo), np.array(g.hi)
    mid, half = (lo + hi) / 2, (hi - lo) / 2 * spread
    X = rng.uniform(mid - half, mid + half, (n, g.ndim))
    t = rng.uniform(-0.05, table.horizon * 1.05, n)
    return t, X[:, :-1], X[:, -1]


def grid_states(table):
    g = table.grid("V")
    V, Y = np.meshgrid(g.axis(0), g.axis(1), indexing="ij")
    return np.c_[V.ravel(), Y.ravel()]


# ------------------------------------------------------------------------------------------ agreement with Table
@pytest.mark.parametrize("layout", ["stacked", "stencil"])
def test_value_gradient_and_inputs_match_the_table(pointmass_table, layout):
    vfilter = ValueFilter(pointmass_table, DT, margin=0.0, layout=layout)
    assert vfilter.field.layout == layout
    rng = np.random.default_rng(0)
    t, x, z = random_queries(rng, 3000, pointmass_table)
    ref = pointmass_table.value(t, x, z)
    mine = vfilter.value(t, x, z)
    assert np.isinf(ref).sum() > 100 and np.isfinite(ref).sum() > 1000  # both kinds of query were drawn
    np.testing.assert_array_equal(np.isinf(mine), np.isinf(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(mine[fin], ref[fin], rtol=0, atol=1e-9)

    X = np.c_[x, z]
    _, grad, _ = vfilter.field.value_and_gradient(t, X)
    np.testing.assert_allclose(grad, pointmass_table.gradient(t, x, z)[:, :2], rtol=0, atol=1e-9)
    # bang-bang inputs: identical wherever the switching function is not within rounding of zero
    clear = np.abs(grad[:, 0]) > 1e-9
    a_ref, a_mine = pointmass_table.optimal_control(t, x, z), vfilter.optimal_action(t, x, z)
    np.testing.assert_array_equal(a_mine[clear], a_ref[clear])
    b_ref, b_mine = pointmass_table.worst_disturbance(t, x, z), vfilter.worst_disturbance(t, x, z)
    np.testing.assert_array_equal(b_mine[clear], b_ref[clear])


@pytest.mark.parametrize("layout", ["stacked", "stencil"])
def test_single_query_path_matches_the_batch_path(pointmass_table, layout):
    vfilter = ValueFilter(pointmass_table, DT, layout=layout)
    rng = np.random.default_rng(1)
    t, x, z = random_queries(rng, 400, pointmass_table, spread=1.0)
    a = rng.uniform(-70, 70, (400, 1))  # some beyond the control box: clipped alike
    applied, info = vfilter.filter(t, x, z, a)
    fast = 0
    for i in range(400):
        fast += vfilter._filter_single(float(t[i]), x[i], float(z[i]), a[i], False) is not None
        ai, ii = vfilter.filter(float(t[i]), x[i], float(z[i]), a[i])
        np.testing.assert_allclose(ai, applied[i], rtol=0, atol=1e-12)
        for key in info:
            np.testing.assert_allclose(np.asarray(ii[key], dtype=float), np.asarray(info[key][i], dtype=float),
                                       rtol=0, atol=1e-9, err_msg=key)
    assert fast > 300  # the scalar path answered most queries (edge cells go to the batch path)


# ------------------------------------------------------------------------------------------ margin
def one_period(model, x, a, b, dt, substeps=8):
    """RK4 over one control period with held inputs (the environments' integration)."""
    h = dt / substeps

    def f(xx):
        return model.f_array(0.0, xx, a, b)

    for _ in range(substeps):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def test_margin_bounds_the_value_change_over_one_period(pointmass_table, vfilter):
    """The margin's motion part: from any query, any action and any wind held for one period move W~ by less
    than the margin (the interpolation terms only add to it)."""
    model = pointmass_table.model
    rng = np.random.default_rng(2)
    n = 4000
    t = rng.uniform(0, pointmass_table.horizon - DT, n)
    x = np.c_[rng.uniform(-16, 16, n), rng.uniform(-1, 19, n)]
    z = rng.uniform(0.0, 1.0, n)
    margin = vfilter.margin(t, x, z)
    finite = np.isfinite(margin)
    assert finite.mean() > 0.9
    w0 = vfilter.value(t, x, z)
    worst = np.zeros(n)
    u_max, d_max = model.params.u_max, model.params.d_max
    for a in (-u_max, 0.0, u_max):
        for b in (-d_max, d_max):
            x1 = one_period(model, x, np.full((n, 1), a), np.full((n, 1), b), DT)
            # the budget drains at most at unit rate; both ends of that range
            for z1 in (z, z - DT):
                w1 = vfilter.value(t + DT, x1, z1)
                worst = np.maximum(worst, np.abs(w1 - w0))
    ok = finite & np.isfinite(worst)
    assert ok.sum() > 3000
    excess = worst[ok] - margin[ok]
    assert excess.max() <= 1e-9, f"value moved by more than the margin: {excess.max()}"


def test_margin_is_local_and_the_policy_has_room(pointmass_table, vfilter):
    """Deep inside RA~_Q (Q > 0) a good share of the safe nodes pass the policy; the constant one-Lipschitz
    margin of the whole table would leave none."""
    xs = grid_states(pointmass_table)
    s = vfilter.margin_field.summary()
    global_margin = sum(v for k, v in s["terms_max"].items() if k.startswith("motion_")) + s["terms_max"]["time"]
    for q in (0.06, 0.3, 0.6):
        w = vfilter.value(0.0, xs, q)
        m = vfilter.margin(0.0, xs, q)
        safe = w <= 0
        deep = w <= -m
        assert safe.sum() > 100
        assert deep.sum() >= 0.3 * safe.sum(), (q, deep.sum(), safe.sum())
        assert not (w <= -global_margin).any()


def test_pooled_margin_field_is_conservative(pointmass_table, vfilter):
    """A memory budget too small for one margin per cell max-pools blocks of cells: never a smaller margin."""
    full = vfilter.margin_field.field
    small = ValueFilter(pointmass_table, DT, max_margin_bytes=full.nbytes // 5)
    assert small.margin_field.pool[0] >= 2 and small.margin_field.field.nbytes <= full.nbytes // 5
    rng = np.random.default_rng(8)
    t, x, z = random_queries(rng, 3000, pointmass_table, spread=0.95)
    m_full, m_small = vfilter.margin(t, x, z), small.margin(t, x, z)
    assert np.all(m_small >= m_full)
    assert np.mean(m_small > m_full) > 0.1  # pooling did coarsen it


def test_zero_budget_is_never_deep(pointmass_table, vfilter):
    """W_eps(t, x, 0) >= 0 (the budget term), so with no budget left the filter always applies a*."""
    xs = grid_states(pointmass_table)
    rng = np.random.default_rng(3)
    for t in (0.0, 0.35, 0.8):
        a = rng.uniform(-60, 60, (len(xs), 1))
        applied, info = vfilter.filter(t, xs, 0.0, a)
        assert info["active"].all()
        np.testing.assert_array_equal(applied, info["optimal_action"])


def test_constant_margin_override(pointmass_table):
    vf = ValueFilter(pointmass_table, DT, margin=0.1)
    xs = grid_states(pointmass_table)
    w = vf.value(0.2, xs, 0.3)
    a = np.full((len(xs), 1), 17.0)
    applied, info = vf.filter(0.2, xs, 0.3, a)
    np.testing.assert_array_equal(info["margin"], 0.1)
    np.testing.assert_array_equal(~info["active"], w <= -0.1)
    np.testing.assert_array_equal(applied[w <= -0.1], 17.0)


# ------------------------------------------------------------------------------------------ rules
def test_switch_rule():
    value = np.array([-1.0, -0.2, 0.5, np.nan, -np.inf, np.inf])
    margin = np.array([0.5, 0.5, 0.0, 0.1, np.inf, 0.0])
    pol = np.arange(6.0)[:, None]
    opt = -np.arange(6.0)[:, None] - 10
    applied, active = switch_rule(value, margin, pol, opt)
    # deep; too shallow; outside the set; NaN value (unsafe); -inf <= -inf passes; +inf (outside the table)
    expect_pass = np.array([True, False, False, False, True, False])
    np.testing.assert_array_equal(~active, expect_pass)
    np.testing.assert_array_equal(applied[:, 0], np.where(expect_pass, pol[:, 0], opt[:, 0]))


def test_smooth_rule_finds_the_closest_admissible_blend():
    """With an affine prediction the admissible blends are an interval [0, lam*]; bisection finds lam*."""
    rng = np.random.default_rng(4)
    n = 200
    value = rng.uniform(-0.5, 0.5, n)
    margin = np.full(n, 0.3)
    a_opt = rng.uniform(-1, 1, (n, 2))
    a_pol = rng.uniform(-1, 1, (n, 2))
    slope = rng.uniform(0.1, 2.0, n)
    lam_true = rng.uniform(-0.2, 1.2, n)  # < 0: even a* fails; > 1: the policy passes

    def predict(rows, a):
        # predicted value = current value + slope * (lam - lam_true) along the segment of each row
        d = a_pol[rows] - a_opt[rows]
        lam = np.sum((a - a_opt[rows]) * d, axis=1) / np.sum(d * d, axis=1)
        return value[rows] + slope[rows] * (lam - lam_true[rows])

    applied, lam = smooth_rule(value, margin, a_pol, a_opt, predict, iterations=12)
    deep = value <= -margin
    np.testing.assert_array_equal(lam[deep], 1.0)
    np.testing.assert_array_equal(applied[deep], a_pol[deep])
    rest = ~deep
    expect = np.clip(lam_true, 0.0, 1.0)
    expect[rest & (lam_true < 0)] = 0.0
    assert np.all(np.abs(lam[rest] - expect[rest]) <= 2.0 ** -12)
    assert np.all(lam[rest] <= np.maximum(expect[rest], 0) + 1e-15)  # never beyond the admissible end
    np.testing.assert_allclose(applied, a_opt + lam[:, None] * (a_pol - a_opt), atol=1e-12)


def test_smooth_filter_keeps_the_predicted_value_from_increasing(pointmass_table):
    vf = ValueFilter(pointmass_table, DT, rule="smooth")
    xs = grid_states(pointmass_table)
    rng = np.random.default_rng(5)
    t, q = 0.3, 0.3
    a = rng.uniform(-60, 60, (len(xs), 1))
    applied, info = vf.filter(t, xs, q, a)
    w, m = info["value"], info["margin"]
    deep = w <= -m
    np.testing.assert_array_equal(applied[deep], a[deep])
    blend = info["reason"] == BLEND
    assert blend.sum() > 10  # the smooth rule does move actions part of the way somewhere
    # applied actions lie between a* and the policy's action
    lo = np.minimum(a, info["optimal_action"]) - 1e-9
    hi = np.maximum(a, info["optimal_action"]) + 1e-9
    assert np.all((applied >= lo) & (applied <= hi))
    # for the blends, the worst predicted value after one period does not exceed the current one
    rows = np.nonzero(blend)[0]
    winds = np.concatenate([vf.worst_disturbance(t, xs[rows], q)[:, None, :],
                            np.broadcast_to(vf.wind_corners, (len(rows),) + vf.wind_corners.shape)], axis=1)
    pred = vf.predicted_value(np.full(len(rows), t), xs[rows], np.full(len(rows), q), applied[rows], winds)
    assert np.all(pred <= w[rows] + 1e-12)
    # and the switch rule would have applied a* there: the smooth rule is less restrictive
    _, sw = ValueFilter(pointmass_table, DT).filter(t, xs, q, a)
    assert sw["active"][rows].all()


# ------------------------------------------------------------------------------------------ special cases
def test_outside_after_horizon_and_below_budget_never_crash(vfilter):
    x = np.array([[0.0, 5.0], [25.0, 5.0], [0.0, -7.0], [0.0, 5.0], [0.0, 5.0], [0.0, 5.0]])
    t = np.array([0.2, 0.2, 0.2, 1.5, 0.2, -0.1])
    z = np.array([0.3, 0.3, 0.3, 0.3, -0.5, 0.3])
    a = np.full((6, 1), 5.0)
    applied, info = vfilter.filter(t, x, z, a)
    assert np.isfinite(applied).all()
    np.testing.assert_array_equal(info["reason"][1:], [OUTSIDE, OUTSIDE, AFTER_HORIZON, OUTSIDE, OUTSIDE])
    assert np.isinf(info["value"][1:]).all() and info["active"][1:].all()
    np.testing.assert_array_equal(applied[1:], info["optimal_action"][1:])


def test_nonfinite_table_values_are_unsafe(pointmass_table_path):
    table = load_table(pointmass_table_path)
    vals = np.array(table.values("W_eps"))
    g = table.grid("W_eps")
    iv = int(round((0.0 - g.lo[0]) / g.spacing[0]))
    iy = int(round((5.0 - g.lo[1]) / g.spacing[1]))
    vals[:, iv - 2:iv + 3, iy - 2:iy + 3, :] = np.nan  # a NaN hole around (v, y) = (0, 5)
    table._arrays["W_eps"] = vals
    vf = ValueFilter(table, DT, margin=0.05, fallback_action=[25.0])
    applied, info = vf.filter(0.2, np.array([[0.0, 5.0], [0.0, 5.0 + 2.5 * g.spacing[1]]]), 0.3,
                              np.array([[3.0], [3.0]]))
    assert info["reason"][0] == FALLBACK and applied[0, 0] == 25.0  # NaN value and NaN gradient
    assert info["active"].all()
    assert info["reason"][1] in (NONFINITE, FALLBACK)
    # the computed margin marks the hole's neighbourhood as never passing
    vf2 = ValueFilter(table, DT)
    assert np.isinf(vf2.margin(0.2, [0.0, 5.0 + 3.5 * g.spacing[1]], 0.3))


def test_reason_codes_inside(vfilter, pointmass_table):
    xs = grid_states(pointmass_table)
    a = np.zeros((len(xs), 1))
    _, info = vfilter.filter(0.1, xs, 0.3, a)
    r = info["reason"]
    assert set(np.unique(r)) <= {PASS, OPTIMAL, OUTSIDE}
    np.testing.assert_array_equal(r == PASS, ~info["active"])


# ------------------------------------------------------------------------------------------ inputs and errors
@pytest.mark.parametrize("bad, match", [
    (dict(x=[np.nan, 1.0]), "x must be finite"),
    (dict(action=[np.inf]), "action must be finite"),
    (dict(t=np.nan), "t must be finite"),
    (dict(z=np.inf), "z must be finite"),
    (dict(x=[1.0, 2.0, 3.0]), r"x must have shape \(N, 2\)"),
    (dict(action=[[1.0], [2.0]]), "action must have shape"),
    (dict(z=[0.1, 0.2]), r"z must be a scalar or have shape \(1,\)"),
])
def test_bad_inputs_raise(vfilter, bad, match):
    args = dict(t=0.1, x=[0.0, 5.0], z=0.3, action=[1.0])
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        vfilter.filter(**args)


def test_construction_errors(pointmass_table):
    with pytest.raises(TableError, match="d_max"):
        ValueFilter(pointmass_table, DT, model=get_model("pointmass", d_max=5.0))
    with pytest.raises(TableError, match="glider"):
        ValueFilter(pointmass_table, DT, model=get_model("glider"))
    with pytest.raises(ValueError, match="rule"):
        ValueFilter(pointmass_table, DT, rule="clip")
    with pytest.raises(ValueError, match="margin"):
        ValueFilter(pointmass_table, DT, margin=-0.1)
    with pytest.raises(ValueError, match="dt"):
        ValueFilter(pointmass_table, 0.0)
    with pytest.raises(ValueError, match="fallback_action"):
        ValueFilter(pointmass_table, DT, margin=0.0, fallback_action=[1.0, 2.0])


def test_normalized_actions_match_physical(vfilter, pointmass_table):
    rng = np.random.default_rng(6)
    t, x, z = random_queries(rng, 500, pointmass_table, spread=0.8)
    a_norm = rng.uniform(-1.2, 1.2, (500, 1))
    phys, info = vfilter.filter(t, x, z, 60.0 * np.clip(a_norm, -1, 1))
    norm, info_n = vfilter.filter(t, x, z, a_norm, normalized=True)
    np.testing.assert_array_equal(info["active"], info_n["active"])
    np.testing.assert_allclose(norm[info["active"]] * 60.0, phys[info["active"]], atol=1e-9)
    np.testing.assert_array_equal(norm[~info["active"]], a_norm[~info["active"]])  # the policy's own numbers
    np.testing.assert_allclose(info_n["optimal_action"] * 60.0, info["optimal_action"], atol=1e-9)


def test_torch_in_torch_out(vfilter, pointmass_table):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(7)
    t, x, z = random_queries(rng, 64, pointmass_table, spread=0.9)
    a = rng.uniform(-1, 1, (64, 1))
    ref, ref_info = vfilter.filter(t, x, z, a, normalized=True)
    for dtype in (torch.float32, torch.float64):
        out, info = vfilter.filter(torch.tensor(t, dtype=dtype), torch.tensor(x, dtype=dtype),
                                   torch.tensor(z, dtype=dtype), torch.tensor(a, dtype=dtype), normalized=True)
        assert isinstance(out, torch.Tensor) and out.dtype == dtype and out.device.type == "cpu"
        assert out.shape == (64, 1)
        assert info["active"].dtype == torch.bool and info["reason"].dtype == torch.int64
        assert info["value"].dtype == dtype and info["optimal_action"].dtype == dtype
        tol = 1e-6 if dtype == torch.float32 else 1e-12
        # float32 inputs shift the queries by rounding; compare where the decision is not within rounding
        clear = np.abs(ref_info["value"] + ref_info["margin"]) > 1e-3
        np.testing.assert_array_equal(info["active"].numpy()[clear], ref_info["active"][clear])
        np.testing.assert_allclose(out.numpy()[clear], ref[clear], atol=tol, rtol=0)
    one, one_info = vfilter.filter(0.1, torch.tensor([0.0, 5.0]), 0.3, torch.tensor([0.5]))
    assert isinstance(one, torch.Tensor) and one.shape == (1,) and one_info["value"].shape == ()


def test_torch_on_gpu_when_available(vfilter):
    torch = pytest.importorskip("torch")
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    x = torch.tensor([[0.0, 5.0], [1.0, 3.0]], device="cuda")
    a = torch.tensor([[0.2], [-0.4]], device="cuda")
    out, info = vfilter.filter(0.1, x, 0.3, a, normalized=True)
    assert out.device.type == "cuda" and info["active"].device.type == "cuda"
    ref, _ = vfilter.filter(0.1, x.cpu().numpy(), 0.3, a.cpu().numpy(), normalized=True)
    np.testing.assert_allclose(out.cpu().numpy(), ref, atol=1e-6)
