"""The Dubins vehicle (``dubins``): its closed forms against brute force, its held-period enclosures against
simulated motion, and the properties of its solved sets (a small grid, heading periodic)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from softreach.reach import get_model
from softreach.reach.models.dubins import Dubins, DubinsParams

MODEL = get_model("dubins")


def _random_states(rng, n):
    return [rng.uniform(-4.5, 4.5, n), rng.uniform(-4.5, 4.5, n), rng.uniform(-math.pi, math.pi, n)]


def test_hamiltonian_and_optimal_inputs_are_the_min_max_over_the_input_boxes():
    """H = min_u max_w p . f, computed by enumerating the boxes' vertices (f is affine in u and w)."""
    rng = np.random.default_rng(0)
    x = _random_states(rng, 200)
    p = [rng.normal(size=200) for _ in range(3)]
    (u_lo,), (u_hi,) = MODEL.control_bounds
    w_lo, w_hi = MODEL.disturbance_bounds
    best = np.full(200, np.inf)
    for u in (u_lo, u_hi):
        worst = np.full(200, -np.inf)
        for w in itertools.product(*zip(w_lo, w_hi)):
            f = MODEL.f(0.0, x, [u], list(w))
            worst = np.maximum(worst, sum(pi * fi for pi, fi in zip(p, f)))
        best = np.minimum(best, worst)
    np.testing.assert_allclose(MODEL.hamiltonian(0.0, x, p), best, atol=1e-12)
    a = MODEL.optimal_control(0.0, x, p)
    b = MODEL.worst_disturbance(0.0, x, p)
    f = MODEL.f(0.0, x, a, b)
    np.testing.assert_allclose(sum(pi * fi for pi, fi in zip(p, f)), best, atol=1e-12)


def test_dissipation_bounds_the_hamiltonians_slopes():
    """alpha_i >= |dH/dp_i| (finite differences of the exact H at random states and co-states)."""
    rng = np.random.default_rng(1)
    x = _random_states(rng, 300)
    p = [rng.normal(size=300) for _ in range(3)]
    alpha = MODEL.dissipation(0.0, x, None, None)
    for i in range(3):
        d = 1e-6
        hi = [pj + (d if j == i else 0) for j, pj in enumerate(p)]
        lo = [pj - (d if j == i else 0) for j, pj in enumerate(p)]
        slope = (MODEL.hamiltonian(0.0, x, hi) - MODEL.hamiltonian(0.0, x, lo)) / (2 * d)
        assert np.all(np.abs(slope) <= np.broadcast_to(alpha[i], slope.shape) + 1e-6)


def _simulate_held(x0, u, winds, dt, steps=400):
    """Fine RK4 of one held period, the wind switching between the given values at random instants."""
    xs = [np.array(x0, dtype=float)]
    h = dt / steps
    x = xs[0]
    for k in range(steps):
        w = winds[k]
        f = lambda s: np.array(MODEL.f(0.0, list(s), [u], list(w)), dtype=float)  # noqa: E731
        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs.append(x)
    return np.array(xs)


