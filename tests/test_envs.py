"""Behaviour of the landing environments: dynamics, budget, episode end, rewards, inputs, wind modes."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
import softreach.reach as reach
from softreach.envs import GliderLandingEnv, PointMassLandingEnv
from softreach.reach.sim.integrator import integrate_period
from softreach.reach.models import get_model

PM = "softreach/PointMassLanding-v0"
GL = "softreach/GliderLanding-v0"
DEG = math.pi / 180.0


def run(env, actions, **reset_kwargs):
    """Reset then step through ``actions`` until the episode ends; return the list of step results."""
    env.reset(**reset_kwargs)
    out = []
    for a in actions:
        res = env.step(np.asarray(a, dtype=np.float32))
        out.append(res)
        if res[2] or res[3]:
            break
    return out


# --------------------------------------------------------------------------------------------- registration


@pytest.mark.parametrize("env_id, cls, steps", [(PM, PointMassLandingEnv, 100), (GL, GliderLandingEnv, 100)])
def test_registered_with_horizon_consistent_step_limit(env_id, cls, steps):
    spec = gym.spec(env_id)
    env = gym.make(env_id)
    inner = env.unwrapped
    assert isinstance(inner, cls)
    assert spec.max_episode_steps == steps
    assert math.isclose(steps * inner.dt, inner.horizon)
    # the "module:id" form resolves too (the fresh-interpreter case is in test_envs_integration.py)
    assert isinstance(gym.make("softreach.envs:" + env_id).unwrapped, cls)


def test_spaces_and_observation_layout():
    env = PointMassLandingEnv()
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    assert env.observation_space.dtype == np.float32 and env.observation_space.shape == (4,)
    obs, info = env.reset(seed=3, options={"state": [2.5, 7.0], "budget": 0.3, "time": 0.25})
    np.testing.assert_allclose(obs, np.float32([2.5, 7.0, 0.3, 0.75]))
    assert obs.dtype == np.float32 and obs in env.observation_space
    assert info["budget"] == 0.3 and info["budget_used"] == 0.0 and info["cost"] == 0.0
    genv = GliderLandingEnv()
    assert genv.observation_space.shape == (5,) and genv.action_space.shape == (1,)
    obs, _ = genv.reset(options={"state": [30.0, 70.0, -2 * DEG], "budget": 5.0})
    np.testing.assert_allclose(obs, np.float32([30.0, 70.0, -2 * DEG, 5.0, 10.0]), rtol=1e-6)


def test_action_mapping_physical_units():
    env = PointMassLandingEnv()
    np.testing.assert_allclose(env.physical_action([-1.0, 0.0, 1.0]), [-60.0, 0.0, 60.0])
    np.testing.assert_allclose(env.normalized_action([9.8]), [9.8 / 60.0], rtol=1e-6)
    genv = GliderLandingEnv()
    np.testing.assert_allclose(genv.alpha_degrees([[-1.0], [0.0], [1.0]]), [[0.0], [6.5], [13.0]], atol=1e-12)
    np.testing.assert_allclose(genv.normalized_action_from_degrees([6.5]), [0.0], atol=1e-7)
    np.testing.assert_allclose(genv.physical_action([1.0]), [13 * DEG])
    genv.reset(options={"state": [30.0, 70.0, -2 * DEG]})
    _, _, _, _, info = genv.step(genv.normalized_action_from_degrees([4.0]))
    np.testing.assert_allclose(info["action_physical"], [4 * DEG], rtol=1e-6)


# --------------------------------------------------------------------------------------------- dynamics = model


def test_pointmass_step_is_exact_solution_of_model():
    """Held inputs: v and y follow the closed form of y'' = u - g + d to round-off."""
    env = PointMassLandingEnv(wind="constant", wind_value=-4.0)
    rng = np.random.default_rng(0)
    for _ in range(20):
        v0, y0 = rng.uniform(-9, 9), rng.uniform(3, 15)
        env.reset(options={"state": [v0, y0], "budget": 0.0})
        a = rng.uniform(-1, 1)
        obs, *_ = env.step(np.float32([a]))
        u = 60.0 * float(np.float32(a))
        acc = u - 9.8 - 4.0
        v1, y1 = v0 + acc * 0.01, y0 + v0 * 0.01 + 0.5 * acc * 0.01**2
        np.testing.assert_allclose(env.state, [v1, y1], rtol=0, atol=1e-13)


def test_env_calls_the_models_own_f(monkeypatch):
    """The integrator evaluates ``model.f`` (4 RK4 stages per sub-step) and nothing else; a changed model
    parameter changes the motion accordingly."""
    env = GliderLandingEnv()
    env.reset(options={"state": [30.0, 70.0, -2 * DEG]})
    calls = []
    original = type(env.model).f

    def spy(self, t, x, a, b):
        calls.append((t, tuple(x), tuple(a), tuple(b)))
        return original(self, t, x, a, b)

    monkeypatch.setattr(type(env.model), "f", spy)
    env.step(np.float32([0.0]))
    assert len(calls) == 4 * env.n_substeps
    assert calls[0][0] == 0.0 and calls[0][1] == (30.0, 70.0, -2 * DEG)
    monkeypatch.undo()

    moon = PointMassLandingEnv(model_params={"gravity": 1.62})
    moon.reset(options={"state": [0.0, 10.0]})
    moon.step(np.float32([0.0]))
    np.testing.assert_allclose(moon.state[0], -1.62 * 0.01, rtol=1e-12)


def test_glider_step_agrees_with_solver_model_to_roundoff():
    """One control period of the env against a tolerance-1e-13 integration of the model's ``f_array``."""
    model = get_model("glider")
    env = GliderLandingEnv(wind="constant", wind_value=3000.0)
    rng = np.random.default_rng(1)
    for _ in range(8):
        x0 = [rng.uniform(5, 40), rng.uniform(62, 82), rng.uniform(-2.9, -0.1) * DEG]
        env.reset(options={"state": x0})
        act = np.float32([rng.uniform(-1, 1)])
        env.step(act)
        alpha = env.physical_action(act)

        def rhs(t, x):
            return model.f_array(t, np.asarray(x)[None, :], alpha[None, :], np.array([[3000.0]]))[0]

        sol = solve_ivp(rhs, (0.0, 0.1), x0, method="DOP853", rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(env.state, sol.y[:, -1], rtol=0, atol=1e-9)


# --------------------------------------------------------------------------------------------- the budget


def _exact_heps_integral(c0: float, c1: float, h: float, eps: float) -> float:
    """``int_0^h clip(c(t)/eps, 0, 1) dt`` for ``c`` linear from ``c0`` to ``c1``."""

    def F(c):  # antiderivative of clip(c/eps, 0, 1) in c
        if c <= 0:
            return 0.0
        if c < eps:
            return c * c / (2 * eps)
        return c - eps / 2

    if c1 == c0:
        return h * min(1.0, max(0.0, c0 / eps))
    return h * (F(c1) - F(c0)) / (c1 - c0)


def test_budget_drains_by_exactly_the_violation_time_pointmass():
    """A scripted dive leaves C2 (v < -10) and comes back; z drops by the time spent outside, z < 0 is
    allowed and counted, and the per-step ``cost`` is that time step by step."""
    eps = 1e-3
    env = PointMassLandingEnv(eps=eps)
    q = 0.03
    obs, _ = env.reset(options={"state": [-9.0, 15.0], "budget": q})
    actions = [-1.0] * 5 + [1.0] * 10 + [0.0] * 5
    exact = indicator = 0.0
    costs, zs, exceeded = [], [], []
    for a in actions:
        v0 = env.state[0]
        obs, r, term, trunc, info = env.step(np.float32([a]))
        assert not term and not trunc
        v1 = env.state[0]
        exact += _exact_heps_integral(-10.0 - v0, -10.0 - v1, 0.01, eps)
        # time with v < -10 on the linear speed segment
        frac = 0.0
        if v0 < -10 and v1 < -10:
            frac = 1.0
        elif (v0 < -10) != (v1 < -10):
            cross = (-10.0 - v0) / (v1 - v0)
            frac = cross if v0 < -10 else 1.0 - cross
        indicator += 0.01 * frac
        costs.append(info["cost"])
        zs.append(info["budget"])
        exceeded.append(info["budget_exceeded"])
        assert info["soft_violation"] == (v1 < -10.0)
        assert obs[2] == np.float32(info["budget"])
    used = q - zs[-1]
    assert used == pytest.approx(exact, abs=3e-6)  # bisection to 1e-6 s at each of the two crossings
    assert used == pytest.approx(indicator, abs=2 * eps / 50.0 + 3e-6)  # eps smoothing: eps/|v'| per crossing
    assert used > 0.05  # really left C2 for a while
    assert sum(costs) == pytest.approx(used, abs=1e-15)
    # whole periods outside the eps band cost exactly dt; whole periods inside cost exactly 0
    assert 0.01 in costs and costs[-1] == 0.0 and costs[0] == 0.0
    # the budget went negative and the episode went on, flagged
    assert zs[-1] < 0 and exceeded[-1] and not exceeded[0]


def test_budget_pointmass_without_refinement_would_be_coarse():
    """Guard that the exactness above comes from the bisection: with it disabled the same script is off by
    more than the tolerance used above (so that test can fail)."""
    model = get_model("pointmass")
    x = [-9.9, 15.0]
    # one 0.01 s period at full down-thrust crossing v = -10 early in the period
    _, cost_fine, _, _ = integrate_period(model, 0.0, x, [-60.0], [0.0], 0.01, 1, 1e-3, 1e-7)
    _, cost_coarse, _, _ = integrate_period(model, 0.0, x, [-60.0], [0.0], 0.01, 1, 1e-3, 1.0)
    v1 = -9.9 - 69.8 * 0.01
    exact = _exact_heps_integral(-10.0 + 9.9, -10.0 - v1, 0.01, 1e-3)
    assert cost_fine == pytest.approx(exact, abs=1e-6)
    assert abs(cost_coarse - exact) > 1e-4


def test_budget_glider_matches_dense_reference():
    """Glider: V drops below 66 m/s and a strong (unclipped) tail wind brings it back; every step's cost equals
    int h_eps dt along a tolerance-1e-12 solution of the model from the same state with the same inputs."""
    model = get_model("glider")
    eps = 1e-3

    def wind(t, state, budget, action):
        return -10000.0 if t < 0.8 else 60000.0

    def hold_gamma(env):  # a simple autopilot: trim angle of attack plus a flight-path correction
        h, V, g = env.state
        alpha = model.trim_alpha(V, g) + 2.0 * (-2 * DEG - g)
        return env.normalized_action([alpha])

    env = GliderLandingEnv(wind=wind, clip_wind=False, eps=eps)
    env.reset(options={"state": [35.0, 66.05, -2 * DEG], "budget": 2.0})
    total, ref_total, left, back = 0.0, 0.0, False, False
    for _ in range(45):
        x0 = env.state
        _, _, term, trunc, info = env.step(hold_gamma(env))
        assert not term and not trunc
        a, b = info["action_physical"], info["wind"]
        sol = solve_ivp(lambda t, x: np.array(model.f(t, list(x), list(a), list(b)), dtype=float), (0.0, 0.1), x0,
                        method="DOP853", rtol=1e-12, atol=1e-12, dense_output=True)
        ts = np.linspace(0.0, 0.1, 40001)
        xs = sol.sol(ts)
        rate = model.violation_rate(ts, list(xs), eps)
        ref = float(np.sum(0.5 * (rate[1:] + rate[:-1]) * np.diff(ts)))
        assert info["cost"] == pytest.approx(ref, abs=2e-5)
        total += info["cost"]
        ref_total += ref
        left |= info["soft_violation"]
        back |= left and not info["soft_violation"]
    assert left and back
    assert total == pytest.approx(ref_total, abs=3e-5)
    assert 1.0 < total < 4.5


# --------------------------------------------------------------------------------------------- episode end


def test_hard_violation_terminates_pointmass():
    env = PointMassLandingEnv()
    res = run(env, [[-1.0]] * 50, options={"state": [-13.0, 15.0], "budget": 0.6})
    obs, r, term, trunc, info = res[-1]
    assert term is True and trunc is False
    assert info["hard_violation"] and not info["landed"] and not info["is_success"]
    assert obs[0] < -15.0
    assert info["reward_failure"] == -100.0 and info["reward_landing"] == 0.0
    assert r == pytest.approx(info["reward_landing"] + info["reward_failure"] + info["reward_shaping"])
    assert all(not (step[2] or step[3]) for step in res[:-1])
    # crash into the ground (y < 0) is a hard violation too
    res = run(env, [[0.0]] * 50, options={"state": [-5.0, 0.2]})
    assert res[-1][2] and res[-1][4]["hard_violation"] and res[-1][0][1] < 0


def test_landing_terminates_with_landed_flag_pointmass():
    env = PointMassLandingEnv()
    hover = env.normalized_action([9.8])
    res = run(env, [hover] * 50, options={"state": [-0.5, 0.723], "budget": 0.0})
    obs, r, term, trunc, info = res[-1]
    assert len(res) == 5  # 0.723 - 0.005 k <= 0.7 first at k = 5
    assert term is True and trunc is False
    assert info["landed"] and info["is_success"] and not info["hard_violation"]
    assert info["reward_landing"] == 100.0 and info["reward_failure"] == 0.0
    # too fast: inside the altitude band but outside the speed band, no landing
    res = run(env, [hover] * 3, options={"state": [-1.5, 0.6]})
    assert not any(step[4]["landed"] for step in res)


def test_glider_landing_needs_soft_constraint_at_touchdown():
    model = get_model("glider")

    def trim_action(env):
        _, V, g = env.state
        return env.normalized_action([model.trim_alpha(V, g)])

    env = GliderLandingEnv()
    env.reset(options={"state": [0.65, 70.0, -0.5 * DEG], "budget": 0.0})
    for _ in range(5):
        obs, r, term, trunc, info = env.step(trim_action(env))
        if term:
            break
    assert term and info["landed"] and not info["hard_violation"]
    # the same touchdown at 64 m/s (inside C1, outside C2) is not a landing; the glider hits the ground
    env.reset(options={"state": [0.65, 64.0, -0.5 * DEG], "budget": 5.0})
    seen_band = False
    for _ in range(30):
        obs, r, term, trunc, info = env.step(trim_action(env))
        seen_band |= abs(obs[0]) <= 0.5
        assert not info["landed"]
        if term:
            break
    assert seen_band and term and info["hard_violation"] and obs[0] < 0


def test_glider_hard_violation_on_flight_path_corridor():
    env = GliderLandingEnv()
    res = run(env, [[-1.0]] * 100, options={"state": [30.0, 70.0, -2.9 * DEG]})
    obs, r, term, trunc, info = res[-1]
    assert term is True and info["hard_violation"] and obs[2] < -3 * DEG


def test_truncation_at_horizon_with_start_time_and_python_bools():
    env = PointMassLandingEnv()
    hover = env.normalized_action([9.8])
    env.reset(options={"state": [0.0, 10.0], "time": 0.975})
    results = [env.step(hover) for _ in range(3)]
    for obs, r, term, trunc, info in results:
        assert type(term) is bool and type(trunc) is bool
    assert [res[3] for res in results] == [False, False, True]
    obs, r, term, trunc, info = results[-1]
    assert info["t"] == 1.0 and obs[3] == 0.0 and not term
    assert info["reward_failure"] == -100.0  # late: reached the horizon without landing
    # the last period was shortened to 0.005 s: hovering at v = 0 moves nothing, the time left is exact
    assert results[1][0][3] == np.float32(0.005)


def test_truncated_by_registered_time_limit_after_100_steps():
    env = gym.make(PM)
    env.reset(seed=0, options={"state": [0.0, 17.0], "budget": 0.0})
    hover = env.unwrapped.normalized_action([9.8])
    n = 0
    while True:
        n += 1
        _, _, term, trunc, _ = env.step(hover)
        if term or trunc:
            break
    assert n == 100 and trunc and not term


def test_progress_shaping_telescopes():
    env = PointMassLandingEnv(effort_weight=0.0)
    env.reset(options={"state": [0.0, 5.0]})
    g0 = float(env.model.target(0.0, [0.0, 5.0]))
    total = 0.0
    rng = np.random.default_rng(2)
    for _ in range(30):
        *_, info = env.step(np.float32([rng.uniform(-0.3, 0.3)]))
        total += info["reward_shaping"]
    g1 = float(env.model.target(0.0, list(env.state)))
    assert total == pytest.approx(10.0 * (max(g0, 0) - max(g1, 0)), abs=1e-9)
    # the effort term: full thrust for a whole episode costs effort_weight
    env2 = PointMassLandingEnv(progress_weight=0.0)
    env2.reset(options={"state": [0.0, 10.0]})
    *_, info = env2.step(np.float32([1.0]))
    assert info["reward_shaping"] == pytest.approx(-10.0 * 0.01)


# --------------------------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("env_cls", [PointMassLandingEnv, GliderLandingEnv])
def test_bad_actions_raise_clear_errors(env_cls):
    env = env_cls()
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be finite, got \[nan\]"):
        env.step(np.array([np.nan], dtype=np.float32))
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.inf]))
    with pytest.raises(ValueError, match=r"shape \(1,\).*\(2,\)"):
        env.step(np.zeros(2, dtype=np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros((1, 1), dtype=np.float32))
    with pytest.raises(ValueError, match="action"):
        env.step("up")
    # out-of-range finite actions are clipped
    *_, info = env.step(np.float32([7.0]))
    np.testing.assert_allclose(info["action_physical"], env.action_high_physical)
    *_, info = env.step([-3.0])
    np.testing.assert_allclose(info["action_physical"], env.action_low_physical)


def test_step_before_reset_raises():
    with pytest.raises(gym.error.ResetNeeded):
        PointMassLandingEnv().step(np.float32([0.0]))


def test_bad_reset_options_name_the_problem():
    env = PointMassLandingEnv()
    with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['altitude', 'speed'\]"):
        env.reset(options={"speed": 1.0, "altitude": 3.0})
    with pytest.raises(ValueError, match=r"y=25\.0 not in \[-5, 20\]"):
        env.reset(options={"state": [0.0, 25.0]})
    with pytest.raises(ValueError, match="v=-30"):
        env.reset(options={"state": [-30.0, 5.0]})
    with pytest.raises(ValueError, match="shape"):
        env.reset(options={"state": [0.0, 5.0, 1.0]})
    with pytest.raises(ValueError, match="finite"):
        env.reset(options={"state": [np.nan, 5.0]})
    with pytest.raises(ValueError, match=r"budget.*\[0, T\]"):
        env.reset(options={"budget": 1.5})
    with pytest.raises(ValueError, match="budget"):
        env.reset(options={"budget": -0.1})
    with pytest.raises(ValueError, match="time"):
        env.reset(options={"time": 1.0})
    genv = GliderLandingEnv()
    with pytest.raises(ValueError, match="gamma=-2.0 .*looks like degrees"):
        genv.reset(options={"state": [20.0, 70.0, -2.0]})  # degrees passed as radians
    with pytest.raises(ValueError, match="V=50"):
        genv.reset(options={"state": [20.0, 50.0, -0.01]})


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="wind must be one of"):
        PointMassLandingEnv(wind="gale")
    with pytest.raises(ValueError, match="wind_value"):
        PointMassLandingEnv(wind="constant")
    with pytest.raises(ValueError, match="outside the disturbance box"):
        PointMassLandingEnv(wind="constant", wind_value=25.0)
    with pytest.raises(ValueError, match="wind_value= is used only with wind='constant'"):
        PointMassLandingEnv(wind="random", wind_value=1.0)
    with pytest.raises(ValueError, match="budget"):
        PointMassLandingEnv(budget=(0.5, 0.1))
    with pytest.raises(ValueError, match="init_state_high"):
        PointMassLandingEnv(init_state_high=(5.0, 30.0))
    with pytest.raises(ValueError, match="n_substeps"):
        PointMassLandingEnv(n_substeps=0)


