"""The sampled-data filter's core: enclosures, the next value, the one-period test, the rules, inputs."""

from __future__ import annotations

import numpy as np
import pytest

from reference_decision import ReferenceDecision
from softreach.reach.sim.integrator import integrate_period
from softreach.filters import AFTER_HORIZON, BLEND, OPTIMAL, OUTSIDE, PASS, UNCERTIFIED, ValueFilter
from softreach.reach import TableError, get_model, load_table
from softreach.reach.tables.interpolation import interpolate

DT = 0.01


@pytest.fixture(scope="module")
def vfilter(pointmass_held_table):
    return ValueFilter(pointmass_held_table, DT)


def by_reference(vf, t, x, z, a):
    """``(passes, keeps, next value)`` of holding each row's action ``a`` from its state, by the slow reference of
    ``docs/filters.md`` (``tests/reference_decision.py``): the one-period test, and whether the next state is
    certified whatever the wind does (what the filter asks of the policy's action)."""
    ref = ReferenceDecision(vf)
    out = []
    for ti, xi, zi, ai in zip(np.broadcast_to(t, (len(x),)), x, np.broadcast_to(z, (len(x),)), a):
        v = ref.judge(float(ti), xi, xi, float(zi), np.asarray(ai, dtype=np.float64))
        out.append((v.passes, ref.keeps(float(ti), v, float(zi), slabs=True), ref._next(v)))
    return tuple(np.array(c) for c in zip(*out))


def certified_states(vf, q, n, seed=0, t=0.0):
    rng = np.random.default_rng(seed)
    x = rng.uniform([-15, 0], [15, 18], (4000, 2))
    ok, _, _ = vf.certify(t, x, q)
    assert ok.sum() >= n, f"only {ok.sum()} certified states"
    return x[ok][:n]


# ------------------------------------------------------------------------------------------ enclosures
def test_pointmass_enclosure_holds_every_switching_wind_and_is_tight():
    model = get_model("pointmass")
    rng = np.random.default_rng(0)
    x = rng.uniform([-14, 1], [14, 17], (60, 2))
    a = rng.uniform(-60, 60, (60, 1))
    tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure(0.0, x, a, DT)
    pieces = 20
    for i in range(len(x)):
        ends = []
        for trial in range(8):
            winds = rng.choice([-10.0, 10.0], size=pieces) if trial > 1 else np.full(pieces, 10.0 * (2 * trial - 1))
            xs = list(x[i])
            for j in range(pieces):
                xs, _, _, _ = integrate_period(model, j * DT / pieces, xs, [a[i, 0]], [winds[j]], DT / pieces, 2,
                                            1e-3, 1e-6)
                assert np.all(np.array(xs) >= tube_lo[i] - 1e-9) and np.all(np.array(xs) <= tube_hi[i] + 1e-9)
            ends.append(xs)
        ends = np.array(ends)
        assert np.all(ends >= end_lo[i] - 1e-9) and np.all(ends <= end_hi[i] + 1e-9)
        # constant extreme winds reach the end box's bounds: it is the tightest box
        np.testing.assert_allclose(ends[:2].min(axis=0), end_lo[i], atol=1e-9)
        np.testing.assert_allclose(ends[:2].max(axis=0), end_hi[i], atol=1e-9)


def test_pointmass_pieces_cover_the_period():
    model = get_model("pointmass")
    x, a = np.array([[-10.05, 5.0]]), np.array([[40.0]])
    lo, hi = model.held_tube_pieces(0.0, x, a, DT, 4)
    t_lo, t_hi, _, _ = model.held_enclosure(0.0, x, a, DT)
    np.testing.assert_allclose(lo.min(axis=0), t_lo)
    np.testing.assert_allclose(hi.max(axis=0), t_hi)
    # outside C2 (v < -10) only early in the period: the later pieces lie inside and cost no budget
    assert lo[0, 0, 0] < -10 and lo[-1, 0, 0] > -10


