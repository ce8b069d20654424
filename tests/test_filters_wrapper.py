"""``SafetyFilter`` as a gymnasium wrapper: info keys, episode summary, exact pass-through, errors, vector envs."""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the environments)
from softreach.filters import SafetyFilter, ValueFilter
from softreach.reach import TableError

ENV_ID = "softreach/PointMassLanding-v0"
KEYS = ("filter_active", "policy_action", "applied_action", "value", "margin", "optimal_action", "filter_reason")


def deep_start(table, q=0.3, which=0):
    """A grid node with W <= -margin at t = 0 (from the table itself)."""
    vf = ValueFilter(table, 0.01)
    g = table.grid("V")
    V, Y = np.meshgrid(g.axis(0), g.axis(1), indexing="ij")
    xs = np.c_[V.ravel(), Y.ravel()]
    deep = xs[vf.value(0.0, xs, q) <= 0.0]
    assert len(deep) > which
    return deep[which]


def test_info_and_episode_summary(pointmass_table):
    env = SafetyFilter(gym.make(ENV_ID), pointmass_table)
    x0 = deep_start(pointmass_table)
    obs, info = env.reset(seed=0, options={"state": x0.tolist(), "budget": 0.3})
    assert info["value"] <= -info["margin"]
    env.action_space.seed(0)
    rows = []
    done = False
    while not done:
        action = env.action_space.sample()
        obs, reward, terminated, truncated, info = env.step(action)
        done = terminated or truncated
        for key in KEYS:
            assert key in info
        assert info["policy_action"].shape == (1,) and info["applied_action"].dtype == np.float32
        np.testing.assert_array_equal(info["policy_action"], action)
        # what the environment applied (physical) is what the filter says it applied
        np.testing.assert_allclose(info["action_physical"], 60.0 * info["applied_action"].astype(float), rtol=1e-6)
        if info["filter_active"]:
            np.testing.assert_allclose(info["applied_action"], info["optimal_action"], atol=1e-6)
            assert info["filter_reason"] in ("optimal", "uncertified", "outside_domain", "after_horizon")
        else:
            np.testing.assert_array_equal(info["applied_action"], action)  # bit-exact pass-through
            # a pass is certified: the cells prove it, whatever table ranks the candidates (the table's next value,
            # ``lookahead``, only ranks here: tests/test_filters_ties.py checks it bounds a pass without cells)
            assert info["filter_reason"] == "pass" and info["certified"]
        rows.append((info["filter_active"], info["value"]))
    summary = info["filter_episode"]
    active = np.array([r[0] for r in rows])
    values = np.array([r[1] for r in rows])
    assert summary["steps"] == len(rows)
    assert summary["interventions"] == active.sum()
    assert summary["intervention_rate"] == pytest.approx(active.mean())
    assert summary["min_value"] == values.min() and summary["max_value"] == values.max()
    assert summary["budget_used"] == pytest.approx(info["budget_used"])
    assert summary["initial_budget"] == 0.3
    # a new episode starts new statistics
    env.reset(options={"state": x0.tolist(), "budget": 0.3})
    assert env.episode_summary()["steps"] == 0


def _dive_with_the_smooth_rule(table) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray, bool]]:
    """A filter built from ``table``'s path with ``rule="smooth"``; from a certified start a policy that dives (full
    thrust down) under random wind: each step's (reason, policy's, applied and chosen action, certified)."""
    env = SafetyFilter(gym.make(ENV_ID, wind="random"), str(table.path), rule="smooth")
    env.reset(seed=1, options={"state": deep_start(table).tolist(), "budget": 0.3})
    rows = []
    for _ in range(100):
        _, _, terminated, truncated, info = env.step(np.array([-1.0], np.float32))
        rows.append((info["filter_reason"], *(np.asarray(info[k], float) for k in
                                              ("policy_action", "applied_action", "optimal_action")),
                     info["certified"]))
        if terminated or truncated:
            break
    return rows


