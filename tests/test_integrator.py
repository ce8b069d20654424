"""One integrator behind the environments and the rollouts (:mod:`softreach.reach.sim.integrator`).

* the batched entry point (``N`` states at once) moves every state as the environments' own steps do, for every
  registered model (the point mass on its scalar fast path, the glider and the Dubins vehicle on the vectorised
  one), events included;
* the budget spent over a period that crosses the ``eps`` band of ``h_eps`` is its exact integral (the point
  mass's speed is linear in time, so ``h_eps`` is piecewise linear with kinks at known instants), where the
  plain RK4 sum of the stage rates is not;
* :func:`~softreach.reach.sim.simulate.rollout` and ``gymnasium.make("softreach/PointMassLanding-v0")`` give the same
  trajectories, landing times, violations and budgets for the same actions and winds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.reach.sim.integrator import episode_ends, integrate_batch, integrate_period, rk4_stages
from softreach.reach.models import get_model
from softreach.reach.registry import GENERIC_ENV_ID, env_id, model_names
from softreach.reach.sim.simulate import constant, rollout


def _env(name: str, **kwargs):
    model = get_model(name)
    ident = env_id(name)
    if ident == GENERIC_ENV_ID:
        return gym.make(ident, model=model, **kwargs).unwrapped
    return gym.make(ident, **kwargs).unwrapped


def _random_starts(name: str, rng: np.random.Generator, n: int) -> np.ndarray:
    """Starts in the model's start box and, for a third of them, on the edge of ``C2`` (so that the period
    crosses the kinks of ``h_eps``)."""
    model = get_model(name)
    lo, hi = (np.asarray(v, dtype=np.float64) for v in model.start_box)
    x = rng.uniform(lo, hi, (n, len(lo)))
    if name == "pointmass":
        x[::3, 0] = rng.choice([-10.0, 10.0], len(x[::3])) + rng.normal(0.0, 0.3, len(x[::3]))
    elif name == "glider":
        x[::3, 1] = rng.choice([66.0, 78.0], len(x[::3])) + rng.normal(0.0, 0.01, len(x[::3]))
    elif name == "dubins":  # on the soft zone's rim, heading across it
        zone, radius = np.asarray(model.params.zone), model.params.zone_radius
        ang = rng.uniform(0.0, 2.0 * np.pi, len(x[::3]))
        x[::3, :2] = zone + (radius + rng.normal(0.0, 0.02, len(ang)))[:, None] * np.stack([np.cos(ang),
                                                                                           np.sin(ang)], 1)
        x[::3, 2] = ang + np.pi + rng.uniform(-1.0, 1.0, len(ang))
    return x


@pytest.mark.parametrize("name", sorted(set(model_names()) & {"pointmass", "glider", "dubins"}))
def test_batched_period_equals_the_envs_steps(name):
    """Random states, actions and constant winds: one ``integrate_batch`` call over all of them against one
    environment step each (its own state, time, cost, end rate and events), to rounding."""
    model = get_model(name)
    rng = np.random.default_rng(11)
    n = 24
    x = _random_starts(name, rng, n)
    lo_b, hi_b = (np.asarray(v, dtype=np.float64) for v in model.disturbance_bounds)
    winds = rng.uniform(lo_b, hi_b, (n, len(lo_b)))
    actions = rng.uniform(-1.0, 1.0, (n, model.control_dim)).astype(np.float32)
    actions[::4] = np.sign(actions[::4])  # full thrust or turn: the fastest crossings
    t0 = 0.3 * model.horizon
    rows = []
    for i in range(n):
        env = _env(name, wind="constant", wind_value=winds[i].tolist(), budget=0.5)
        env.reset(seed=i, options={"state": x[i].tolist(), "budget": 0.5, "time": t0})
        _, _, terminated, _, info = env.step(actions[i])
        rows.append((env, info, terminated))
    env = rows[0][0]
    a = np.array([info["action_physical"] for _, info, _ in rows])
    b = np.array([info["wind"] for _, info, _ in rows])
    assert np.array_equal(b, winds)
    got = integrate_batch(model, t0, x, a, b, env.dt, env.n_substeps, env.eps, env.budget_resolution,
                          stop=lambda t, xc, r: episode_ends(model, t, xc, r))
    crossed = 0
    for i, (env_i, info, terminated) in enumerate(rows):
        end = np.array(model.wrap_state(got.x[i]))  # the env wraps periodic axes after the step
        np.testing.assert_allclose(end, env_i.state, rtol=1e-12, atol=1e-12)
        assert got.cost[i] == pytest.approx(info["cost"], rel=1e-12, abs=1e-15)
        assert t0 + got.elapsed[i] == pytest.approx(info["t"], rel=1e-14)
        assert (got.rate[i] > 0.0) == info["soft_violation"]
        hard = float(model.hard_constraint(info["t"], list(got.x[i]))) > 0.0
        assert hard == info["hard_violation"]
        crossed += 0.0 < info["cost"] < env.dt
    assert crossed >= 3  # the kinks of h_eps were crossed, and the quadrature's refinement ran


def test_single_state_paths_equal_the_batched_path():
    """integrate_period (scalar fast path and vectorised) and integrate_batch on one state each."""
    model = get_model("pointmass")
    rng = np.random.default_rng(12)
    for _ in range(200):
        x = [float(rng.choice([-10.0, 10.0]) + rng.normal(0.0, 0.2)), float(rng.uniform(0.5, 17.5))]
        a, b = [float(rng.uniform(-60.0, 60.0))], [float(rng.uniform(-10.0, 10.0))]
        eps = float(rng.choice([1e-3, 0.1]))
        one = integrate_period(model, 0.0, x, a, b, 0.01, 10, eps, 1e-6)
        vec = integrate_period(model, 0.0, x, a, b, 0.01, 10, eps, 1e-6, fast=None)
        batch = integrate_batch(model, 0.0, np.array([x]), np.array([a]), np.array([b]), 0.01, 10, eps, 1e-6)
        assert one == vec
        np.testing.assert_allclose(batch.x[0], one[0], rtol=1e-14, atol=1e-14)
        assert batch.cost[0] == pytest.approx(one[1], rel=1e-12, abs=1e-15)
        assert batch.rate[0] == pytest.approx(one[2], abs=1e-12) and batch.elapsed[0] == one[3]


def test_rk4_step_is_exact_for_a_quadratic_path():
    """RK4 integrates the point mass's motion (speed linear, altitude quadratic in time) exactly."""
    model = get_model("pointmass")
    v, y, u, d, h = -3.0, 9.0, 25.0, -4.0, 0.01
    acc = u - model.params.gravity + d
    xn, stages = rk4_stages(model.f_scalar, 0.0, [v, y], [u], [d], h)
    assert xn[0] == pytest.approx(v + acc * h, rel=1e-15)
    assert xn[1] == pytest.approx(y + v * h + 0.5 * acc * h * h, rel=1e-15)
    assert stages[1][0] == pytest.approx(v + acc * h / 2, rel=1e-15)
    arrays = rk4_stages(model.f, 0.0, [np.array([v, v]), np.array([y, y])], [np.array([u, u])],
                        [np.array([d, d])], h)[0]
    assert [list(c) for c in arrays] == [[xn[0]] * 2, [xn[1]] * 2]


