"""The environments' fast paths give the same numbers as the vectorised code they stand in for.

* the point mass's scalar methods (``f_scalar``, ``*_scalar`` sets) against its ``f`` and sets, exactly;
* ``sets.box`` and the numpy shortcuts of ``backend.maximum/minimum/clip`` against the plain formulas;
* the scalar integrator (:func:`integrate_period` on the model's scalar methods) and the cached Hermite basis of
  the budget refinement against the vectorised integrator, and whole episodes with and without the fast path, bit
  for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import softreach.envs._common
from softreach.envs import GliderLandingEnv, PointMassLandingEnv
from softreach.reach.sim import budget_quadrature as Q
from softreach.reach.sim.integrator import ScalarModel, integrate_period, scalar_model
from softreach.reach import backend as B
from softreach.reach import sets
from softreach.reach.models import get_model
from softreach.reach.models.pointmass import PointMass

import torch


def _same(u, v) -> bool:
    """Equal values of the same type (arrays: same dtype and shape; NaN equals NaN)."""
    if isinstance(u, np.ndarray) or isinstance(v, np.ndarray):
        return (type(u) is type(v) and u.dtype == v.dtype and u.shape == v.shape
                and np.array_equal(u, v, equal_nan=True))
    if isinstance(u, dict):
        return u.keys() == v.keys() and all(_same(u[k], v[k]) for k in u)
    if isinstance(u, (list, tuple)):
        return len(u) == len(v) and all(_same(a, b) for a, b in zip(u, v))
    return type(u) is type(v) and (u == v or (u != u and v != v))


def _pointmass_points(rng, n):
    """Random states, dense near the set boundaries (|v| = 10, 15, v in [-1, 0], y in {0, 0.7, 18})."""
    v = rng.uniform(-20, 20, n)
    y = rng.uniform(-5, 20, n)
    near = rng.integers(0, 8, n)
    edges_v = np.array([-15.0, -10.0, -1.0, 0.0, 10.0, 15.0])
    edges_y = np.array([0.0, 0.7, 18.0])
    v = np.where(near == 1, rng.choice(edges_v, n) + rng.normal(0, 1e-3, n), v)
    y = np.where(near == 2, rng.choice(edges_y, n) + rng.normal(0, 1e-3, n), y)
    v = np.where(near == 3, rng.choice(edges_v, n), v)  # exactly on an edge
    return v, y


# --------------------------------------------------------------------------------------------- model scalars


@pytest.mark.parametrize("params", [{}, {"gravity": 1.62, "u_max": 20.0, "soft_speed": (-7.0, 4.0),
                                         "target_altitude": (0.1, 0.5), "altitude": (-1.0, 12.0)}])
def test_pointmass_scalar_methods_equal_vectorised(params):
    model = PointMass(**params)
    rng = np.random.default_rng(0)
    v, y = _pointmass_points(rng, 4000)
    u = rng.uniform(-60, 60, v.size)
    d = rng.uniform(-10, 10, v.size)
    t = 0.3
    f_vec = model.f(t, [v, y], [u], [d])
    for eps in (1e-3, 0.5):
        rate_vec = model.violation_rate(t, [v, y], eps)
        for i in range(v.size):
            x = [float(v[i]), float(y[i])]
            assert model.violation_rate_scalar(t, x, eps) == rate_vec[i]
    # the soft constraint enters the env only through violation_rate_scalar, checked above
    sets_vec = {name: getattr(model, name)(t, [v, y]) for name in ("target", "hard_constraint")}
    for i in range(v.size):
        x = [float(v[i]), float(y[i])]
        a, b = [float(u[i])], [float(d[i])]
        fs = model.f_scalar(t, x, a, b)
        assert type(fs) is tuple and all(type(c) is float for c in fs)
        assert fs[0] == f_vec[0][i] and fs[1] == f_vec[1][i]
        # also against f at this one point of Python floats (what the vectorised env path evaluates)
        assert list(fs) == [float(c) for c in model.f(t, x, a, b)]
        for name, vec in sets_vec.items():
            s = getattr(model, name + "_scalar")(t, x)
            assert type(s) is float and s == vec[i], (name, x)


def test_scalar_model_lookup_falls_back_when_a_vectorised_method_is_overridden():
    pm = get_model("pointmass")
    fast = scalar_model(pm)
    assert isinstance(fast, ScalarModel) and fast.f == pm.f_scalar
    assert scalar_model(get_model("glider")) is None  # no scalar methods: the env uses f and the sets

    class Windy(PointMass):  # changes f but not f_scalar: the fast path would ignore the change
        def f(self, t, x, a, b):
            out = super().f(t, x, a, b)
            return [out[0] - 0.1 * x[0], out[1]]

    class Wider(PointMass):
        def soft_constraint(self, t, x):
            return super().soft_constraint(t, x) - 1.0

    class Consistent(PointMass):  # overrides both: its own scalar method is used
        def target(self, t, x):
            return super().target(t, x) - 0.5

        def target_scalar(self, t, x):
            return super().target_scalar(t, x) - 0.5

    assert scalar_model(Windy()) is None
    assert scalar_model(Wider()) is None
    assert scalar_model(Consistent()) is not None
    patched = PointMass()
    patched.hard_constraint = lambda t, x: 0.0
    assert scalar_model(patched) is None

    env = PointMassLandingEnv()
    env.model = Windy()
    env.reset(options={"state": [5.0, 10.0]})
    assert env._fast is None
    env.step(np.float32([0.0]))
    plain = PointMassLandingEnv()
    plain.reset(options={"state": [5.0, 10.0]})
    plain.step(np.float32([0.0]))
    assert env.state[0] < plain.state[0]  # the drag of the overridden f acts


# --------------------------------------------------------------------------------------------- sets, backend


def _box_reference(x, lo, hi, scale=None):
    """``sets.box`` as first written: every term divided by its scale, maxima taken term by term."""
    if scale is None:
        scale = [1.0] * len(x)
    out = None
    for xi, l, h, s in zip(x, lo, hi, scale):
        terms = []
        if l != -math.inf:
            terms.append((l - xi) / s)
        if h != math.inf:
            terms.append((xi - h) / s)
        for term in terms:
            out = term if out is None else B.maximum(out, term)
    return out


@pytest.mark.parametrize("kind", ["numpy", "float", "int", "torch", "broadcast"])
def test_box_equals_reference(kind):
    rng = np.random.default_rng(1)
    inf = math.inf
    cases = [((-1.0, 0.0), (0.0, 0.7), None), ((-15.0, 0.0), (15.0, 18.0), None),
             ((0.0, 60.0, -0.05), (inf, 83.0, 0.0), (1.0, 5.0, 0.0174)), ((-inf, 2.0), (1.0, inf), (3.0, 0.5)),
             ((-0.5,), (0.5,), (2.0,)), ((-2, 0), (2, 4), None)]
    for lo, hi, scale in cases:
        n = len(lo)
        for _ in range(20):
            if kind == "numpy":
                x = [rng.uniform(-20, 90, 50) for _ in range(n)]
            elif kind == "float":
                x = [float(rng.uniform(-20, 90)) for _ in range(n)]
            elif kind == "int":
                x = [rng.integers(-5, 90, 7) for _ in range(n)]
            elif kind == "torch":
                x = [torch.as_tensor(rng.uniform(-20, 90, 9), dtype=torch.float32) for _ in range(n)]
            else:
                x = [rng.uniform(-20, 90, (5,) + (1,) * i + (3,)) for i in range(n)]
            x[0] = x[0] * 0 + lo[0] if kind != "torch" and rng.random() < 0.2 and lo[0] != -inf else x[0]
            ref = _box_reference(x, lo, hi, scale)
            got = sets.box(x, lo, hi, scale)
            if kind == "torch":
                assert got.dtype == ref.dtype and torch.equal(got, ref)
            else:
                assert _same(got, ref), (lo, hi, scale, x)
    with pytest.raises(ValueError, match="at least one finite bound"):
        sets.box([np.zeros(3)], (-inf,), (inf,))


def test_backend_numpy_shortcuts_equal_numpy():
    rng = np.random.default_rng(2)
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, -1.0, 1e-300])
    for _ in range(50):
        a = np.concatenate([rng.normal(size=40), rng.choice(special, 8)])
        b = np.concatenate([rng.normal(size=40), rng.choice(special, 8)])
        s = float(rng.choice([0.0, -0.0, 0.5, np.nan]))
        for fn, ref in ((B.maximum, np.maximum), (B.minimum, np.minimum)):
            assert _same(fn(a, b), ref(a, b))
            assert _same(fn(a, s), ref(a, s))
            assert _same(fn(a[:1].reshape(()), 0.25), ref(a[:1].reshape(()), 0.25))
        for lo, hi in ((0.0, 1.0), (-0.5, 0.5), (0, 1)):
            assert _same(B.clip(a, lo, hi), np.clip(a, lo, hi))
            assert _same(B.clip(a.astype(np.float32), lo, hi), np.clip(a.astype(np.float32), lo, hi))
            assert _same(B.clip(a.reshape(6, 8), lo, hi), np.clip(a.reshape(6, 8), lo, hi))
    # inputs outside the shortcut keep their old results
    assert _same(B.clip(np.arange(5), 1, 3), np.clip(np.arange(5), 1, 3))
    assert _same(B.clip(2.5, 0.0, 1.0), np.clip(2.5, 0.0, 1.0))
    assert _same(B.maximum(1.0, np.arange(3.0)), np.maximum(1.0, np.arange(3.0)))
    t = torch.linspace(-2, 2, 9)
    assert torch.equal(B.clip(t, 0.0, 1.0), torch.clamp(t, 0.0, 1.0))
    assert torch.equal(B.maximum(t, 0.5), torch.clamp(t, min=0.5))


# --------------------------------------------------------------------------------------------- integrator


def test_scalar_integrator_equals_vectorised_pointmass():
    """Random periods, many of them crossing v = +-10 (the budget refinement runs): the same state, cost and
    end rate, bit for bit, with and without the cached start rate."""
    model = get_model("pointmass")
    fast = scalar_model(model)
    rng = np.random.default_rng(3)
    refined = 0
    for i in range(1500):
        x = [float(rng.uniform(-16, 16)), float(rng.uniform(-1, 19))]
        if i % 2:
            x[0] = float(rng.choice([-10.0, 10.0]) + rng.normal(0, 0.3))
        a, b = [float(rng.uniform(-60, 60))], [float(rng.uniform(-10, 10))]
        n = int(rng.integers(1, 4))
        h = float(rng.choice([0.01, 0.003, 0.02]))
        eps = float(rng.choice([1e-3, 0.05]))
        res = float(rng.choice([1e-6, 1e-3, 1.0]))
        slow = integrate_period(model, 0.1, x, a, b, h, n, eps, res, fast=None)
        assert _same(list(integrate_period(model, 0.1, x, a, b, h, n, eps, res)), list(slow))
        rate0 = model.violation_rate_scalar(0.1, x, eps)
        assert _same(list(integrate_period(model, 0.1, x, a, b, h, n, eps, res, fast=fast, rate0=rate0)), list(slow))
        refined += 0.0 < slow[1] < h and res < h
    assert refined > 100


def test_scalar_integrator_general_dimension_equals_vectorised():
    """The n != 2 branch, driven by a stand-in scalar model made of the glider's vectorised methods."""
    model = get_model("glider")
    stand_in = ScalarModel(
        f=lambda t, x, a, b: [float(c) for c in model.f(t, x, a, b)],
        violation_rate=lambda t, x, eps: float(model.violation_rate(t, x, eps)),
        hard_constraint=lambda t, x: float(model.hard_constraint(t, x)),
        target=lambda t, x: float(model.target(t, x)))
    rng = np.random.default_rng(4)
    for _ in range(60):
        x = [float(rng.uniform(0, 40)), float(rng.uniform(64, 70)), float(rng.uniform(-0.05, 0.0))]
        a, b = [float(rng.uniform(-0.1, 0.2))], [float(rng.uniform(-20000, 20000))]
        slow = integrate_period(model, 0.0, x, a, b, 0.1, 2, 1e-3, 1e-6, fast=None)
        new = integrate_period(model, 0.0, x, a, b, 0.1, 2, 1e-3, 1e-6, fast=stand_in)
        assert _same(list(new), list(slow))