def test_held_enclosures_hold_simulated_motion_from_points_and_boxes():
    rng = np.random.default_rng(2)
    dt, steps = MODEL.control_period, 400
    w_lo, w_hi = (np.array(v) for v in MODEL.disturbance_bounds)
    for _ in range(40):
        lo = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-4, 4)])
        hi = lo + rng.uniform(0, 0.3, 3) * rng.integers(0, 2)  # a point or a box
        u = rng.uniform(*[b[0] for b in MODEL.control_bounds])
        tube_lo, tube_hi, end_lo, end_hi = MODEL.held_enclosure_box(0.0, lo[None], hi[None], np.array([[u]]), dt)
        piece_lo, piece_hi = MODEL.held_tube_pieces_box(0.0, lo[None], hi[None], np.array([[u]]), dt, 4)
        for _ in range(5):
            x0 = rng.uniform(lo, hi)
            switch = np.cumsum(rng.random(steps) < 0.02) % 2
            corners = rng.choice([w_lo, w_hi], size=2)
            winds = np.where(switch[:, None] == 0, corners[0], corners[1])
            path = _simulate_held(x0, u, winds, dt, steps)
            assert np.all(path >= tube_lo - 1e-9) and np.all(path <= tube_hi + 1e-9)
            assert np.all(path[-1] >= end_lo[0] - 1e-9) and np.all(path[-1] <= end_hi[0] + 1e-9)
            for j in range(4):
                part = path[j * steps // 4:(j + 1) * steps // 4 + 1]
                assert np.all(part >= piece_lo[j] - 1e-9) and np.all(part <= piece_hi[j] + 1e-9)


def test_the_end_box_from_a_point_is_the_exact_turn_widened_by_the_wind_alone():
    """From one state the turn is deterministic, so the end box at ``s`` holds the windless end state exactly
    (``s sinc(u s / 2) (cos, sin)(theta + u s / 2)``, here summed in many small steps) and is ``2 w s`` wide in ``x``
    and ``y``, the wind's part, but for rounding: a box that counted the turn as uncertainty is wider."""
    rng = np.random.default_rng(4)
    steps = 100  # RK4's error on the smooth windless turn is far below the tolerances
    dt = MODEL.control_period
    w = MODEL.params.wind_max
    u_lo, u_hi = MODEL.control_bounds[0][0], MODEL.control_bounds[1][0]
    for _ in range(60):
        x = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi)])
        u = rng.choice([u_lo, u_hi, rng.uniform(u_lo, u_hi)])
        _, _, end_lo, end_hi = MODEL.held_enclosure_box(0.0, x[None], x[None], np.array([[u]]), dt)
        path = _simulate_held(x, u, np.zeros((steps, 2)), dt, steps)
        assert np.all(path[-1, :2] >= end_lo[0, :2] + w * dt - 1e-9), (x, u)
        assert np.all(path[-1, :2] <= end_hi[0, :2] - w * dt + 1e-9), (x, u)
        assert np.all(end_hi[0, :2] - end_lo[0, :2] <= 2 * w * dt + 1e-12), (x, u, end_hi - end_lo)


@pytest.mark.parametrize("which", ["hard_constraint", "soft_constraint"])
def test_set_box_max_bounds_the_obstacle_and_zone_over_boxes_and_is_tight(which):
    """c1 and c2 are largest inside a box near the discs' centres, where no corner sees it."""
    rng = np.random.default_rng(3)
    fn = getattr(MODEL, which)
    lo = np.column_stack([rng.uniform(-4, 3.5, 300), rng.uniform(-4, 3.5, 300), np.zeros(300)])
    hi = lo + np.column_stack([rng.uniform(0, 1.5, 300), rng.uniform(0, 1.5, 300), np.zeros(300)])
    bound = MODEL.set_box_max(which, 0.0, lo, hi)
    s = np.linspace(0, 1, 41)
    gx, gy = np.meshgrid(s, s, indexing="ij")
    worse_than_corners = 0
    for r in range(300):
        xs = lo[r, 0] + gx.ravel() * (hi[r, 0] - lo[r, 0])
        ys = lo[r, 1] + gy.ravel() * (hi[r, 1] - lo[r, 1])
        sampled = fn(0.0, [xs, ys, 0 * xs])
        assert bound[r] >= sampled.max() - 1e-12
        assert bound[r] <= sampled.max() + 0.05  # within the sampling's resolution
        corners = fn(0.0, [np.array([lo[r, 0], lo[r, 0], hi[r, 0], hi[r, 0]]),
                           np.array([lo[r, 1], hi[r, 1], lo[r, 1], hi[r, 1]]), np.zeros(4)])
        worse_than_corners += sampled.max() > corners.max() + 1e-3
    assert worse_than_corners > 0  # the corners alone would have been unsound on these boxes


def test_bad_parameters_are_refused_by_name():
    with pytest.raises(ValueError, match="turn_max"):
        Dubins(turn_max=0.0)
    with pytest.raises(ValueError, match="goal"):
        Dubins(goal=(1.0,))
    with pytest.raises(TypeError):
        Dubins(DubinsParams(), speed=2.0)


# ------------------------------------------------------------------------------------------ solved sets

def _grid_points(table):
    axes = table.state_axes("V")
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1)