@pytest.mark.parametrize("eps", [None, 0.5], ids=["table_eps", "eps_0.5"])
def test_a_period_spends_budget_only_where_its_box_may_leave_c2(vfilter, pointmass_held_table, eps):
    """The one-period test charges a period's pieces only where its whole box may leave ``C2``: inside, the budget
    is kept to the bit; where it may leave, the pieces' charge, the same to the bit in the compiled bounds (the
    filter's and the cells' builder's, :mod:`softreach.reach.proof.period`) and in the reference transcribed from
    ``docs/filters.md``. On states on both sides of the soft limit ``v = -10`` and far from it, at the budgets the
    decision uses. With the table's ``h_eps`` width (``1e-3``) nearly every piece is charged all or nothing; with a
    width of 0.5 most are charged a fraction, where an order of the sum would show."""
    if eps is not None:
        from softreach.reach.proof.cell_certificate import CellCertificate
        from softreach.reach.proof.lookahead import Lookahead

        la = Lookahead.from_table(pointmass_held_table, pointmass_held_table.model, DT, eps)
        vfilter = ValueFilter(pointmass_held_table, DT, eps=eps, landing_cells=CellCertificate.empty(la))
    la = vfilter.lookahead
    rng = np.random.default_rng(3)
    x = np.c_[np.r_[rng.uniform(-10.8, -9.2, 300), rng.uniform(-14, 14, 300)], rng.uniform(1, 17, 600)]
    a = rng.uniform(-60, 60, (600, 1))
    z = rng.uniform(0.0, 0.6, 600)
    # the filter's compiled one-period test: its end budget
    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import judge

    fast = vfilter.compiled
    work = decision_space(la.n, 1, len(fast.cands))[0].work
    lo, hi = np.empty(la.n), np.empty(la.n)
    z_end = np.array([judge(fast.enclose, fast.M, fast.C, 0.0, x[r], x[r], z[r], a[r], lo, hi, work).z_end
                      for r in range(600)])
    ref = ReferenceDecision(vfilter)
    tubes = [ref.boxes(x[r], x[r], a[r], 0.0, DT) for r in range(600)]
    # inside: the tube, and the box of the states the env computes widened by its rounding, lie in C2
    inside = np.array([not ref.may_spend(x[r], x[r], a[r], DT, *tubes[r]) for r in range(600)])
    assert all(ref.set_max("soft_constraint", *tubes[r]) <= 0 for r in np.flatnonzero(inside))
    # the pieces widened by the allowance for the env's rounding, and the budget allowance added
    charged = z - np.array([ref.spent(x[r], x[r], a[r], DT) for r in range(600)])
    assert inside.sum() > 200 and (~inside).sum() > 100 and (charged[~inside] < z[~inside]).sum() > 50
    np.testing.assert_array_equal(z_end[inside], z[inside])
    np.testing.assert_array_equal(z_end[~inside], charged[~inside])
    # the point mass's pieces lie in its period's box, so inside it they are charged nothing either
    np.testing.assert_array_equal(charged[inside], z[inside])
    if eps is not None:  # charges of a fraction of a piece's share, at most rows that spend
        shares = (z - charged)[~inside] / (DT / la.pieces)
        assert (np.abs(shares - np.round(shares)) > 1e-3).mean() > 0.5


# ------------------------------------------------------------------------------------------ the next value
def test_the_next_value_is_the_certificate_at_the_end_boxs_centre(pointmass_held_table):
    """The value that ranks an action (:func:`softreach.filters.judge.next_value`): ``min(V, W_eps)`` of the table's
    own interpolation at the end box's centre, at the budget the period may leave; ``+inf`` off the grid (a budget
    below the table's budget grid too)."""
    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import next_value

    table = pointmass_held_table
    vf = ValueFilter(table, 0.01)
    work = decision_space(2, 1, len(vf.compiled.cands))[0].work
    fields = {f: (table.values(f), table.times(f), table.grid(f)) for f in ("V", "W_eps")}
    z_top = fields["W_eps"][2].hi[-1]
    rng = np.random.default_rng(1)
    times = fields["W_eps"][1]
    for i in range(200):
        lo = rng.uniform([-15, 0], [14, 17])
        hi = lo + rng.uniform([0, 0], [0.5, 0.3])
        z = rng.uniform(0, 0.9)
        t = float(times[30]) if i % 2 else 0.3 * times[30] + 0.7 * times[31]  # between snapshots: a blend
        c = 0.5 * (lo + hi)
        w, _ = interpolate(*fields["W_eps"], np.array([t]), np.r_[c, min(z, z_top)][None])
        v, _ = interpolate(*fields["V"], np.array([t]), c[None])
        got = next_value(vf.compiled.T, t, lo, hi, z, work)
        assert got == pytest.approx(min(w[0], v[0]), abs=1e-9), (i, got, w[0], v[0])
    lo, hi = np.array([19.5, 5.0]), np.array([21.0, 5.1])  # its centre lies past the grid's 20 m/s
    assert next_value(vf.compiled.T, 0.1, lo, hi, 0.3, work) == np.inf
    assert next_value(vf.compiled.T, 0.1, np.array([0.0, 5.0]), np.array([0.1, 5.1]), -0.2, work) == np.inf