def _is_plan_step(reason, applied, best) -> bool:
    """A step reported as a blend that applies the chosen candidate itself: what a step that follows a cell plan
    (filters.compiled._follow_plan) would look like if its reason were taken from the bisection's ``lam``."""
    return reason == "blend" and np.array_equal(applied, best)


def test_table_path_and_smooth_rule(pointmass_held_table):
    """Every step of the dive stays certified; a pass applies the policy's action unchanged, a blend a point
    strictly between the chosen candidate and the policy's action at one of the bisection's
    ``k / 2**smooth_iterations`` steps, an optimal step the candidate itself; and the dive gets blended."""
    steps = 2 ** ValueFilter(pointmass_held_table, 0.01, rule="smooth").smooth_iterations
    rows = _dive_with_the_smooth_rule(pointmass_held_table)
    for i, (reason, pol, applied, best, certified) in enumerate(rows):
        assert certified, (i, reason)
        if reason == "pass":
            np.testing.assert_array_equal(applied, pol)
        elif reason == "blend":
            lam = float((applied - best)[0] / (pol - best)[0])
            # float32 actions in [-1, 1]: lam is k / steps up to a few float32 ulps over |pol - best| >= 1 / steps
            k = lam * steps
            assert 1 <= round(k) <= steps - 1 and abs(k - round(k)) < 1e-3, (i, lam)
        else:
            assert reason == "optimal", (i, reason)
            np.testing.assert_array_equal(applied, best)
    assert sum(r[0] == "blend" for r in rows) >= 1, [r[0] for r in rows]


def test_smooth_rule_reports_plan_steps_as_candidates(pointmass_held_table):
    rows = _dive_with_the_smooth_rule(pointmass_held_table)
    assert not [i for i, r in enumerate(rows) if _is_plan_step(r[0], r[2], r[3])]


def test_mismatched_table_is_an_error_at_construction(pointmass_table):
    with pytest.raises(TableError, match="d_max"):
        SafetyFilter(gym.make(ENV_ID, model_params={"d_max": 5.0}), pointmass_table)
    with pytest.raises(TableError, match="glider|pointmass"):
        SafetyFilter(gym.make("softreach/GliderLanding-v0"), pointmass_table)
    with pytest.raises(TableError, match="eps"):
        SafetyFilter(gym.make(ENV_ID, eps=0.01), pointmass_table)
    with pytest.raises(TypeError, match="state"):
        SafetyFilter(gym.make("CartPole-v1"), pointmass_table)


def test_a_shared_value_filter(pointmass_table):
    """Many environments can share one core (the margin field is computed once)."""
    core = ValueFilter(pointmass_table, 0.01)
    a = SafetyFilter(gym.make(ENV_ID), value_filter=core)
    b = SafetyFilter(gym.make(ENV_ID), pointmass_table, value_filter=core)
    assert a.value_filter is core and b.value_filter is core and a.rule == "switch"
    x0 = deep_start(pointmass_table).tolist()
    for env in (a, b):
        env.reset(options={"state": x0, "budget": 0.3})
    ia = a.step(np.array([0.5], np.float32))[-1]
    ib = b.step(np.array([0.5], np.float32))[-1]
    assert ia["value"] == ib["value"] and ia["filter_active"] == ib["filter_active"]
    with pytest.raises(ValueError, match="dt"):
        SafetyFilter(gym.make(ENV_ID, dt=0.02, max_episode_steps=50), value_filter=core)
    with pytest.raises(ValueError, match="rule"):
        SafetyFilter(gym.make(ENV_ID), value_filter=core, rule="smooth")
    with pytest.raises(ValueError, match="margin"):
        SafetyFilter(gym.make(ENV_ID), value_filter=core, margin=0.2)
    with pytest.raises(TableError, match="d_max"):
        SafetyFilter(gym.make(ENV_ID, model_params={"d_max": 5.0}), value_filter=core)


def test_bad_actions_raise_before_the_env_steps(pointmass_table):
    env = SafetyFilter(gym.make(ENV_ID), pointmass_table)
    with pytest.raises(gym.error.ResetNeeded):
        env.step(np.zeros(1, np.float32))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(2, np.float32))