def test_table_grid_is_periodic_in_heading(dubins_table):
    grid = dubins_table.grid("W_eps")
    assert grid.periodic == (False, False, True, False)
    assert grid.lo[2] == pytest.approx(-math.pi) and grid.hi[2] == pytest.approx(math.pi)
    x = np.array([[1.0, -2.0, 3.0], [1.0, -2.0, 3.0 - 2 * math.pi], [1.0, -2.0, 3.0 + 4 * math.pi]])
    w = dubins_table.value(0.0, x, 0.7)
    assert np.all(np.isfinite(w)) and np.ptp(w) < 1e-9


def _dilate(mask: np.ndarray) -> np.ndarray:
    """``mask`` grown by one cell along every axis and diagonal (the heading's neighbours taken across the seam;
    rolling x and y wraps around the grid's edges, where the sets are empty anyway: outside C1)."""
    out = np.zeros_like(mask)
    for shift in itertools.product((-1, 0, 1), repeat=mask.ndim):
        out |= np.roll(mask, shift, axis=tuple(range(mask.ndim)))
    return out


def test_q0_set_equals_the_classical_set_within_one_grid_cell(dubins_table):
    """RA~_0 (from W_eps) and RA (from V) are the same set (Prop. 3). On the grid their boundaries may lie a cell
    apart (the paper's grid study: below the spacing h), so

    * every node where they differ has a neighbour on the other side of RA's boundary, and
    * every node of either set has a node of the other within two cells: the boundaries' one cell, plus one for
      reading each set at the nodes (a node set misses a sliver thinner than a cell).

    Losing RA's whole one-cell boundary layer (70 % of RA's nodes on this grid) breaks the second."""
    ra = dubins_table.set_mask(0.0)
    ra0 = dubins_table.set_mask(0.0, 0.0)
    assert ra.sum() > 100
    diff = ra ^ ra0
    near = (_dilate(ra) & ~ra) | (_dilate(~ra) & ra)  # the nodes on either side of RA's boundary
    assert np.all(near[diff])
    for a, b in ((ra, ra0), (ra0, ra)):
        assert not (a & ~_dilate(_dilate(b))).any()


def test_sets_grow_with_the_budget_and_the_zone_is_the_shortcut(dubins_table):
    budgets = [0.0, 0.5, 1.0, 2.0]
    masks = [dubins_table.set_mask(0.0, q) for q in budgets]
    for q_small, q_large, small, large in zip(budgets, budgets[1:], masks, masks[1:]):
        # W_eps does not increase with z, so the sets are nested; the (non-monotone) scheme keeps that up to a few
        # nodes on the boundary (measured on this grid: 0, 0 and 3 of about 2,500), where W is within a few
        # centimetres of 0
        lost = small & ~large
        assert lost.sum() <= max(3, 0.01 * small.sum())
        pts = _grid_points(dubins_table)[lost]
        assert np.all(np.abs(dubins_table.value(0.0, pts, q_large)) < 0.05)
    assert masks[-1].sum() > 1.1 * masks[0].sum()
    # what the budget buys lies west of the obstacle: the paths through the soft zone
    gained = masks[-1] & ~masks[0]
    pts = _grid_points(dubins_table)
    assert np.median(pts[gained][:, 0]) < 0.5


def test_obstacle_and_zone_states_are_never_in_a_set(dubins_table):
    pts = _grid_points(dubins_table)
    comps = [pts[..., i] for i in range(3)]
    inside_obstacle = MODEL.hard_constraint(0.0, comps) > 0
    assert inside_obstacle.sum() > 20
    for q in (None, 0.0, 1.0, 2.0):
        assert not np.any(dubins_table.set_mask(0.0, q)[inside_obstacle])
    # inside the soft zone with no budget: never (it would already be spending)
    in_zone = MODEL.soft_constraint(0.0, comps) > 0.1
    assert not np.any(dubins_table.set_mask(0.0, 0.0)[in_zone])