@pytest.mark.parametrize("n", [1, 3, 5])
def test_rk4_step_is_the_rk4_polynomial_on_a_linear_system(n):
    """On ``x' = M x`` one RK4 step multiplies by ``I + hM + (hM)^2/2 + (hM)^3/6 + (hM)^4/24``, for any number of
    components, on floats and on component arrays alike."""
    rng = np.random.default_rng(n)
    M = rng.normal(size=(n, n))
    h = 0.1

    def f(t, x, a, b):
        return [sum(M[i, k] * x[k] for k in range(n)) for i in range(n)]

    hm = h * M
    amp = np.eye(n) + hm + hm @ hm / 2 + hm @ hm @ hm / 6 + hm @ hm @ hm @ hm / 24
    x0 = rng.normal(size=n)
    xn, stages = rk4_stages(f, 0.0, list(x0), [], [], h)
    np.testing.assert_allclose(xn, amp @ x0, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(stages[1], x0 + h / 2 * (M @ x0), rtol=1e-13, atol=1e-14)
    batch = rng.normal(size=(n, 4))
    xb = rk4_stages(f, 0.0, list(batch), [], [], h)[0]
    np.testing.assert_allclose(np.array(xb), amp @ batch, rtol=1e-12, atol=1e-13)


def _exact_budget(v0: float, acc: float, h: float, eps: float) -> float:
    """``int_0^h h_eps ds`` for ``c2 = max(-10 - v, v - 10)`` along ``v(s) = v0 + acc s`` (altitude inside its band):
    ``h_eps`` is linear between the instants where ``c2`` crosses ``0`` and ``eps``, so the trapezoid rule on the
    pieces between those instants is exact."""
    def rate(s: float) -> float:
        v = v0 + acc * s
        return min(1.0, max(0.0, max(-10.0 - v, v - 10.0) / eps))

    knots = {0.0, h}
    for level in (-10.0, -10.0 - eps, 10.0, 10.0 + eps):
        if acc != 0.0:
            s = (level - v0) / acc
            if 0.0 < s < h:
                knots.add(s)
    knots = sorted(knots)
    return math.fsum(0.5 * (rate(s0) + rate(s1)) * (s1 - s0) for s0, s1 in zip(knots, knots[1:]))


@pytest.mark.parametrize("v0, acc, eps", [(-9.9995, -30.0, 1e-3), (-10.0015, 45.0, 1e-3), (9.99, 60.2, 1e-3),
                                          (-10.02, 3.7, 0.05), (-9.97, -12.0, 0.05), (10.3, -58.0, 1e-3)])
def test_budget_over_a_period_crossing_the_eps_band_is_exact(v0, acc, eps):
    model = get_model("pointmass")
    g = model.params.gravity
    h, n_sub = 0.01, 10
    u, d = acc + g, 0.0
    if abs(u) > model.params.u_max:
        u, d = math.copysign(model.params.u_max, u), acc + g - math.copysign(model.params.u_max, u)
    x = [v0, 9.0]
    exact = _exact_budget(v0, u - g + d, h, eps)
    assert 0.0 < exact < h
    one = integrate_period(model, 0.0, x, [u], [d], h, n_sub, eps, 1e-9)
    batch = integrate_batch(model, 0.0, np.array([x, x]), np.array([[u], [u]]), np.array([[d], [d]]), h, n_sub,
                            eps, 1e-9)
    assert one[1] == pytest.approx(exact, rel=1e-9)
    assert batch.cost == pytest.approx([exact, exact], rel=1e-9)
    # at the environments' default resolution the error stays below that resolution per crossing
    assert abs(integrate_period(model, 0.0, x, [u], [d], h, n_sub, eps, 1e-6)[1] - exact) <= 2e-6
    # the plain RK4 sum of the stage rates (the speed at the stages is exact here) misses the kinks
    hs = h / n_sub
    a_net = u - g + d

    def rate(v: float) -> float:
        return min(1.0, max(0.0, max(-10.0 - v, v - 10.0) / eps))

    plain = math.fsum(hs / 6.0 * (rate(v0 + a_net * j * hs) + 4.0 * rate(v0 + a_net * (j + 0.5) * hs)
                                  + rate(v0 + a_net * (j + 1) * hs)) for j in range(n_sub))
    assert abs(plain - exact) > 1e-6 * exact


def _env_episode(x0, budget, action, wind):
    env = gym.make("softreach/PointMassLanding-v0", wind="constant", wind_value=wind, budget=budget)
    env.reset(seed=0, options={"state": list(x0), "budget": budget})
    states, info = [np.array(x0)], {}
    for _ in range(200):
        _, _, terminated, truncated, info = env.step(np.array([action], dtype=np.float32))
        states.append(env.unwrapped.state)
        if terminated or truncated:
            break
    return np.array(states), info


def test_rollout_moves_as_the_environment_steps():
    """Landing, a soft excursion that spends budget and comes back, a hard violation, and a run to the horizon:
    the same states after every period, the same landing time, violation and budget."""
    model = get_model("pointmass")
    cases = [((-6.0, 3.0), 0.3, 0.275, 0.0),  # brakes into the target, inside a period
             ((-9.0, 17.0), 0.3, -0.05, -10.0),  # falls past the soft speed limit, then past the hard one
             ((-10.5, 15.0), 0.3, 0.5, 0.0),  # starts below -10 m/s and brakes back inside C2
             ((0.0, 10.0), 0.0, 0.1635, 0.0)]  # hovers until the horizon
    outcomes = []
    for x0, q, action, wind in cases:
        states, info = _env_episode(x0, q, action, wind)
        u = float(np.float32(action)) * model.params.u_max
        ro = rollout(model, np.array([x0]), q, constant(u), constant(wind), dt=0.01, eps=1e-3)
        steps = len(states) - 1
        assert ro.steps[0] == steps
        np.testing.assert_allclose(ro.x[:steps + 1, 0], states, rtol=1e-12, atol=1e-12)
        assert ro.landed[0] == info["landed"] and ro.hard_violation[0] == info["hard_violation"]
        assert ro.budget_used[0] == pytest.approx(info["budget_used"], rel=1e-12, abs=1e-15)
        assert ro.end_time[0] == pytest.approx(info["t"], rel=1e-12)
        if info["landed"]:
            assert ro.landing_time[0] == pytest.approx(info["t"], rel=1e-12)
        else:
            assert math.isnan(ro.landing_time[0])
        outcomes.append((info["landed"], info["hard_violation"], info["budget_used"] > 0.0, info["t"]))
    # the four episodes really are of the four kinds named above
    assert outcomes[0][0] and not outcomes[0][2]
    assert abs(outcomes[0][3] / 0.01 - round(outcomes[0][3] / 0.01)) > 0.05  # landed between period ends
    assert outcomes[1][1] and outcomes[1][2]
    assert not outcomes[2][0] and not outcomes[2][1] and outcomes[2][2]
    assert not any(outcomes[3][:3]) and outcomes[3][3] == pytest.approx(1.0)


def test_rollout_many_states_match_their_episodes():
    """A batch of starts, each against its own episode: the batch's per-state events do not leak across rows."""
    model = get_model("pointmass")
    rng = np.random.default_rng(13)
    x0 = np.column_stack([rng.uniform(-9.0, 2.0, 12), rng.uniform(1.0, 17.0, 12)])
    action, wind = 0.2, -6.0
    u = float(np.float32(action)) * model.params.u_max
    ro = rollout(model, x0, 0.2, constant(u), constant(wind), dt=0.01, eps=1e-3)
    kinds = set()
    for i, x in enumerate(x0):
        states, info = _env_episode(x, 0.2, action, wind)
        assert ro.steps[i] == len(states) - 1
        np.testing.assert_allclose(ro.x[len(states) - 1, i], states[-1], rtol=1e-12, atol=1e-12)
        assert ro.landed[i] == info["landed"] and ro.hard_violation[i] == info["hard_violation"]
        assert ro.budget_used[i] == pytest.approx(info["budget_used"], rel=1e-12, abs=1e-15)
        kinds.add((info["landed"], info["hard_violation"]))
    assert len(kinds) >= 2
