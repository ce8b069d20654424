"""Closed-loop simulation of the budget-augmented system, batched over initial states.

Used to check soundness (a state inside ``RA~_Q`` must land, never leave ``C1`` and spend at most ``Q``) and to draw
the paper's worst-case trajectories and budget-depletion curves (Fig. 1, 5, 9). A rollout moves as an episode of
the environments does: the same integrator (:func:`softreach.reach.sim.integrator.integrate_batch`: RK4 sub-steps,
the kink-aware budget integral) and the same events (landing and ``C1`` checked at every sub-step end, the period
ending at the first of them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .integrator import episode_ends, integrate_batch
from ..problem import Model

Policy = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Rollout:
    """Trajectories of ``N`` simulations: ``t (T+1,)``, ``x (T+1, N, n)``, ``z (T+1, N)``, ``a (T, N, m)``,
    ``b (T, N, k)`` (row ``k + 1`` of ``x`` and ``z``: where period ``k`` ended, at its event if one ended it
    early; ``nan`` after a simulation ended); per simulation: ``landed``, ``hard_violation``, ``budget_used``,
    ``landing_time`` (``nan`` if not landed), ``steps`` (periods simulated) and ``end_time`` (when it landed,
    left ``C1`` or reached the horizon)."""

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    a: np.ndarray
    b: np.ndarray
    landed: np.ndarray
    hard_violation: np.ndarray
    budget_used: np.ndarray
    landing_time: np.ndarray
    steps: np.ndarray
    end_time: np.ndarray


def _budget(table, z: np.ndarray) -> np.ndarray | None:
    """The budget a table's feedback reads: ``None`` for a classical-only table, negative budgets at 0."""
    return np.maximum(z, 0.0) if (table.has_budget or getattr(table, "has_budget_surface", False)) else None


def table_control(table) -> Policy:
    """The table's optimal control ``a*(t, x, z)`` as a policy (negative budgets are queried at 0)."""
    return lambda t, x, z: table.optimal_control(t, x, _budget(table, z), outside="nearest")


def table_disturbance(table) -> Policy:
    """The table's worst-case disturbance ``b*(t, x, z)`` as a policy."""
    return lambda t, x, z: table.worst_disturbance(t, x, _budget(table, z), outside="nearest")


def constant(value: Any) -> Policy:
    """A constant input."""
    v = np.atleast_1d(np.asarray(value, dtype=np.float64))
    return lambda t, x, z: np.broadcast_to(v, (len(x), len(v))).copy()


