"""``VecSafetyFilter``: batched decisions equal each environment's own, step for step, across episode ends."""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv

import softreach.envs  # noqa: F401  (registers the environments)
from softreach.filters import AFTER_HORIZON, SafetyFilter, ValueFilter, VecSafetyFilter

ENV_ID = "softreach/PointMassLanding-v0"
KEYS = ("filter_active", "filter_reason", "certified", "lookahead", "value")


def _venv(table, n, vf):
    return DummyVecEnv([lambda: SafetyFilter(gym.make(ENV_ID, wind="random"), value_filter=vf) for _ in range(n)])


def test_batched_decisions_equal_single_ones(pointmass_held_table):
    vf = ValueFilter(pointmass_held_table, 0.01, target_checks=10)
    n = 5
    plain, batched = _venv(pointmass_held_table, n, vf), VecSafetyFilter(_venv(pointmass_held_table, n, vf))
    for v in (plain, batched):
        v.seed(3)
    o1, o2 = plain.reset(), batched.reset()
    np.testing.assert_array_equal(o1, o2)
    rng = np.random.default_rng(0)
    active = ends = 0
    for _ in range(250):
        # a bang-bang policy: it leaves the set often enough for the filter to act
        a = rng.choice([-1.0, 1.0], size=(n, 1)).astype(np.float32)
        o1, r1, d1, i1 = plain.step(a)
        o2, r2, d2, i2 = batched.step(a)
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for a1, a2 in zip(i1, i2):
            np.testing.assert_array_equal(a1["applied_action"], a2["applied_action"])
            for k in KEYS:
                assert a1[k] == a2[k] or (a1[k] != a1[k] and a2[k] != a2[k]), k
            active += a1["filter_active"]
        ends += int(d1.sum())
    assert active > 20 and ends > 3, (active, ends)  # both paths were exercised: interventions and resets


def test_a_stale_decision_is_not_used(pointmass_held_table):
    vf = ValueFilter(pointmass_held_table, 0.01)
    env = SafetyFilter(gym.make(ENV_ID), value_filter=vf)
    env.reset(seed=0, options={"state": [0.0, 5.0], "budget": 0.3})
    base = env.unwrapped
    a = np.array([0.2], dtype=np.float32)
    applied, dec = vf.filter(base.time, base.state, base.budget, a, normalized=True)
    bogus = {**dec, "active": True, "reason": AFTER_HORIZON}
    env.expect(np.array([0.9], dtype=np.float32), np.array([-1.0]), bogus)  # for another action
    _, _, _, _, info = env.step(a)
    np.testing.assert_allclose(info["applied_action"], np.clip(applied, -1, 1))
    assert info["filter_reason"] == "pass" and not info["filter_active"]


def test_needs_filters_in_process(pointmass_held_table):
    with pytest.raises(TypeError, match="SafetyFilter"):
        VecSafetyFilter(DummyVecEnv([lambda: gym.make(ENV_ID)]))