# --------------------------------------------------------------------------------------------- wind modes


def test_wind_none_constant_and_callable():
    env = PointMassLandingEnv()
    env.reset(options={"state": [0.0, 10.0]})
    *_, info = env.step(np.float32([0.0]))
    np.testing.assert_array_equal(info["wind"], [0.0])

    env = PointMassLandingEnv(wind="constant", wind_value=7.5)
    env.reset(options={"state": [0.0, 10.0]})
    *_, info = env.step(np.float32([0.0]))
    np.testing.assert_array_equal(info["wind"], [7.5])
    assert env.state[0] == pytest.approx((7.5 - 9.8) * 0.01, abs=1e-14)

    seen = []

    def gust(t, state, budget, action):
        seen.append((t, state.copy(), budget, action.copy()))
        return 100.0 if t < 0.02 else [-3.0]

    env = PointMassLandingEnv(wind=gust)
    env.reset(options={"state": [1.0, 10.0], "budget": 0.2})
    infos = [env.step(np.float32([0.5]))[4] for _ in range(3)]
    assert [float(i["wind"][0]) for i in infos] == [10.0, 10.0, -3.0]  # clipped to the box [-10, 10]
    t0, s0, z0, a0 = seen[0]
    assert t0 == 0.0 and s0.tolist() == [1.0, 10.0] and z0 == 0.2 and a0.tolist() == [30.0]

    free = PointMassLandingEnv(wind=gust, clip_wind=False)
    free.reset(options={"state": [1.0, 10.0]})
    assert free.step(np.float32([0.0]))[4]["wind"][0] == 100.0

    bad = PointMassLandingEnv(wind=lambda t, s, z, a: float("nan"))
    bad.reset(seed=0)
    with pytest.raises(ValueError, match="wind callable.*finite"):
        bad.step(np.float32([0.0]))