def test_hermite_cached_basis_and_first_level_grid():
    grid, basis = Q.kink_grid(128)
    assert np.array_equal(grid, (np.zeros(1)[:, None] + 1.0 * grid[None, :]).reshape(-1))
    assert not grid.flags.writeable
    rng = np.random.default_rng(5)
    x0, f0, x1, f1 = ([float(v) for v in rng.normal(size=3)] for _ in range(4))
    for theta in (grid, rng.uniform(0, 1, 300)):
        # the Hermite dense output as first written
        t2 = theta * theta
        t3 = t2 * theta
        h = 0.01
        h00, h10, h01, h11 = 2.0 * t3 - 3.0 * t2 + 1.0, (t3 - 2.0 * t2 + theta) * h, 3.0 * t2 - 2.0 * t3, (t3 - t2) * h
        ref = [h00 * p + h10 * fp + h01 * q + h11 * fq for p, fp, q, fq in zip(x0, f0, x1, f1)]
        assert _same(Q.hermite(theta, x0, f0, x1, f1, h), ref)
        assert _same(Q.hermite(theta, x0, f0, x1, f1, h, Q.hermite_basis(theta)), ref)


# --------------------------------------------------------------------------------------------- whole episodes


def _rollout(env, seeds, rng):
    out = []
    for seed in seeds:
        out.append(env.reset(seed=seed))
        for k in range(150):
            act = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            if seed % 3 == 0:  # dive out of C2 and brake back in: budget crossings
                act[:] = -1.0 if k < 25 else 1.0
            step = env.step(act)
            out.append(step)
            if step[2] or step[3]:
                break
    return out