def test_table_policy_under_table_wind_reaches_the_goal_from_a_start_that_needs_budget(dubins_table):
    """From the deepest node of RA~_2 that is not in RA~_0 (so it must cross the soft zone), the table's a* held
    for the env's periods, against the table's worst wind b*, reaches the goal, never touches the obstacle."""
    import gymnasium as gym

    import softreach.envs  # noqa: F401

    q = 2.0
    needs = dubins_table.set_mask(0.0, q) & ~dubins_table.set_mask(0.0, 0.0)
    assert needs.any()
    pts = _grid_points(dubins_table)[needs]
    w = dubins_table.value(0.0, pts, q)
    x0 = pts[int(np.argmin(w))]
    env = gym.make("softreach/SoftReach-v0", model=MODEL, wind="adversarial", wind_table=dubins_table)
    base = env.unwrapped
    env.reset(seed=0, options={"state": x0.tolist(), "budget": q})
    path = [base.state]
    terminated = truncated = False
    while not (terminated or truncated):
        a = dubins_table.optimal_control(base.time, base.state, max(base.budget, 0.0), outside="nearest")[0]
        _, _, terminated, truncated, info = env.step(base.normalized_action(a))
        path.append(base.state)
    path = np.array(path)
    assert info["landed"] and not info["hard_violation"]
    assert np.all(MODEL.hard_constraint(0.0, [path[:, 0], path[:, 1], path[:, 2]]) <= 0)
    assert info["budget_used"] > 0  # it did take the shortcut through the zone


def _exact_sub_step(x: np.ndarray, u: float, w: np.ndarray, h: float) -> np.ndarray:
    """The exact motion over ``h`` with the turn rate ``u != 0`` and the wind ``w`` held, in closed form."""
    v, th = MODEL.params.speed, x[:, 2]
    return np.stack([x[:, 0] + v / u * (np.sin(th + u * h) - np.sin(th)) + w[0] * h,
                     x[:, 1] - v / u * (np.cos(th + u * h) - np.cos(th)) + w[1] * h, th + u * h], axis=1)


def test_rk4_error_bounds_the_envs_sub_step_and_is_nearly_reached():
    """The environments' RK4 sub-step against the closed-form motion, over every heading, at the largest turn
    rates and a smaller one, with and without wind: never farther than ``Dubins.rk4_error`` along any axis, and
    at the largest turn rate farther than half of it (Simpson's bound on a cosine is reached at its peaks): a bound
    off by a power of ``h`` fails one or the other."""
    from softreach.reach.sim.rk4 import rk4_rows

    p = MODEL.params
    h = MODEL.control_period / MODEL.substeps
    bound = MODEL.rk4_error(h)
    assert bound.shape == (3,) and bound[2] == 0.0 and 0 < bound[0] == bound[1] < 1e-9
    theta = np.linspace(-math.pi, math.pi, 1441)
    x = np.stack([np.full(theta.size, 0.3), np.full(theta.size, -0.2), theta], axis=1)
    worst = 0.0
    for u in (p.turn_max, -p.turn_max, 0.5 * p.turn_max):
        for w in ((p.wind_max, -p.wind_max), (0.0, 0.0)):
            w = np.array(w)
            end = rk4_rows(MODEL.f, 0.0, 0.5 * h, h, h, x, np.full((theta.size, 1), u), np.tile(w, (theta.size, 1)))
            err = np.abs(end - _exact_sub_step(x, u, w, h))
            # the closed form and RK4 round at about 1e-16 here, six orders below the bound
            assert (err[:, :2] <= bound[:2]).all(), (u, w, err[:, :2].max(), bound[0])
            assert err[:, 2].max() <= 1e-15
            if abs(u) == p.turn_max:
                worst = max(worst, err[:, :2].max())
    assert worst > 0.5 * bound[0], (worst, bound[0])