# ------------------------------------------------------------------------------------------ the held game
def test_held_sets_lie_inside_the_continuous_sets_and_grow_with_the_budget(pointmass_held_table, pointmass_table):
    assert pointmass_held_table.control_period == DT and pointmass_table.control_period is None
    held = [pointmass_held_table.set_measure(0.0, q) for q in (0.0, 0.06, 0.3, 0.6)]
    cont = [pointmass_table.set_measure(0.0, q) for q in (0.0, 0.06, 0.3, 0.6)]
    assert all(b >= a for a, b in zip(held, held[1:]))
    # holding the action for 10 ms can only lose states (same grid and scheme)
    assert all(h <= c for h, c in zip(held, cont)), (held, cont)
    # Prop. 3 for the held game, up to the grid: a state whose box of one grid cell each way lies in either set
    # ({V <= 0}, or RA~_0 of W_eps) is in the other
    t = pointmass_held_table
    x = np.random.default_rng(0).uniform([-20.0, -5.0], [20.0, 20.0], (20000, 2))
    step = np.asarray(t.grid("V").spacing)
    box = [np.array([a, b]) * step for a in (-1, 0, 1) for b in (-1, 0, 1)]
    in_v, in_w = (lambda p: t.contains(0.0, p)), (lambda p: t.contains(0.0, p, 0.0))
    for inside, other in ((in_v, in_w), (in_w, in_v)):
        deep = np.all([inside(x + d) for d in box], axis=0)
        assert deep.sum() > 1000 and other(x[deep]).all()


# ------------------------------------------------------------------------------------------ the filter
def test_the_policy_passes_exactly_when_its_held_period_keeps_the_state_certified(vfilter):
    rng = np.random.default_rng(2)
    x = rng.uniform([-15, 0], [15, 18], (300, 2))
    z = rng.choice([0.0, 0.06, 0.3], 300)
    t = rng.choice(np.arange(0, 95) * DT, 300)
    a = rng.uniform(-60, 60, (300, 1))
    applied, info = vfilter.filter(t, x, z, a)
    _, ok, nxt = by_reference(vfilter, t, x, z, a)
    np.testing.assert_array_equal(info["reason"] == PASS, ok)
    # where the policy passes, every end state of its held period is certified again, also where the end box
    # reaches D > 0 (the interpolant is conservative there): winds switching inside the period, then a
    # candidate must pass from each end state
    model = vfilter.model
    rows = np.nonzero(ok & (t < 0.9))[0][:80]
    wind_rng = np.random.default_rng(7)
    for winds in ([-10.0] * 4, [10.0] * 4, [10.0, 10.0, -10.0, -10.0], list(wind_rng.choice([-10.0, 10.0], 4))):
        ends, zs = [], []
        for i in rows:
            xs, zi = list(x[i]), z[i]
            for j, w in enumerate(winds):
                xs, cost, _, _ = integrate_period(model, t[i] + j * DT / 4, xs, [a[i, 0]], [w], DT / 4, 2, 1e-3, 1e-6)
                zi -= cost
            ends.append(xs)
            zs.append(zi)
        again = vfilter.certify(t[rows] + DT, np.array(ends), np.array(zs))[0]
        assert again.all(), (x[rows][~again], winds)
    np.testing.assert_array_equal(applied[ok], a[ok])  # the policy's own numbers
    # the next value of a passing action: the reference's interpolant is read by another engine, a rounding away
    np.testing.assert_allclose(info["lookahead"][ok], nxt[ok], rtol=1e-9, atol=1e-12)
    assert ok.any() and (~ok).any()


def test_a_certified_state_gets_an_action_that_passes(vfilter):
    for q in (0.0, 0.3):
        x = certified_states(vfilter, q, 150, seed=3)
        a = np.full((len(x), 1), -60.0)  # full down: often refused
        applied, info = vfilter.filter(0.0, x, q, a)
        ok, keeps, _ = by_reference(vfilter, 0.0, x, q, applied)
        # every applied action passes the one-period test or keeps the next state certified (the policy's rule)
        assert (ok | keeps).all() and keeps[info["reason"] == PASS].all() and info["certified"].all()
        assert set(np.unique(info["reason"])) <= {PASS, OPTIMAL}
        assert (info["reason"] == OPTIMAL).any()