def test_unsafe_start_runs_to_the_end(pointmass_table):
    """A start outside the safe set (too high to land in the time left): the filter is not certified there, acts at
    every step, says so, and the episode ends normally (crash or late), without an exception."""
    env = SafetyFilter(gym.make(ENV_ID), pointmass_table)
    _, info = env.reset(options={"state": [0.0, 15.0], "budget": 0.3, "time": 0.9})
    assert info["value"] > 0 and not info["certified"]
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([1.0], np.float32))
        done = terminated or truncated
        assert info["filter_active"] and info["filter_reason"] in ("uncertified", "after_horizon")
        assert not info["certified"]
    assert not info["landed"] and info["filter_episode"]["intervention_rate"] == 1.0


def _make(table_path):
    def thunk():
        return SafetyFilter(gym.make(ENV_ID, wind="random"), table_path)
    return thunk


@pytest.mark.parametrize("vector", ["sync", "async"])
def test_gymnasium_vector_envs(pointmass_table_path, vector):
    cls = gym.vector.SyncVectorEnv if vector == "sync" else gym.vector.AsyncVectorEnv
    envs = cls([_make(pointmass_table_path) for _ in range(2)])
    try:
        envs.reset(seed=0)
        filtered_steps = ends = 0
        for _ in range(120):
            obs, reward, terminated, truncated, infos = envs.step(envs.action_space.sample())
            # a step that auto-resets a sub-environment carries its reset info (value, margin) instead
            assert infos["value"].shape == (2,)
            if "filter_active" in infos:
                stepped = infos["_filter_active"]
                filtered_steps += int(stepped.sum())
                assert infos["applied_action"].shape == (2, 1)
                assert np.all(np.isin(infos["filter_reason"][stepped], ["pass", "optimal", "uncertified", "outside_domain"]))
            if "filter_episode" in infos:
                ends += int(infos["_filter_episode"].sum())
                rate = infos["filter_episode"]["intervention_rate"][infos["_filter_episode"]]
                assert np.all((rate >= 0) & (rate <= 1))
        assert filtered_steps > 150 and ends >= 2  # episodes (at most 100 steps) ended and reported a summary
    finally:
        envs.close()


def test_stable_baselines3_make_vec_env(pointmass_table_path):
    import stable_baselines3  # noqa: F401
    from stable_baselines3.common.env_util import make_vec_env

    venv = make_vec_env(ENV_ID, n_envs=2, seed=0, wrapper_class=SafetyFilter,
                        wrapper_kwargs={"table": pointmass_table_path})
    try:
        venv.reset()
        ends = 0
        for _ in range(110):
            _, _, dones, infos = venv.step(np.array([venv.action_space.sample() for _ in range(2)]))
            for info in infos:
                if "filter_active" in info:  # (SB3 resets inside step; the terminal step's info is kept)
                    assert info["applied_action"].shape == (1,) and info["filter_reason"] in ("pass", "optimal", "uncertified")
                    assert info["filter_active"] == (info["filter_reason"] != "pass")
            ends += sum("filter_episode" in info for info in infos)
        assert ends >= 2
    finally:
        venv.close()


def test_applied_action_is_what_the_env_applies_for_out_of_range_actions(pointmass_held_table):
    env = SafetyFilter(gym.make(ENV_ID), pointmass_held_table)
    env.reset(seed=0, options={"state": [0.0, 5.0], "budget": 0.3})
    seen = set()
    for action in (5.0, -7.5, 5.0, 1.5):
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        seen.add(info["filter_active"])
        assert abs(float(info["applied_action"][0])) <= 1.0
        np.testing.assert_allclose(info["action_physical"], 60.0 * info["applied_action"].astype(float), rtol=1e-6)
        assert info["policy_action"][0] == np.float32(action)  # the policy's own action is reported as given
        if terminated or truncated:
            break
    assert False in seen  # at least one out-of-range action passed the filter (the case that was misreported)