def test_random_wind_is_bounded_correlated_and_seeded():
    env = GliderLandingEnv(wind="random", gust_std=8000.0, gust_tau=1.0)

    def winds(seed):
        env.reset(seed=seed, options={"state": [40.0, 72.0, -1 * DEG]})
        return np.array([env.step(np.float32([-0.1]))[4]["wind"][0] for _ in range(60)])

    w1, w2, w3 = winds(5), winds(5), winds(6)
    np.testing.assert_array_equal(w1, w2)
    assert not np.array_equal(w1, w3)
    assert np.all(np.abs(w1) <= 10000.0) and np.std(w1) > 100.0
    # Ornstein-Uhlenbeck with tau = 1 s sampled at 0.1 s: successive values are strongly correlated
    assert np.corrcoef(w1[:-1], w1[1:])[0, 1] > 0.6


def test_adversarial_wind_needs_a_table():
    with pytest.raises(ValueError, match="wind_table"):
        PointMassLandingEnv(wind="adversarial")
    with pytest.raises(TypeError, match="worst_disturbance"):
        PointMassLandingEnv(wind="adversarial", wind_table=object())


class FakeTable:
    """Stands in for a W_eps table: the contract is ``worst_disturbance(t, x (N, n), z (N,)) -> (N, k)``."""

    def __init__(self, model, value=-10.0):
        self.model_metadata = {"name": model.name, "parameters": model.parameters()}
        self.calls = []
        self.value = value

    def worst_disturbance(self, t, x, z):
        self.calls.append((t, np.array(x), np.array(z)))
        return np.full((len(x), 1), self.value)