def test_the_policy_acts_at_zero_budget(vfilter):
    x = certified_states(vfilter, 0.0, 100, seed=4)
    _, info = vfilter.filter(0.0, x, 0.0, np.full((len(x), 1), 9.8))  # hover
    assert (info["reason"] == PASS).mean() > 0.5


def test_smooth_rule_moves_the_action_less_and_still_passes(pointmass_held_table, vfilter):
    smooth = ValueFilter(pointmass_held_table, DT, rule="smooth")
    x = certified_states(vfilter, 0.3, 150, seed=5)
    a = np.full((len(x), 1), -60.0)
    sw, si = vfilter.filter(0.0, x, 0.3, a)
    sm, mi = smooth.filter(0.0, x, 0.3, a)
    assert np.all(np.abs(sm - a) <= np.abs(sw - a) + 1e-9)
    one, keeps, _ = by_reference(smooth, 0.0, x, 0.3, sm)
    assert (one | keeps).all() and (mi["reason"] == BLEND).any()


def test_outside_after_horizon_and_negative_budget_are_not_certified(vfilter):
    x = np.array([[0.0, 5.0], [25.0, 5.0], [0.0, -7.0], [0.0, 5.0], [0.0, 5.0]])
    t = np.array([0.2, 0.2, 0.2, 1.5, 0.2])
    z = np.array([0.3, 0.3, 0.3, 0.3, -0.5])
    applied, info = vfilter.filter(t, x, z, np.full((5, 1), 5.0))
    assert np.isfinite(applied).all()
    np.testing.assert_array_equal(info["reason"][1:4], [OUTSIDE, OUTSIDE, AFTER_HORIZON])
    assert info["reason"][4] in (UNCERTIFIED, OUTSIDE)
    assert not info["certified"][1:].any() and np.isinf(info["value"][1:]).all()
    ok, why, _ = vfilter.certify(t, x, z)
    assert ok[0] and not ok[1:].any()
    assert why[1:4] == ["outside_table", "outside_table", "after_horizon"]


def test_certify_start_adds_only_starts_plans_to_certify(vfilter, pointmass_held_table):
    """``certify_start`` certifies what ``certify`` does, and more only where it found a plan; without plans
    (``start_periods=0``) it is ``certify``; no states, no plans."""
    x = np.random.default_rng(8).uniform([-15, 0], [15, 18], (3000, 2))
    ok, why, nxt = vfilter.certify(0.0, x, 0.06)
    ok2, why2, nxt2, plans = vfilter.certify_start(0.0, x, 0.06)
    planned = plans[:, 0, 0] >= 0
    assert planned.any() and (ok2 == (ok | planned)).all() and not (ok & planned).any()
    # the point mass holds one candidate only (Model.start_segments)
    assert (plans[:, 1, 0] < 0).all()
    assert [w for w, p in zip(why2, planned) if not p] == [w for w, p in zip(why, planned) if not p]
    np.testing.assert_array_equal(nxt, nxt2)
    none = ValueFilter(pointmass_held_table, DT, start_periods=0)
    ok3, why3, _, plans3 = none.certify_start(0.0, x, 0.06)
    assert (ok3 == ok).all() and why3 == why and (plans3[:, :, 0] < 0).all()
    empty = vfilter.certify_start(0.0, np.zeros((0, 2)), 0.06)
    assert empty[0].shape == (0,) and empty[0].dtype == bool and empty[3].shape == (0, 2, 3)


def test_the_cells_not_the_table_decide_what_is_certified(pointmass_table, pointmass_held_table):
    """The cells prove and the table only ranks: a table solved in continuous time certifies exactly the states
    that one of the sampled-data game on the same grid does. Without landing cells there is no filter."""
    x = np.random.default_rng(3).uniform([-15.0, 0.0], [15.0, 18.0], (1500, 2))
    cont, held = ValueFilter(pointmass_table, DT), ValueFilter(pointmass_held_table, DT)
    assert pointmass_table.control_period is None and cont.landing_cells is not None
    counts = []
    for t in (0.0, 0.5, 0.9):
        for q in (0.0, 0.3):
            ok_cont, ok_held = cont.certify(t, x, q)[0], held.certify(t, x, q)[0]
            np.testing.assert_array_equal(ok_cont, ok_held)
            counts.append(int(ok_cont.sum()))
    assert min(counts) > 0 and max(counts) < len(x), counts
    with pytest.raises(ValueError, match="landing_cells must be 'auto' or a CellCertificate, got None"):
        ValueFilter(pointmass_table, DT, landing_cells=None)