def random_switching(model: Model, seed: int = 0, hold: float = 0.05, kind: str = "disturbance") -> Policy:
    """Bang-bang input that jumps to a random end of its box every ``hold`` seconds."""
    rng = np.random.default_rng(seed)
    lo, hi = (model.disturbance_bounds if kind == "disturbance" else model.control_bounds)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    state: dict[str, Any] = {"until": -np.inf, "value": None}

    def policy(t: float, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        if state["value"] is None or len(state["value"]) != len(x) or t >= state["until"]:
            pick = rng.integers(0, 2, size=(len(x), len(lo)))
            state["value"] = np.where(pick == 1, hi, lo)
            state["until"] = t + hold
        return state["value"]

    return policy


def rollout(model: Model, x0: np.ndarray, budget: np.ndarray | float, control: Policy, disturbance: Policy, *,
            t0: float = 0.0, horizon: float | None = None, dt: float = 1e-3, eps: float = 1e-3,
            substeps: int | None = None, budget_resolution: float = 1e-6) -> Rollout:
    """Simulate ``N`` closed loops with zero-order-hold inputs, as the environments step.

    Every control period is integrated by :func:`~softreach.reach.sim.integrator.integrate_batch` (``substeps`` RK4
    steps, the budget integral exact at the kinks of ``h_eps``). A simulation ends at the first sub-step end where
    it has left ``C1`` (a hard violation) or landed (target reached inside ``C2``), as an episode does
    (:func:`~softreach.reach.sim.integrator.episode_ends`), or at the horizon; a start already landed or outside
    ``C1`` ends at ``t0``. The last period is shortened to end at the horizon, and periodic state axes are wrapped
    after each period, as in the environments.

    :param model: the model to simulate
    :param x0: initial states, ``(N, n)``
    :param budget: initial budget(s) ``Q``
    :param control: ``(t, x (N, n), z (N,)) -> (N, m)``, clipped to the control box
    :param disturbance: ``(t, x, z) -> (N, k)``, clipped to the disturbance box
    :param t0: start time [s]
    :param horizon: final time (default: the model's)
    :param dt: control period [s]
    :param eps: ``h_eps`` width for the budget dynamics
    :param substeps: RK4 sub-steps per period, where the events are checked (default: the model's ``substeps``)
    :param budget_resolution: resolve the kinks of ``h_eps`` to this length [s] (the point-mass env's default)
    """
    x = np.array(x0, dtype=np.float64, ndmin=2)
    n_sim = len(x)
    z = np.broadcast_to(np.asarray(budget, dtype=np.float64), (n_sim,)).copy()
    T = model.horizon if horizon is None else horizon
    n_sub = model.substeps if substeps is None else substeps
    steps = max(int(math.ceil((T - t0) / dt - 1e-9)), 0)
    ts = np.minimum(t0 + dt * np.arange(steps + 1), T)
    if steps:
        ts[-1] = T
    xs = np.full((steps + 1, n_sim, model.state_dim), np.nan)
    zs = np.full((steps + 1, n_sim), np.nan)
    as_ = np.full((steps, n_sim, model.control_dim), np.nan)
    bs = np.full((steps, n_sim, model.disturbance_dim), np.nan)
    xs[0], zs[0] = x, z
    z0 = z.copy()
    wraps = any(model.periodic_axes())

    def comps(arr: np.ndarray) -> list[np.ndarray]:
        return [arr[:, i] for i in range(arr.shape[1])]

    hard = np.asarray(model.hard_constraint(t0, comps(x))) > 0
    landed = np.asarray(model.landed(t0, comps(x)), dtype=bool) & ~hard
    t_end = np.full(n_sim, float(T))
    t_end[hard | landed] = t0
    t_land = np.where(landed, float(t0), np.nan)
    active = ~hard & ~landed
    n_steps = np.zeros(n_sim, int)

    def stop(t: float, xc: list[np.ndarray], rate: np.ndarray) -> np.ndarray:
        return episode_ends(model, t, xc, rate)

    for k in range(steps):
        idx = np.nonzero(active)[0]
        if len(idx) == 0:
            break
        t = float(ts[k])
        xa, za = x[idx], z[idx]
        a = model.clip_control(np.asarray(control(t, xa, za), dtype=np.float64).reshape(len(idx), -1))
        b = model.clip_disturbance(np.asarray(disturbance(t, xa, za), dtype=np.float64).reshape(len(idx), -1))
        as_[k, idx], bs[k, idx] = a, b
        period = integrate_batch(model, t, xa, a, b, min(dt, T - t), n_sub, eps, budget_resolution, stop=stop)
        xa, za = period.x, za - period.cost
        if wraps:
            xa = np.array([model.wrap_state(row) for row in xa], dtype=np.float64).reshape(xa.shape)
        te = t + period.elapsed
        hit = np.asarray(model.hard_constraint(te, comps(xa))) > 0
        arrived = ~hit & (period.rate == 0.0) & (np.asarray(model.target(te, comps(xa))) <= 0)
        hard[idx[hit]] = True
        landed[idx[arrived]] = True
        t_land[idx[arrived]] = te[arrived]
        t_end[idx[hit | arrived]] = te[hit | arrived]
        x[idx], z[idx] = xa, za
        n_steps[idx] += 1
        xs[k + 1, idx], zs[k + 1, idx] = xa, za
        active[idx] = ~hit & ~arrived
    return Rollout(t=ts, x=xs, z=zs, a=as_, b=bs, landed=landed, hard_violation=hard, budget_used=z0 - z,
                   landing_time=t_land, steps=n_steps, end_time=t_end)