@pytest.mark.parametrize("kwargs", [{}, {"wind": "random", "budget": 0.05}, {"n_substeps": 3, "dt": 0.013},
                                    {"wind": "constant", "wind_value": -7.0, "eps": 0.2}])
def test_pointmass_env_identical_with_and_without_fast_path(monkeypatch, kwargs):
    fast_env = PointMassLandingEnv(**kwargs)
    fast_run = _rollout(fast_env, range(12), np.random.default_rng(6))
    assert fast_env._fast is not None
    monkeypatch.setattr(softreach.envs._common, "scalar_model", lambda model: None)  # where the env looks it up
    slow_env = PointMassLandingEnv(**kwargs)
    slow_run = _rollout(slow_env, range(12), np.random.default_rng(6))
    assert slow_env._fast is None
    assert len(fast_run) == len(slow_run) > 12
    for a, b in zip(fast_run, slow_run):
        assert _same(list(a), list(b))


def test_cached_start_rate_is_not_reused_after_the_state_changes():
    """The rate at the current state is reused as the first RK4 stage only for that very (t, x)."""
    env = PointMassLandingEnv(budget=0.5)
    env.reset(options={"state": [-10.5, 15.0]})  # outside C2: rate 1
    env.step(np.float32([1.0]))
    env.reset(options={"state": [0.0, 15.0]})  # inside: rate 0, the cached 1 must not leak into the first step
    _, _, _, _, info = env.step(np.float32([0.0]))
    assert info["cost"] == 0.0
    glider = GliderLandingEnv()
    glider.reset(seed=0)
    assert glider._fast is None