def test_nonfinite_table_values_are_unsafe(pointmass_held_table):
    table = load_table(pointmass_held_table.path)
    for name in ("W_eps", "V"):
        vals = np.array(table.values(name))
        g = table.grid(name)
        iv = int(round((0.0 - g.lo[0]) / g.spacing[0]))
        iy = int(round((5.0 - g.lo[1]) / g.spacing[1]))
        vals[:, iv - 2:iv + 3, iy - 2:iy + 3] = np.nan  # a NaN hole around (v, y) = (0, 5)
        table._arrays[name] = vals
    # the cells do not read the table: their proof stands, and the hole is reported as unsafe, not NaN
    vf = ValueFilter(table, DT)
    applied, info = vf.filter(0.2, [0.0, 5.0], 0.3, [3.0])
    assert info["certified"] and np.isfinite(applied).all() and info["value"] == np.inf


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


@pytest.mark.parametrize("rows", [1, 4, 20])
@pytest.mark.parametrize("name, bad", [("x", -np.inf), ("t", np.nan), ("z", np.inf), ("action", np.nan)])
def test_a_non_finite_entry_is_named_in_a_batch_of_any_size(vfilter, rows, name, bad):
    # a step's few numbers and a batch's many are checked by different code (reach/inputs.check_finite)
    args = dict(t=np.full(rows, 0.1), x=np.tile([0.0, 5.0], (rows, 1)), z=np.full(rows, 0.3),
                action=np.ones((rows, 1)))
    args[name] = args[name].copy()
    args[name][rows - 1] = bad
    with pytest.raises(ValueError, match=f"{name} must be finite, got .*(nan|inf).* at (row|index) {rows - 1}"):
        vfilter.filter(**args)


def test_construction_errors(pointmass_held_table):
    with pytest.raises(TableError, match="d_max"):
        ValueFilter(pointmass_held_table, DT, model=get_model("pointmass", d_max=5.0))
    with pytest.raises(TableError, match="glider"):
        ValueFilter(pointmass_held_table, DT, model=get_model("glider"))
    with pytest.raises(ValueError, match="rule"):
        ValueFilter(pointmass_held_table, DT, rule="clip")
    for bad in (-0.1, 0.1):  # the cells' proof compares no table value with a margin
        with pytest.raises(ValueError, match=f"margin must be None or 0.*got {bad!r}"):
            ValueFilter(pointmass_held_table, DT, margin=bad)
    with pytest.raises(ValueError, match="dt"):
        ValueFilter(pointmass_held_table, 0.0)
    with pytest.raises(ValueError, match="fallback_action"):
        ValueFilter(pointmass_held_table, DT, fallback_action=[1.0, 2.0])
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match=f"start_periods .*got {bad!r}"):
            ValueFilter(pointmass_held_table, DT, start_periods=bad)


def test_normalized_actions_match_physical(vfilter):
    rng = np.random.default_rng(6)
    x = rng.uniform([-15, 0], [15, 18], (300, 2))
    a_norm = rng.uniform(-1.2, 1.2, (300, 1))
    phys, info = vfilter.filter(0.1, x, 0.3, 60.0 * np.clip(a_norm, -1, 1))
    norm, info_n = vfilter.filter(0.1, x, 0.3, a_norm, normalized=True)
    np.testing.assert_array_equal(info["active"], info_n["active"])
    act = info["active"]
    np.testing.assert_allclose(norm[act] * 60.0, phys[act], atol=1e-9)
    np.testing.assert_array_equal(norm[~act], a_norm[~act])


def test_torch_in_torch_out(vfilter):
    import torch
    rng = np.random.default_rng(7)
    x = rng.uniform([-15, 0], [15, 18], (64, 2))
    a = rng.uniform(-1, 1, (64, 1))
    ref, ref_info = vfilter.filter(0.1, x, 0.3, a, normalized=True)
    out, info = vfilter.filter(0.1, torch.tensor(x), 0.3, torch.tensor(a), normalized=True)
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float64 and out.shape == (64, 1)
    assert info["active"].dtype == torch.bool and info["reason"].dtype == torch.int64
    np.testing.assert_array_equal(out.numpy(), ref)
    one, one_info = vfilter.filter(0.1, torch.tensor([0.0, 5.0]), 0.3, torch.tensor([0.5]))
    assert isinstance(one, torch.Tensor) and one.shape == (1,) and one_info["value"].shape == ()


