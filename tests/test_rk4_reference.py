"""The integrator's RK4 against a slow reference written from the method's definition: the same numbers, bit for
bit, for the step itself (floats and numpy component arrays), for the batched period and for the environments'
steps (the point mass on its scalar fast path, the glider on the vectorised one)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.reach.sim.integrator import integrate_batch
from softreach.reach.models import get_model
from softreach.reach.sim.rk4 import rk4_stages


def reference_rk4(f, t, x, a, b, h):
    """The classical Runge-Kutta step, as the textbook writes it: ``k1 = f(t, x)``,
    ``k2 = f(t + h/2, x + h/2 k1)``, ``k3 = f(t + h/2, x + h/2 k2)``, ``k4 = f(t + h, x + h k3)``,
    ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)``; one component at a time."""
    n = len(x)
    k1 = list(f(t, x, a, b))
    s2 = [x[i] + h / 2 * k1[i] for i in range(n)]
    k2 = list(f(t + h / 2, s2, a, b))
    s3 = [x[i] + h / 2 * k2[i] for i in range(n)]
    k3 = list(f(t + h / 2, s3, a, b))
    s4 = [x[i] + h * k3[i] for i in range(n)]
    k4 = list(f(t + h, s4, a, b))
    end = [x[i] + h / 6 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]) for i in range(n)]
    return end, [list(x), s2, s3, s4]


def reference_path(f, t, x, a, b, h, n_substeps):
    """The states at the ends of ``n_substeps`` reference steps over a period ``h`` (the ``j``-th from
    ``t + j h / n_substeps``), the start first."""
    hs = h / n_substeps
    path = [list(x)]
    for j in range(n_substeps):
        path.append(reference_rk4(f, t + j * hs, path[-1], a, b, hs)[0])
    return path


def _field(t, x, a, b):
    """A nonlinear, time-dependent field of three components (every stage time and state matters)."""
    return [math.sin(x[1]) * t + a[0], x[0] * x[2] - b[0] * math.cos(t), -x[1] ** 2 + a[0] * b[0]]


def _field_arrays(t, x, a, b):
    return [np.sin(x[1]) * t + a[0], x[0] * x[2] - b[0] * np.cos(t), -x[1] ** 2 + a[0] * b[0]]


def _same(u, v) -> bool:
    return np.array_equal(np.asarray(u, dtype=np.float64), np.asarray(v, dtype=np.float64))


def test_the_step_is_the_definition_on_floats_and_arrays():
    rng = np.random.default_rng(0)
    for _ in range(200):
        t, h = float(rng.uniform(0, 3)), float(rng.choice([1e-3, 0.01, 0.37, 1.0 / 3.0]))
        x, a, b = [float(v) for v in rng.normal(size=3)], [float(rng.normal())], [float(rng.normal())]
        end, stages = rk4_stages(_field, t, x, a, b, h)
        ref_end, ref_stages = reference_rk4(_field, t, x, a, b, h)
        assert end == ref_end and stages == ref_stages  # Python floats: == is bit for bit (no NaN here)
    # N states at once, one array per component: each row is that state's own step
    X, A, B = rng.normal(size=(3, 50)), rng.normal(size=(1, 50)), rng.normal(size=(1, 50))
    end, stages = rk4_stages(_field_arrays, 0.4, list(X), list(A), list(B), 0.05)
    for r in range(50):
        ref_end, ref_stages = reference_rk4(_field, 0.4, [float(v) for v in X[:, r]], [float(A[0, r])],
                                            [float(B[0, r])], 0.05)
        assert _same([c[r] for c in end], ref_end)
        assert all(_same([c[r] for c in s], rs) for s, rs in zip(stages, ref_stages))


@pytest.mark.parametrize("name", ["pointmass", "glider"])
def test_the_batched_period_is_the_reference_path(name):
    model = get_model(name)
    rng = np.random.default_rng(1)
    lo, hi = (np.asarray(v, dtype=np.float64) for v in model.start_box)
    x = rng.uniform(lo, hi, (40, model.state_dim))
    a = rng.uniform(*model.control_bounds, (40, model.control_dim))
    b = rng.uniform(*model.disturbance_bounds, (40, model.disturbance_dim))
    h, n = 0.1, 4
    out = integrate_batch(model, 0.2, x, a, b, h, n, 0.05, 1e-4)
    for r in range(len(x)):
        ref = reference_path(model.f, 0.2, [float(v) for v in x[r]], [float(v) for v in a[r]],
                             [float(v) for v in b[r]], h, n)
        assert _same(out.x[r], ref[-1]), r


@pytest.mark.parametrize("env_id", ["softreach/PointMassLanding-v0", "softreach/GliderLanding-v0"])
def test_every_env_step_is_the_reference_path(env_id):
    """Random actions and the env's own winds, episodes to their ends: each step's end state is the reference
    path's state after the sub-steps the step took (all of them, or up to the event that ended the episode)."""
    env = gym.make(env_id).unwrapped
    env.action_space.seed(2)
    model, n = env.model, env.n_substeps
    env.reset(seed=2)
    steps = ends = early = 0
    while steps < 300:
        x0, t0 = [float(v) for v in env.state], float(env._t)
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        a, b = [float(v) for v in info["action_physical"]], [float(v) for v in info["wind"]]
        h = min(env.dt, env.horizon - t0)
        path = reference_path(model.f, t0, x0, a, b, h, n)
        taken = n if not terminated else round((info["t"] - t0) / (h / n))
        assert _same(env.state, path[taken]), (steps, taken)
        early += taken < n
        steps += 1
        if terminated or truncated:
            ends += 1
            env.reset()
    assert ends >= 1 and early >= 1  # an episode's end inside a period was met
