"""Landing inside a control period: the environment ends an episode at the first sub-step end where the vehicle
has landed or left ``C1``, and the filter's look-ahead counts on landing only at those instants."""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from judged import candidate_verdicts
from softreach.reach.sim.integrator import integrate_period
from softreach.filters import SafetyFilter, ValueFilter, plans
from softreach.reach import get_model
from softreach.reach.proof.cell_certificate import CellCertificate

DT = 0.01
# 7 mm above the ground, sinking 7 mm/s faster than the 1 m/s touchdown limit: full thrust brakes into the target
# within a millisecond, but ten milliseconds of it end below the ground (the traced failure of docs/filters.md)
BRINK = (-1.007, 0.007)


def _run(n_substeps):
    env = gym.make("softreach/PointMassLanding-v0", wind="constant", wind_value=-10.0, n_substeps=n_substeps,
                   budget=0.3)
    env.reset(seed=0, options={"state": BRINK, "budget": 0.3, "time": 0.5})
    _, _, terminated, _, info = env.step(np.array([1.0], dtype=np.float32))
    return terminated, info


def test_a_touchdown_inside_the_period_is_a_landing():
    terminated, info = _run(None)  # the model's sub-steps: every millisecond
    assert terminated and info["landed"] and not info["hard_violation"]
    assert 0.5 < info["t"] <= 0.5 + 0.002 + 1e-12  # it ends at the sub-step where it landed
    # checked only at the period's end, the same run is a crash: the sub-steps are what decides
    terminated, info = _run(1)
    assert terminated and info["hard_violation"] and not info["landed"]


def test_integrator_stops_at_the_first_event_on_both_paths():
    model = get_model("pointmass")

    def stop(t, x, rate):
        return float(model.hard_constraint(t, x)) > 0 or (rate == 0.0 and float(model.target(t, x)) <= 0)

    slow = integrate_period(model, 0.5, list(BRINK), [60.0], [-10.0], DT, 10, 1e-3, 1e-6, fast=None, stop=stop)
    quick = integrate_period(model, 0.5, list(BRINK), [60.0], [-10.0], DT, 10, 1e-3, 1e-6, stop=stop)
    assert slow == quick
    x, cost, rate, elapsed = slow
    assert elapsed == pytest.approx(0.001) and cost == 0.0 and rate == 0.0
    assert -1.0 <= x[0] <= 0.0 and 0.0 <= x[1] <= 0.7


def test_the_filter_lands_from_the_brink_only_with_the_envs_checks(pointmass_held_table, monkeypatch):
    t, x, z = np.array([0.5]), np.array([BRINK]), np.array([0.3])
    ends_only = ValueFilter(pointmass_held_table, DT)
    checks = ValueFilter(pointmass_held_table, DT, target_checks=10)
    ok1 = candidate_verdicts(ends_only, t, x, z)[0]
    ok10, lands10 = candidate_verdicts(checks, t, x, z)
    assert not ok1.any()  # nothing keeps C1 for ten milliseconds
    assert ok10.any() and np.all(lands10[ok10])  # braking surely lands at a check instant
    assert np.all(checks.lookahead.candidates[ok10[0], 0] > 0)  # only thrust up lands
    # the wrapper gives its filter the env's sub-steps, and refuses a shared filter that counts on more checks
    env = gym.make("softreach/PointMassLanding-v0", n_substeps=5)
    # (cells that certify nothing: they would be solved for these checks, and only the count is asked here)
    monkeypatch.setattr(plans, "cached", lambda la, shape, holds: CellCertificate.empty(la, holds))
    assert SafetyFilter(env, pointmass_held_table).value_filter.target_checks == 5
    with pytest.raises(ValueError, match="target_checks"):
        SafetyFilter(env, value_filter=checks)


def test_every_landing_pass_lands_under_adversarial_winds(pointmass_held_table):
    """Wherever the look-ahead says a held action surely lands, the env's integrator with winds that switch
    inside the period (and the extremes) lands at a check instant without leaving C1 or the budget."""
    model = get_model("pointmass")
    vf = ValueFilter(pointmass_held_table, DT, target_checks=10)
    rng = np.random.default_rng(3)
    n = 3000
    x = np.column_stack([rng.uniform(-2.0, 0.0, n), rng.uniform(0.0, 0.1, n)])
    z = rng.choice([0.0, 0.002, 0.05], n)
    t = np.full(n, 0.5)
    rows, cols = np.nonzero(candidate_verdicts(vf, t, x, z)[1])
    assert len(rows) > 200, "too few landing passes to test"

    def stop(tt, xx, rate):
        return float(model.hard_constraint(tt, xx)) > 0 or (rate == 0.0 and float(model.target(tt, xx)) <= 0)

    for r, c in zip(rows[:400], cols[:400]):
        a = [float(vf.lookahead.candidates[c, 0])]
        for wind in ([-10.0] * 10, [10.0] * 10, list(rng.choice([-10.0, 10.0], 10)), [10.0] * 5 + [-10.0] * 5):
            xs, spent, landed = list(x[r]), 0.0, False
            for j in range(10):  # one env sub-step per piece, the wind switching between them
                xs, cost, rate, _ = integrate_period(model, 0.5 + j * DT / 10, xs, a, [wind[j]], DT / 10, 1, 1e-3,
                                                     1e-6, stop=stop)
                spent += cost
                pt = [np.float64(v) for v in xs]
                assert float(model.hard_constraint(0.5, pt)) <= 0, (x[r], a, wind)
                if bool(model.landed(0.5, pt)):
                    landed = True
                    break
            assert landed, (x[r], a, wind)
            assert spent <= z[r] + 1e-12


def test_the_filter_applies_a_landing_candidate_not_the_fallback(pointmass_held_table):
    """At the brink only landing passes, and the filter must apply it (a landing candidate ranks -inf, which once
    read as "could not be bounded" and sent the box centre: traced in the audit as a crash from a certified start)."""
    from softreach.filters import FALLBACK

    vf = ValueFilter(pointmass_held_table, DT, target_checks=10)
    applied, info = vf.filter(0.5, np.array(BRINK), 0.3, np.array([-42.8]))
    assert info["reason"] != FALLBACK and info["lookahead"] == -np.inf and info["certified"] and applied[0] > 0
    env = gym.make("softreach/PointMassLanding-v0", wind="constant", wind_value=-10.0, budget=0.3)
    env.reset(seed=0, options={"state": list(BRINK), "budget": 0.3, "time": 0.5})
    _, _, terminated, _, out = env.step(np.array([applied[0] / 60.0], dtype=np.float32))
    assert terminated and out["landed"] and not out["hard_violation"]