def test_the_safety_value_keeps_c1_where_braking_can(pointmass_held_table):
    """``V_safe`` (:func:`~softreach.reach.problem.avoid_problem`) of the sampled-data game: stay in C1 until T.
    Falling at speed v from height y can be stopped before the ground iff v^2 / (2 (u_max - g - d_max)) < y (full
    thrust against the worst wind)."""
    from softreach.reach import SolverSettings
    from softreach.reach.numerics.held import solve_held
    from softreach.reach.problem import avoid_problem

    table = pointmass_held_table
    g = table.grid("V")
    spec = table.header["fields"]["V"]
    S = solve_held(avoid_problem(get_model("pointmass")), g, table.times("V"), SolverSettings(**spec["settings"]),
                   np.asarray(spec["held_controls"]))
    S = S.cpu().numpy() if hasattr(S, "cpu") else np.asarray(S)
    v, y = np.meshgrid(g.lo[0] + g.spacing[0] * np.arange(g.shape[0]), g.lo[1] + g.spacing[1] * np.arange(g.shape[1]),
                       indexing="ij")
    stop = v ** 2 / (2 * (60.0 - 9.8 - 10.0))
    inside_c1 = (np.abs(v) < 14.5) & (y > 0.1) & (y < 17.0)
    falling = inside_c1 & (v < 0)
    # clear cases, a cell away from the threshold either way
    can, cannot = falling & (stop < y - 1.0), falling & (stop > y + 1.0)
    assert can.sum() > 50 and cannot.sum() >= 3
    assert np.all(S[can] <= 0) and np.all(S[cannot] > 0)
    # every landing-certified node can also keep C1 (the sets are nested)
    V = np.asarray(table.values("V")[0])
    assert np.all(S[V <= -0.05] <= 0)


@pytest.mark.parametrize("rule", ["switch", "smooth"])
def test_a_row_is_decided_alone_as_in_a_batch(pointmass_held_table, rule):
    """A row's decision does not depend on the batch around it: 120 rows decided at once and each alone (the
    one-row entry) give the same actions and ``info``."""
    vf = ValueFilter(pointmass_held_table, DT, target_checks=10, rule=rule)
    rng = np.random.default_rng(11)
    N = 120
    x = np.c_[rng.uniform(-15, 15, N), rng.uniform(0, 18, N)]
    z, t, a = rng.uniform(0, 0.6, N), rng.uniform(0, 0.95, N), rng.uniform(-60, 60, (N, 1))
    batch, info = vf.filter(t, x, z, a)
    assert 0 < info["active"].sum() < N
    for i in range(N):
        one, one_info = vf.filter(t[i], x[i], z[i], a[i])
        assert np.array_equal(one, batch[i])
        for key in ("reason", "lookahead", "certified", "optimal_action"):
            assert np.array_equal(one_info[key], info[key][i], equal_nan=True), key


def test_the_smooth_rules_point_is_an_action_the_environment_applies(vfilter):
    """``ValueFilter.blend``, the smooth rule's point (the compiled decision and the tests' reference clip alike),
    maps a point of the normalised box ``[-1, 1]`` back as an environment does. A box whose top normalises one ulp
    above 1, ``(hi - mid) / half = 1 + 2^-52``, and a policy action at that top: unclipped, the point's image is
    ``hi``, which no normalised action maps to."""
    import copy

    from softreach.reach.proof.lookahead import exact_normalized

    lo, hi = -3.9450472042977047, -1.3488983175517144
    vf = copy.copy(vfilter)
    vf.a_mid, vf.a_half = np.array([0.5 * (lo + hi)]), np.array([0.5 * (hi - lo)])
    assert (hi - vf.a_mid[0]) / vf.a_half[0] > 1.0  # the box this test is about
    top = vf.a_mid + vf.a_half * 1.0  # the largest action the environment applies
    point = vf.blend(top[None, :], np.array([[hi]]), np.array([0.75]))
    q = exact_normalized(point, vf.a_mid, vf.a_half)
    assert -1.0 <= q[0, 0] <= 1.0 and vf.a_mid[0] + vf.a_half[0] * q[0, 0] == point[0, 0]
    assert point[0, 0] == top[0]