def test_the_wrap_between_periods_stays_within_its_allowance():
    """The environment wraps the heading into ``[-pi, pi)`` once a period, and a cell's plan held for several periods
    starts each from the wrapped heading, which the motion (``2 pi``-periodic) treats as the unwrapped one moved by
    the wrap's error. Measured in exact arithmetic against the true ``2 pi``, from end headings up to 0.2 rad past
    either end (more than a period's turn) and across the period, that error is not zero, so the heading's allowance
    needs a part for it, and lies within the part ``state_allowance`` adds along a periodic axis."""
    from decimal import Decimal
    from fractions import Fraction

    from softreach.reach.proof.lookahead import UNIT_ROUNDOFF, state_allowance

    pi = Fraction(Decimal("3.14159265358979323846264338327950288419716939937510582097494459"))
    lo, hi = MODEL.domain[0][2], MODEL.domain[1][2]
    M = 2.0 * max(abs(lo), abs(hi))
    # the allowance along the heading beyond the rounding every axis gets, (24 checks + 8) u M
    part = state_allowance(MODEL, 1)[2] - 32 * UNIT_ROUNDOFF * M
    rng = np.random.default_rng(0)
    ends = np.concatenate([hi + rng.uniform(-0.2, 0.2, 3000), lo + rng.uniform(-0.2, 0.2, 3000),
                           rng.uniform(lo, hi, 1000), [hi, lo, np.nextafter(hi, 0.0), np.nextafter(lo, 0.0)]])
    worst = Fraction(0)
    for r in ends.tolist():
        w = MODEL.wrap_state([0.0, 0.0, r])[2]
        assert lo <= w < hi
        periods = round((Fraction(r) - Fraction(w)) / (2 * pi))
        worst = max(worst, abs(Fraction(w) + periods * 2 * pi - Fraction(r)))
    assert 0 < worst <= part, (float(worst), part)


def test_the_filters_end_box_holds_the_envs_own_state_without_tolerance(dubins_held_table):
    """The env's period (its RK4 sub-steps, as an episode runs them) from points at the largest turn rates and
    with constant winds at the box's corners ends inside the end box the filter proves with (the exact motion's box
    widened by ``Lookahead.slack``: the sub-steps' error and the rounding), compared with no tolerance. The exact
    motion's box alone is tight along the wind there, and misses the env's state at some of these starts."""
    from softreach.reach.proof.lookahead import Lookahead
    from softreach.reach.sim.integrator import integrate_period

    dt = MODEL.control_period
    la = Lookahead.from_table(dubins_held_table, MODEL, dt, dubins_held_table.eps, target_checks=MODEL.substeps)
    assert la.env_covered and (la.slack[:2] > MODEL.substeps * MODEL.rk4_error(dt / MODEL.substeps)[:2]).all()
    rng = np.random.default_rng(5)
    w = MODEL.params.wind_max
    outside_exact = 0
    for _ in range(200):
        x = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi)])
        u = float(rng.choice(la.candidates[:, 0]))
        _, _, end_lo, end_hi = MODEL.held_enclosure_box(0.0, x[None], x[None], np.array([[u]]), dt)
        for wind in itertools.product((-w, w), repeat=2):
            end = np.array(integrate_period(MODEL, 0.0, x.tolist(), [u], list(wind), dt, MODEL.substeps, 1.0,
                                            1e-3)[0])
            assert (end >= end_lo[0] - la.slack).all() and (end <= end_hi[0] + la.slack).all(), (x, u, wind)
            outside_exact += int(not ((end >= end_lo[0]).all() and (end <= end_hi[0]).all()))
    assert outside_exact > 0


def test_env_error_is_the_models_bound_or_unknown_and_a_bad_one_is_refused():
    from softreach.reach.models.pointmass import PointMass
    from softreach.reach.proof.lookahead import env_error, env_slack

    assert (env_error(get_model("pointmass"), 0.001) == 0).all()  # it states RK4 exact for its quadratic motion
    assert (env_error(get_model("glider"), 0.05) == 0).all()  # its kernel holds RK4's states
    assert (env_error(MODEL, 0.05) == MODEL.rk4_error(0.05)).all()

    class Unknown(Dubins):
        def rk4_error(self, h):
            return None

    assert env_error(Unknown(), 0.05) is None

    class Unstated(PointMass):
        def rk4_error(self, h):
            return None

    # RK4 is exact for this motion too, but a model that does not say so gets no allowance: none is inferred, and
    # the look-ahead says which half of the pair is missing
    assert env_error(Unstated(), 0.001) is None
    with pytest.warns(UserWarning, match=r"model 'pointmass' \(.*Unstated\) states rk4_stage_error but not rk4_error"):
        assert env_slack(Unstated(), 0.01, 10) is None

    class Bad(Dubins):
        def rk4_error(self, h):
            return [1e-10, -1.0, 0.0]

    with pytest.raises(ValueError, match=r"dubins\.rk4_error\(0\.05\) must give 3 finite numbers >= 0.*-1\."):
        env_error(Bad(), 0.05)

