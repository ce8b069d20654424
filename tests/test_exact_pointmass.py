"""The exact point-mass reference (``reach/numerics/exact_pointmass.py``), checked by means that do not share its
derivation, then used to grade a solved table.

* the analytic ceiling from rest (spec §4);
* Def. 1's structure: the sets grow with ``Q`` and with the time left, ``Q = 0`` is the classical set of
  ``C1 ∩ C2`` (Prop. 3), ``Q_min`` agrees with membership, with no time left the set is the target;
* optimality: a dynamic programme over discretised speed profiles never descends further than the claimed maximum
  and comes within its own discretisation error of it;
* sufficiency: the witness profile of every sampled member, played against random disturbances, lands without
  leaving ``C1`` or overspending; necessity: sampled bang-coast-bang profiles never save states just outside;
* grading: the coarse fixture table is sound up to one cell and within three cells of the exact boundary.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt

from softreach.reach import get_model
from softreach.reach.numerics.exact_pointmass import exact_mask, exact_member, exact_q_min, grade, max_descent, speed_profile
from softreach.reach.models import PointMassParams

from pointmass_ceiling import CEILING

P = PointMassParams()
D = P.u_max - P.d_max + P.gravity  # fastest downward acceleration of the control-only double integrator
U = P.u_max - P.d_max - P.gravity  # hardest braking
BUDGETS = (0.0, 0.06, 0.3, 0.6)


def _upper_edge(v: np.ndarray, q: np.ndarray, time_left: float = 1.0) -> np.ndarray:
    """The highest member altitude above each speed (NaN where the column holds no member), by bisection."""
    floor = np.where(v < P.target_speed[0], (v**2 - P.target_speed[0] ** 2) / (2 * U), 0.0)
    ok = exact_member(v, floor, q, time_left)
    lo, hi = floor.copy(), np.full_like(floor, P.altitude[1] + 1.0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        good = exact_member(v, mid, q, time_left)
        lo, hi = np.where(good, mid, lo), np.where(good, hi, mid)
    return np.where(ok, lo, np.nan)


def _time_outside(va: np.ndarray, vb: np.ndarray, dt, slack: float = 0.0) -> np.ndarray:
    """Exact time a linear speed ``va -> vb`` over ``dt`` spends outside the soft band (widened by ``slack``)."""
    lo, hi = P.soft_speed[0] - slack, P.soft_speed[1] + slack
    dv = vb - va
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - va) / dv, (hi - va) / dv
    a, b = np.minimum(t1, t2), np.maximum(t1, t2)
    inside = np.where(dv == 0, ((va >= lo) & (va <= hi)).astype(float),
                      np.clip(np.minimum(b, 1.0) - np.maximum(a, 0.0), 0.0, 1.0))
    return dt * (1.0 - inside)


def test_ceiling_from_rest_is_the_analytic_one():
    """The oracle's member edge above rest and the model's closed form equal the ceiling derived from the spec
    (tests/pointmass_ceiling.py). The bisection halves a 19 m bracket 60 times (1.6e-17 m); the membership test
    accepts every inequality up to its slack ``tol = 1e-9`` m, so the edge lies that much above the ceiling at
    most (and never below it), up to float rounding (1e-12 m at 10 m)."""
    top = _upper_edge(np.array([0.0]), np.array([0.0]))[0]
    assert -1e-12 <= top - CEILING <= 1e-9 + 1e-12
    assert get_model("pointmass").exact_ceiling() == pytest.approx(CEILING, abs=1e-9)
    # the budget lifts it: a plateau faster than 10 m/s for Q seconds
    lifted = _upper_edge(np.zeros(3), np.array([0.06, 0.3, 0.6]))
    assert np.all(np.diff(np.r_[top, lifted]) > 0)


def test_sets_grow_with_budget_and_time_left():
    rng = np.random.default_rng(1)
    v, y = rng.uniform(-16, 16, 20000), rng.uniform(-1, 19, 20000)
    budgets = (0.0, 0.01, 0.06, 0.3, 0.6, 1.0)
    masks = [exact_member(v, y, q) for q in budgets]
    for small, large in zip(masks, masks[1:]):
        assert not (small & ~large).any()
    assert masks[3].sum() > 1.3 * masks[0].sum()
    spans = [exact_member(v, y, 0.3, s) for s in (0.0, 0.2, 0.5, 1.0, 1.5)]
    for small, large in zip(spans, spans[1:]):
        assert not (small & ~large).any()
    target = (v >= P.target_speed[0]) & (v <= P.target_speed[1]) & (y >= 0) & (y <= P.target_altitude[1])
    assert np.array_equal(spans[0], target)


def test_zero_budget_is_the_classical_set_of_the_intersection():
    """Prop. 3: ``RA~_0`` is the reach-avoid set with constraint ``C1 ∩ C2``; with ``C1 = C2`` no budget helps."""
    v, y = np.meshgrid(np.linspace(-16, 16, 161), np.linspace(-1, 19, 201), indexing="ij")
    tight = PointMassParams(hard_speed=P.soft_speed)
    ra0 = exact_member(v, y, 0.0)
    assert ra0.sum() > 1000
    for q in (0.0, 0.3, 1.0):
        assert np.array_equal(exact_member(v, y, q, params=tight), ra0)
    assert np.isfinite(exact_q_min(v, y, params=tight)).sum() == ra0.sum()


def test_q_min_agrees_with_membership():
    rng = np.random.default_rng(2)
    v, y = rng.uniform(-16, 16, 5000), rng.uniform(-1, 19, 5000)
    s = rng.uniform(0.2, 1.2, 5000)
    qm = exact_q_min(v, y, s)
    assert np.array_equal(qm == 0, exact_member(v, y, 0.0, s))
    for q in BUDGETS[1:] + (rng.uniform(0, 1, 5000),):
        clear = np.abs(qm - q) > 1e-9
        assert np.array_equal(exact_member(v, y, q, s)[clear], (qm <= q)[clear])
    assert np.isfinite(qm).any() and (~np.isfinite(qm)).any()


def _dp_descent(v0: float, time_left: float, budget: float, dt: float = 0.01) -> float:
    """The largest descent over speed profiles that are linear on steps of ``dt`` between nodes of a speed grid.

    Each such profile is admissible (slopes within ``[-D, U]`` by the floors below; a step is charged in full to the
    budget when either end is outside the soft band, and costs nothing when both are inside, where the whole linear
    step is), so the optimum is a lower bound of the true maximum, found by exhaustive search (dynamic programming).
    """
    n = int(round(time_left / dt))
    dt = time_left / n
    dv = D * dt / 12  # full down-thrust is a whole number of speed cells per step
    lo_k, hi_k = np.ceil((P.hard_speed[0] - v0) / dv - 1e-9), np.floor((P.hard_speed[1] - v0) / dv + 1e-9)
    v = v0 + dv * np.arange(lo_k, hi_k + 1)
    i0 = int(np.argmin(np.abs(v - v0)))
    up, down = int(np.floor(U * dt / dv + 1e-9)), int(np.floor(D * dt / dv + 1e-9))
    nb = int(np.floor(budget / dt + 1e-9)) + 1
    out = (v < P.soft_speed[0]) | (v > P.soft_speed[1])
    val = np.full((nb, len(v)), -np.inf)
    val[0, i0] = 0.0
    for _ in range(n):
        new = np.full_like(val, -np.inf)
        for o in range(-down, up + 1):
            src = slice(max(0, -o), len(v) - max(0, o))
            dst = slice(max(0, o), len(v) + min(0, o))
            cand = val[:, src] - 0.5 * (v[src] + v[dst]) * dt
            charged = out[src] | out[dst]
            block = new[:, dst]
            block[:, ~charged] = np.maximum(block[:, ~charged], cand[:, ~charged])
            block[1:, charged] = np.maximum(block[1:, charged], cand[:-1, charged])
            new[:, dst] = block
        val = new
    land = (v >= P.target_speed[0]) & (v <= P.target_speed[1])
    return float(val[:, land].max())


@pytest.mark.parametrize("v0,time_left,budget", [(0.0, 1.0, 0.0), (0.0, 1.0, 0.3), (-6.0, 0.8, 0.06),
                                                 (4.0, 1.1, 0.45), (-12.5, 0.9, 0.2), (12.0, 1.0, 0.6)])
def test_no_discretised_profile_descends_further(v0, time_left, budget):
    """Optimality of the bang-coast-bang profile with one excursion below ``s_lo``, by exhaustive search."""
    exact = float(max_descent(v0, time_left, budget))
    dp = _dp_descent(v0, time_left, budget)
    assert dp <= exact + 1e-9
    # what the search gives away: up to two steps of budget charged in full at the excursion's ends (2 dt at the
    # 5 m/s the excursion gains), braking 1% softer (39.9 m/s^2: about 0.03 m over a 15 m/s stop) and the start
    # of the braking snapped to the speed grid (dv = 0.05 m/s over the horizon)
    assert exact - dp <= 2 * 0.01 * 5.0 + 0.03 + 0.05 * time_left


def _sample_members(rng, n: int):
    v = rng.uniform(-14.8, 14.8, n)
    q = rng.choice(np.array(BUDGETS), n)
    top = _upper_edge(v, q)
    keep = np.isfinite(top)
    v, q, top = v[keep], q[keep], top[keep]
    floor = np.where(v < -1, (v**2 - 1) / (2 * U), 0.0)
    return v, rng.uniform(floor, top), q


def test_witness_profiles_land_against_random_disturbances():
    """Sufficiency: the profile the derivation builds for a member lands it, whatever the disturbance does."""
    rng = np.random.default_rng(3)
    v0, y0, q = _sample_members(rng, 300)
    assert len(v0) > 200
    assert exact_member(v0, y0, q).all()
    # the horizon S' whose largest-descent profile ends inside the target's altitude band (sufficiency argument)
    start = np.where(v0 > 0, v0 / D, np.maximum(P.target_speed[0] - v0, 0.0) / U)
    final = lambda s: y0 - max_descent(v0, s, q)  # noqa: E731
    goal = np.clip(0.35, final(np.ones_like(v0)), final(start))
    lo, hi = start, np.ones_like(v0)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        above = final(mid) > goal
        lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
    horizon = hi
    n = 4000
    s = horizon[:, None] * np.linspace(0.0, 1.0, n + 1)[None, :]
    dt = horizon / n
    profile = speed_profile(s, v0[:, None], horizon[:, None], q[:, None])
    acc = np.diff(profile, axis=1) / dt[:, None]
    assert acc.min() >= -D - 1e-6 and acc.max() <= U + 1e-6
    d = rng.uniform(-P.d_max, P.d_max, acc.shape)
    u = acc + P.gravity - d
    assert np.abs(u).max() <= P.u_max + 1e-6
    vel = np.concatenate([v0[:, None], v0[:, None] + np.cumsum((u - P.gravity + d) * dt[:, None], axis=1)], axis=1)
    alt = np.concatenate([y0[:, None], y0[:, None] + np.cumsum(0.5 * (vel[:, 1:] + vel[:, :-1]) * dt[:, None], axis=1)],
                         axis=1)
    assert np.abs(vel).max() <= P.hard_speed[1] + 1e-6
    assert alt.min() >= -1e-6 and alt.max() <= P.altitude[1] + 1e-6
    assert (vel[:, -1] >= P.target_speed[0] - 1e-6).all() and (vel[:, -1] <= P.target_speed[1] + 1e-6).all()
    assert (alt[:, -1] >= -1e-6).all() and (alt[:, -1] <= P.target_altitude[1] + 1e-6).all()
    # the chord of the step across the profile's kink at the end of the excursion dips below s_lo: one step at most;
    # the slack absorbs the summation's rounding along the coast at s_lo
    spent = _time_outside(vel[:, :-1], vel[:, 1:], dt[:, None], slack=1e-9).sum(axis=1)
    assert (spent <= q + dt + 1e-9).all()
    assert np.allclose(alt[:, -1], final(horizon), atol=1e-4)


def _saved_by_sampling(v0, y0, q, rng, n_profiles: int = 2000, dt: float = 2e-3, time_left: float = 1.0):
    """Whether any of ``n_profiles`` sampled profiles lands each state. A profile changes speed as fast as it can
    to a random ``-c1`` in ``[-15, -1]``, holds it a random time, changes to a random ``-c2``, holds it until full
    braking would reach ``-1 m/s`` at a random altitude of the target band, then brakes: the shape of every stop,
    brake and largest descent above, with its speeds and lengths free. Motion, ``C1`` (with the altitude's dip inside
    a step) and budget are exact per step; landing is checked at step ends."""
    m, k = len(v0), n_profiles
    fast, soft = -P.hard_speed[0], -P.soft_speed[0]

    def speeds():
        # the optimum sits on the limits: half the draws there
        pick = rng.integers(0, 4, (m, k))
        return np.choose(pick, [np.full((m, k), fast), np.full((m, k), soft), rng.uniform(1.0, fast, (m, k)),
                                rng.uniform(1.0, fast, (m, k))])

    c1, c2 = speeds(), speeds()
    y_land = np.where(rng.random((m, k)) < 0.5, P.target_altitude[1], rng.uniform(0.0, P.target_altitude[1], (m, k)))
    v = np.repeat(v0[:, None], k, axis=1)
    y = np.repeat(y0[:, None], k, axis=1)
    reach = np.where(v > -c1, (v + c1) / D, (-c1 - v) / U)
    # half the holds spend exactly the budget left once the ramps below s_lo are paid for
    spent_on_ramps = (np.maximum(v - soft, 0.0) / D + np.maximum(c1 - np.maximum(soft, -v), 0.0) / D
                      + np.maximum(-v - np.maximum(c1, soft), 0.0) / U + np.maximum(c1 - soft, 0.0) / U)
    exhaust = q[:, None] - spent_on_ramps
    hold = np.where(rng.random((m, k)) < 0.5, np.maximum(exhaust, 0.0), rng.uniform(0.0, 0.8, (m, k)))
    switch = reach + hold
    alive = np.ones((m, k), bool)
    braking = np.zeros((m, k), bool)
    spent = np.zeros((m, k))
    saved = np.zeros((m, k), bool)
    for step in range(int(round(time_left / dt))):
        goal = np.where(step * dt < switch, -c1, -c2)
        braking |= (step * dt >= switch) & (v < -1) & (y - (v**2 - 1) / (2 * U) <= y_land)
        a = np.where(braking, U, np.clip((goal - v) / dt, -D, U))
        v1 = v + a * dt
        y1 = y + v * dt + 0.5 * a * dt**2
        with np.errstate(divide="ignore", invalid="ignore"):
            dip = np.where((v < 0) & (v1 > 0), y - v**2 / (2 * a), np.minimum(y, y1))
        spent += _time_outside(v, v1, dt)
        alive &= (np.abs(v1) <= P.hard_speed[1]) & (dip >= 0) & (np.maximum(y, y1) <= P.altitude[1])
        alive &= spent <= q[:, None] + 1e-9
        saved |= alive & (v1 >= P.target_speed[0]) & (v1 <= 0) & (y1 >= 0) & (y1 <= P.target_altitude[1])
        v, y = v1, y1
    return saved.any(axis=1)


@pytest.mark.parametrize("time_left", [1.0, 0.4])
def test_sampled_profiles_save_no_state_just_outside(time_left):
    """Necessity: states 1 to 30 cm above the upper edge, just below the braking curve or short of the forced
    budget are not saved by any sampled profile, while the same sampler saves most members 5 cm inside."""
    rng = np.random.default_rng(4)
    v = rng.uniform(-14.5, 14.5, 30)
    q = rng.choice(np.array(BUDGETS), 30)
    top = _upper_edge(v, q, time_left)
    ok = np.isfinite(top)
    assert ok.sum() >= 15
    above = (v[ok], top[ok] + rng.uniform(0.01, 0.3, ok.sum()), q[ok])
    vb = rng.uniform(-14.5, -3.0, 10)
    below = (vb, (vb**2 - 1) / (2 * U) - rng.uniform(0.01, 0.1, 10), rng.choice(np.array(BUDGETS), 10))
    vs = rng.uniform(-14.8, -11.0, 6)
    short = (vs, np.full(6, 5.0), np.maximum((np.abs(vs) - 10) / U - 0.01, 0.0))
    outside = [np.concatenate(parts) for parts in zip(above, below, short)]
    assert not exact_member(*outside, time_left).any()
    assert not _saved_by_sampling(*outside, rng, time_left=time_left).any()
    # the sampler has the power to tell: 5 cm inside the upper edge it saves most states (about three in four)
    inside = (v[ok], top[ok] - 0.05, q[ok])
    assert exact_member(*inside, time_left).all()
    assert _saved_by_sampling(*inside, rng, time_left=time_left).mean() > 0.5


@pytest.mark.parametrize("t", [0.0, 0.5, 0.8])
def test_grading_the_coarse_table(pointmass_table, t):
    """The fixture (41 x 41 x 45, ENO2/RK2) against the exact sets on its own nodes.

    Soundness: a node the table claims may lie outside the exact set only next to it (one cell, the resolution of
    a node sample: the exact boundary crosses that node's cell). Tightness: every node where the sets differ lies
    within three cells of the exact boundary, a band proportional to the spacing. Three cells is the boundary
    displacement of this second-order scheme measured at both 41 x 41 x 45 and 101 x 101 x 111 (the value has kinks
    where the scheme drops to first order, so the displacement scales with the spacing); the area bound follows.
    """
    report = grade(pointmass_table, BUDGETS, t)
    cell = pointmass_table.cell_volume()
    for q in BUDGETS:
        exact = exact_mask(pointmass_table, q, t)
        claimed = pointmass_table.set_mask(t, q)
        depth_in = distance_transform_cdt(exact, metric="chessboard")
        depth_out = distance_transform_cdt(~exact, metric="chessboard")
        unsound, missed = claimed & ~exact, exact & ~claimed
        assert (depth_out[unsound] <= 1).all(), q
        assert (depth_in[missed] <= 3).all(), q
        r = report[q]
        band = float(((depth_in <= 3) & exact).sum() + ((depth_out == 1) & ~exact).sum()) * cell
        assert r["symmetric_difference"] <= band
        assert r["unsound_area"] <= float(((depth_out == 1) & ~exact).sum()) * cell
        assert r["exact_area"] == pytest.approx(exact.sum() * cell)
        assert r["claimed_area"] == pytest.approx(pointmass_table.set_measure(t, q))
        assert r["relative_difference"] == pytest.approx(r["symmetric_difference"] / r["exact_area"])
    areas = [report[q]["exact_area"] for q in BUDGETS]
    assert all(a <= b for a, b in zip(areas, areas[1:])) and areas[0] > 0