def test_adversarial_wind_queries_the_table_contract():
    model = get_model("pointmass")
    table = FakeTable(model, value=-10.0)
    env = PointMassLandingEnv(wind="adversarial", wind_table=table)
    env.reset(options={"state": [-2.0, 10.0], "budget": 0.3})
    *_, info = env.step(np.float32([0.0]))
    t, x, z = table.calls[0]
    assert t == 0.0 and x.shape == (1, 2) and x.tolist() == [[-2.0, 10.0]] and z.tolist() == [0.3]
    np.testing.assert_array_equal(info["wind"], [-10.0])
    assert env.state[0] == pytest.approx(-2.0 + (-9.8 - 10.0) * 0.01, abs=1e-13)
    other = FakeTable(get_model("pointmass", d_max=5.0))
    with pytest.raises(ValueError, match="d_max"):
        PointMassLandingEnv(wind="adversarial", wind_table=other)
    with pytest.raises(ValueError, match="glider"):
        PointMassLandingEnv(wind="adversarial", wind_table=FakeTable(get_model("glider")))


# --------------------------------------------------------------------------------------------- a real W_eps table

needs_tables = pytest.mark.skipif(not (hasattr(reach, "load_table") and hasattr(reach, "solve_table")),
                                  reason="softreach.reach.load_table / solve_table not available")


