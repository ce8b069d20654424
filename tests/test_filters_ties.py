"""The filter against the environment's own arithmetic, at exact floating-point ties (issue 37, "sound to the last
bit"): the action the environment applies is the one the filter judged, bit for bit; a start that ``reset``
certifies never meets a hard violation or an overspend, even where the exact motion touches ``C1``'s face and the
environment's RK4 rounds to the other side of it; and starts bisected onto the certified edge run without an
``"uncertified"`` step. Every run here is the environment itself (``PointMassLanding-v0`` under ``SafetyFilter``),
not a re-integration."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import softreach.envs  # noqa: F401  (registers the environments)
from judged import verdict
from softreach.filters import OPTIMAL, SafetyFilter, ValueFilter
from softreach.reach import get_model
from softreach.reach.proof.lookahead import exact_normalized, representable, state_allowance
from softreach.reach.sim.rk4 import rk4_step

ENV = "softreach/PointMassLanding-v0"


@pytest.fixture(scope="module")
def vf(pointmass_held_table):
    """The filter ``SafetyFilter`` makes for the point-mass env (landing checked at its 10 sub-steps)."""
    return ValueFilter(pointmass_held_table, 0.01, target_checks=get_model("pointmass").substeps)


def _episode(vf, x0, q, t0, action, wind_value=None, wind="constant", seed=0):
    """One filtered episode in the env: ``(reset info, [step infos])``; ``action`` a constant normalised action or a
    callable ``rng -> action``."""
    kwargs = {"wind": wind} if wind_value is None else {"wind": wind, "wind_value": wind_value}
    env = SafetyFilter(gym.make(ENV, **kwargs), value_filter=vf)
    _, first = env.reset(seed=seed, options={"state": list(x0), "budget": q, "time": t0})
    rng = np.random.default_rng(seed)
    steps = []
    while True:
        a = action(rng) if callable(action) else action
        _, _, terminated, truncated, info = env.step(np.array([a], np.float32))
        steps.append(info)
        if terminated or truncated:
            return first, steps


def _sound(first, steps):
    """What a certified start promises, read off the env's own flags: no hard violation, never a negative budget,
    landed, and every step certified."""
    assert first["certified"], first["certified_reason"]
    assert not any(s["hard_violation"] for s in steps), [s["t"] for s in steps if s["hard_violation"]]
    assert not any(s["budget_exceeded"] for s in steps), min(s["budget"] for s in steps)
    assert steps[-1]["landed"], steps[-1]
    assert all(s["filter_reason"] != "uncertified" for s in steps)


def test_the_env_applies_exactly_the_candidate_judged(vf):
    """Issue 37: the hover candidate u = 9.8 went to the env as float32 and came out as 9.799999594688416 m/s^2.
    Every action the filter applies reaches the env's physics bit for bit: a candidate as the candidate, and any
    action as the physical value the filter judged."""
    cands = vf.lookahead.candidates[:, 0]
    assert 9.8 in cands.tolist()
    applied = []
    # the fall at the speed limit, under a policy that pushes down and one that pushes up: the filter
    # replaces their actions by candidates, the hover thrust among them
    for push in (-1.0, 1.0):
        env = SafetyFilter(gym.make(ENV, wind="constant", wind_value=-10.0), value_filter=vf)
        env.reset(options={"state": [-14.9, 11.38525635681534], "budget": 0.6})
        for _ in range(100):
            _, _, terminated, truncated, info = env.step(np.array([push], np.float32))
            if info["filter_active"]:
                applied.append(float(info["action_physical"][0]))
                assert applied[-1] in cands.tolist(), applied[-1]
            if terminated or truncated:
                break
    assert 9.8 in applied, applied  # the hover thrust itself was applied, not a float32 neighbour
    # every candidate of every built-in model is the image of a normalised action (the env's map, binary64)
    for name in ("pointmass", "glider", "dubins"):
        model = get_model(name)
        lo, hi = (np.asarray(b, float) for b in model.control_bounds)
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        c = representable(np.asarray(model.held_candidates(), float), mid, half)
        q = exact_normalized(c, mid, half)
        assert np.array_equal(mid + half * np.clip(q, -1, 1), c), name
        # a candidate with no exact preimage moves by at most one unit in the last place
        np.testing.assert_allclose(c, np.asarray(model.held_candidates(), float), rtol=4e-16, atol=0)


@pytest.mark.parametrize("env_id", [ENV, "softreach/SoftReach-v0"])
def test_every_env_gets_the_physical_action_judged(vf, env_id):
    """The landing env and the generic one (same action map): each step's physical control is the policy's own
    action where it passed, and otherwise the exact image of the normalised action the filter returned, which is
    the physical action it judged (a candidate, or the smooth rule's blend)."""
    kwargs = {"model": get_model("pointmass")} if env_id != ENV else {}
    smooth = ValueFilter(vf.table, 0.01, rule="smooth", target_checks=vf.target_checks)
    for f in (vf, smooth):
        env = SafetyFilter(gym.make(env_id, wind="random", **kwargs), value_filter=f)
        env.reset(seed=3, options={"state": [-6.0, 6.0], "budget": 0.06})
        rng = np.random.default_rng(3)
        acted = 0
        for _ in range(100):
            base = env.unwrapped
            t, x, z = base.time, base.state, base.budget
            a = np.array([rng.uniform(-1, 1)], np.float32)
            applied, out = f.filter(t, x, z, a, normalized=True, plan=env._plan)
            _, _, terminated, truncated, info = env.step(a)
            phys = float(info["action_physical"][0])
            if out["active"]:
                acted += 1
                judged = float(f.physical(applied)[0])
                assert phys == judged, (phys, judged)
                if out["reason"] == OPTIMAL:  # the candidate itself
                    assert phys in f.lookahead.candidates[:, 0].tolist()
            else:
                assert phys == float(f.physical(a)[0])
            if terminated or truncated:
                break
        assert acted, f.rule


def test_glider_gets_its_candidates_in_binary64(glider_held_table):
    """The glider's kernel holds its env's RK4 states (``rk4_error`` and ``rk4_stage_error`` zero), so its proof is
    one of the env's numbers, rounding allowed for, and its candidates are the images of normalised actions (the
    table's second angle of attack, which none maps to, moved by one unit in the last place): each reaches the env in
    binary64 exactly, where a float32 action would have moved it by about 1e-9 rad."""
    f = ValueFilter(glider_held_table, 0.1, target_checks=2)
    assert f.lookahead.env_covered and (f.lookahead.slack > 0).all() and (f.lookahead.slack < 1e-11).all()
    assert 0 < f.lookahead.budget_slack < 1e-12
    cands = f.lookahead.candidates[:, 0]
    table = np.asarray(glider_held_table.model.held_candidates(), dtype=np.float64)[:, 0]
    assert np.abs(cands - table).max() <= np.spacing(table).max()
    env = SafetyFilter(gym.make("softreach/GliderLanding-v0"), value_filter=f)
    replaced = 0
    for action in (1.0, -1.0):
        env.reset(seed=0)
        for _ in range(15):
            _, _, terminated, truncated, info = env.step(np.array([action], np.float32))
            if info["filter_active"]:
                replaced += 1
                phys = float(info["action_physical"][0])
                assert phys in cands, phys
            if terminated or truncated:
                break
    assert replaced


def test_hover_start_just_above_the_ground(vf):
    """Issue 37: start (-0.01, 1.5e-05) m/s, m, no budget, a policy that always dives, wind -10: the float32 hover
    thrust ended 2.0e-13 m below the ground after 1 ms. Certified, the run now lands."""
    first, steps = _episode(vf, (-0.01, 1.5000000000000002e-05), 0.0, 0.0, -1.0, wind_value=-10.0)
    _sound(first, steps)


@pytest.mark.parametrize("wind_value", [-10.0, -9.9, -9.0, -5.0, 0.0, 10.0])
def test_fast_fall_at_the_speed_limit(vf, wind_value):
    """Issue 37: start (-14.9, 11.385...) with Q = 0.6; a wind that aims the end speed at -14.9 - 0.1 left the
    float32 hover thrust at v = -15.000000004, outside C1. (On the tests' coarse table, with the allowances, the
    start is no longer certified: it lies at the edge of the set where the cells' ties decide.)"""
    first, steps = _episode(vf, (-14.9, 11.38525635681534), 0.6, 0.0, -1.0, wind_value=wind_value)
    if first["certified"]:
        _sound(first, steps)
    # certified or not, the speed limit holds in the env's own numbers
    assert not any(s["hard_violation"] for s in steps)


@pytest.mark.parametrize("x0, t0", [((-0.32973171649909216, 0.00030963171649909214), 0.0),
                                    ((-0.2600974477372232, 0.0002399974477372232), 0.99)])
@pytest.mark.parametrize("action", [-1.0, 0.0, 1.0])
def test_exact_motion_touching_the_ground(vf, x0, t0, action):
    """Issue 37: starts whose exact motion under full thrust and the worst wind reaches y = 0 exactly at the first
    sub-step end; the env's RK4 rounds to y = -5.42e-20 there. The filter's boxes carry the allowance for the env's
    rounding, so such a start is either not certified, or certified and every run from it keeps C1."""
    first, steps = _episode(vf, x0, 0.0, t0, action, wind_value=-10.0)
    if first["certified"]:
        _sound(first, steps)
    else:
        assert first["certified_reason"] in ("not_in_set", "no_certified_action"), first["certified_reason"]


def test_the_point_mass_rk4_error_of_zero_holds_to_the_rounding_the_allowance_counts():
    """``PointMass.rk4_error`` is zero because RK4 integrates its held quadratic motion exactly: an env sub-step
    (:func:`rk4_step` on ``f_scalar``, as the env takes it) ends within the ``24 u M_i`` a sub-step that
    :func:`state_allowance` counts for rounding of the exact motion, computed in exact rational arithmetic from the
    same floats; from states across the domain and its corners, thrusts at the box's ends, the hover and inside,
    winds at the box's ends and inside, at the env's sub-step and at 50 times it. A motion RK4 does not integrate
    exactly (a drag term, say) ends farther."""
    from fractions import Fraction

    model = get_model("pointmass")
    p, (lo, hi) = model.params, model.domain
    per_step = (state_allowance(model, 2) - state_allowance(model, 1)).tolist()  # the 24 u M_i of one sub-step
    rng = np.random.default_rng(3)
    states = [[v, y] for v in (lo[0], hi[0]) for y in (lo[1], hi[1])] + rng.uniform(lo, hi, (60, 2)).tolist()
    thrusts = [model.control_bounds[0][0], model.control_bounds[1][0], p.gravity, float(rng.uniform(0, 20))]
    winds = [-p.d_max, p.d_max, float(rng.uniform(-p.d_max, p.d_max))]
    h0 = model.control_period / model.substeps
    for h in (h0, 50 * h0):
        for (v, y), u, d in ((s, u, d) for s in states for u in thrusts for d in winds):
            end = rk4_step(model.f_scalar, 0.0, 0.0, 0.0, 0.5 * h, h, h / 6.0, [v, y], [u], [d])[0]
            acc, H = Fraction(u) - Fraction(p.gravity) + Fraction(d), Fraction(h)
            exact = (Fraction(v) + acc * H, Fraction(y) + Fraction(v) * H + acc * H * H / 2)
            for i in range(2):
                assert abs(Fraction(float(end[i])) - exact[i]) <= Fraction(per_step[i]), (v, y, u, d, h, i)


def test_the_allowances_are_outward_and_tiny(vf):
    """The allowances widen every box and charge every spending period a little more, never less, and stay far
    below any physical scale (metres, m/s, seconds of budget)."""
    la = vf.lookahead
    # the point mass states its RK4 error and stages' (the allowances apply)
    assert la.env_covered
    assert (la.slack > 0).all() and (la.slack < 1e-9).all()
    assert 0 < la.budget_slack < 1e-12
    # a period outside C2 (v = -12 m/s): the filter's end budget lies below the env's after each of several
    # periods, so a chain of them never ends above what the env holds (0.3 - 0.01 four times is 0.2599...95)
    x = np.array([[-12.0, 10.0]])
    a = np.array([[9.8]])
    z = 0.3
    for _ in range(4):
        z_end = verdict(vf, 0.0, x[0], z, a[0]).z_end  # the filter's compiled one-period test
        z_env = z - 0.01  # the env's own update for a period wholly outside C2 (cost exactly dt)
        assert z_end < z_env, (z_end, z_env)
        z = z_env
    assert z == 0.25999999999999995


def _edge_starts(vf, q, t0, speeds):
    """Starts bisected onto the certified edge along the altitude at fixed speeds: the last certified altitude
    within 1e-12 m of the first uncertified one above it (``reset``'s certificate, start plans included)."""
    ys = np.linspace(0.0, 18.0, 181)
    out = []
    for v in speeds:
        ok = np.array([bool(vf.certify_start(t0, [v, y], q)[0]) for y in ys])
        flips = np.nonzero(ok[:-1] & ~ok[1:])[0]
        if not len(flips):
            continue
        lo, hi = ys[flips[-1]], ys[flips[-1] + 1]
        while hi - lo > 1e-12:
            mid = 0.5 * (lo + hi)
            if vf.certify_start(t0, [v, mid], q)[0]:
                lo = mid
            else:
                hi = mid
        out.append((v, lo))
    return out


@pytest.mark.parametrize("q", [0.0, 0.06, 0.3])
def test_starts_bisected_onto_the_certified_edge(vf, q):
    """Issue 37: from starts bisected onto the certified edge the filter reported ``"uncertified"`` steps (states
    within 1e-12 of a cell edge; the env's running budget one rounding below a proven budget cell). Every run from
    such a start, under policies that dive, climb or act at random and winds at both extremes, is certified at every
    step, keeps C1 and the budget and lands."""
    starts = _edge_starts(vf, q, 0.0, speeds=(-8.0, -3.0, 0.0, 3.0))
    assert len(starts) >= 3, starts
    policies = (-1.0, 1.0, lambda rng: float(rng.uniform(-1, 1)))
    runs = 0
    for v, y in starts:
        for k, action in enumerate(policies):
            for wind_value in (-10.0, 10.0):
                first, steps = _episode(vf, (v, y), q, 0.0, action, wind_value=wind_value, seed=k)
                _sound(first, steps)
                runs += 1
        # and the random wind of the env (a new value every step)
        first, steps = _episode(vf, (v, y), q, 0.0, lambda rng: float(rng.uniform(-1, 1)), wind="random", seed=7)
        _sound(first, steps)
    assert runs >= 18


def test_a_continuous_table_with_the_cells_keeps_every_promise(pointmass_table):
    """The cells prove and the table only ranks candidates, so a table solved in continuous time certifies as well:
    runs from starts bisected onto its certified edge, under policies that dive, climb or act at random and winds
    at both extremes or random, are certified at every step, keep C1 and the budget and land."""
    vf = ValueFilter(pointmass_table, 0.01, target_checks=get_model("pointmass").substeps)
    assert pointmass_table.control_period is None
    starts = _edge_starts(vf, 0.3, 0.0, speeds=(-8.0, 0.0, 3.0))
    assert len(starts) >= 2, starts
    for v, y in starts:
        for k, action in enumerate((-1.0, 1.0, lambda rng: float(rng.uniform(-1, 1)))):
            for wind_value in (-10.0, 10.0):
                _sound(*_episode(vf, (v, y), 0.3, 0.0, action, wind_value=wind_value, seed=k))
        _sound(*_episode(vf, (v, y), 0.3, 0.0, lambda rng: float(rng.uniform(-1, 1)), wind="random", seed=7))