@pytest.fixture(scope="module")
def small_pointmass_table(tmp_path_factory):
    """A coarse point-mass table (21 x 21 x 8, 3 snapshots; well under a second)."""
    path = tmp_path_factory.mktemp("tables") / "pointmass_small.srt"
    cfg = reach.SolveConfig(shape=(21, 21), budget_points=8, snapshots=3,
                            settings=reach.SolverSettings(scheme="eno2", time_order=2, backend="numpy"))
    reach.solve_table(reach.get_model("pointmass"), cfg, path, progress=False, resume=False)
    return path


def _worst_wind(table, t: float, x: np.ndarray, z: float) -> float | None:
    """The point mass's worst wind by the spec, not by the code the env calls: ``v' = u - g + d`` with
    ``|d| <= 10``, so ``b* = argmax_d dW/dv * d = 10 sign(dW/dv)``, the slope read as the central difference of
    ``W_eps`` over one grid spacing along ``v`` (the table's gradient rule) at the budget ``max(z, r)`` (``W_eps``
    is flat at ``z = 0``; r the table's budget resolution). ``None`` where that stencil leaves the grid or the
    slope is a rounding-level tie."""
    g = table.grid("W_eps")
    h = g.spacing[0]
    if not (g.lo[0] + h <= x[0] <= g.hi[0] - h):
        return None
    zq = np.array([max(z, table.budget_resolution)] * 2)
    w_up, w_down = table.value(t, np.array([x + [h, 0.0], x - [h, 0.0]]), zq)
    slope = w_up - w_down
    if abs(slope) <= 1e-9 * max(abs(w_up), abs(w_down), 1.0):
        return None
    return 10.0 * math.copysign(1.0, slope)


@needs_tables
def test_adversarial_wind_from_a_real_table(small_pointmass_table):
    """The env's adversarial wind is the spec's b* from the table, for a table given by path (str or Path) or
    loaded; the starts make the wind blow both ways (a slow descent high up: +10, an upward push that delays the
    landing; a fast descent: -10, a downward push past the soft speed limit)."""
    table = reach.load_table(small_pointmass_table)
    for source in (str(small_pointmass_table), small_pointmass_table, table):
        signs = set()
        for start in ([-4.0, 12.0], [-12.0, 10.0]):
            env = PointMassLandingEnv(wind="adversarial", wind_table=source)
            env.reset(options={"state": start, "budget": 0.3})
            checked = 0
            for k in range(15):
                t, x, z = env.time, env.state.copy(), env.budget
                *_, term, trunc, info = env.step(np.float32([0.1 * math.sin(k)]))
                expected = _worst_wind(table, t, x, z)
                if expected is not None:
                    assert info["wind"].tolist() == [expected], (start, k, x.tolist(), z)
                    signs.add(expected)
                    checked += 1
                if term or trunc:
                    break
            assert checked >= 10, (start, checked)
        assert signs == {-10.0, 10.0}
    # a table loaded from a path travels by path when pickled, and answers the same
    env = PointMassLandingEnv(wind="adversarial", wind_table=str(small_pointmass_table))
    env.reset(options={"state": [-4.0, 12.0], "budget": 0.3})
    env.step(np.float32([0.0]))
    clone = pickle.loads(pickle.dumps(env))
    assert clone.wind_table is not None and clone.wind_table is not env.wind_table
    np.testing.assert_array_equal(env.step(np.float32([0.2]))[0], clone.step(np.float32([0.2]))[0])


@needs_tables
def test_real_table_for_other_parameters_is_refused(small_pointmass_table):
    with pytest.raises(ValueError, match="d_max"):
        PointMassLandingEnv(wind="adversarial", wind_table=small_pointmass_table, model_params={"d_max": 5.0})
    with pytest.raises(ValueError, match="pointmass"):
        GliderLandingEnv(wind="adversarial", wind_table=small_pointmass_table)


@needs_tables
def test_real_table_with_other_eps_warns(small_pointmass_table):
    with pytest.warns(UserWarning, match="eps"):
        PointMassLandingEnv(wind="adversarial", wind_table=small_pointmass_table, eps=1e-2)
