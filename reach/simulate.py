"""Fine-step closed-loop simulation of the budget-augmented system, batched over initial states.

Used to check soundness (a state inside ``RA~_Q`` must land, never leave ``C1`` and spend at most ``Q``) and to draw
the paper's worst-case trajectories and budget-depletion curves (Fig. 1, 5, 9).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .problem import Model

Policy = Callable[[float, np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Rollout:
    """Trajectories of ``N`` simulations: ``t (T+1,)``, ``x (T+1, N, n)``, ``z (T+1, N)``, ``a (T, N, m)``, ``b (T, N, k)``;
    per simulation: ``landed``, ``hard_violation``, ``budget_used`` and ``landing_time`` (``nan`` if not landed)."""

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


def table_control(table) -> Policy:
    """The table's optimal control ``a*(t, x, z)`` as a policy (negative budgets are queried at 0)."""
    return lambda t, x, z: table.optimal_control(t, x, np.maximum(z, 0.0) if table.has_budget else None,
                                                 outside="nearest")


def table_disturbance(table) -> Policy:
    """The table's worst-case disturbance ``b*(t, x, z)`` as a policy."""
    return lambda t, x, z: table.worst_disturbance(t, x, np.maximum(z, 0.0) if table.has_budget else None,
                                                   outside="nearest")


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
            t0: float = 0.0, horizon: float | None = None, dt: float = 1e-3, eps: float = 1e-3, substeps: int = 4) -> Rollout:
    """Simulate ``N`` closed loops with zero-order-hold inputs and RK4 substeps.

    A simulation stops when it lands (target reached inside ``C2``); the hard constraint is checked at every substep.

    :param x0: initial states, ``(N, n)``
    :param budget: initial budget(s) ``Q``
    :param control: ``(t, x (N, n), z (N,)) -> (N, m)``
    :param disturbance: ``(t, x, z) -> (N, k)``
    :param horizon: final time (default: the model's)
    :param dt: control period
    :param eps: ``h_eps`` width for the budget dynamics
    """
    x = np.array(x0, dtype=np.float64, ndmin=2)
    n_sim = len(x)
    z = np.broadcast_to(np.asarray(budget, dtype=np.float64), (n_sim,)).copy()
    T = model.horizon if horizon is None else horizon
    steps = int(round((T - t0) / dt))
    ts = t0 + dt * np.arange(steps + 1)
    xs = np.full((steps + 1, n_sim, model.state_dim), np.nan)
    zs = np.full((steps + 1, n_sim), np.nan)
    as_ = np.full((steps, n_sim, model.control_dim), np.nan)
    bs = np.full((steps, n_sim, model.disturbance_dim), np.nan)
    xs[0], zs[0] = x, z
    z0 = z.copy()
    active = np.ones(n_sim, bool)
    landed = np.zeros(n_sim, bool)
    hard = np.zeros(n_sim, bool)
    t_land = np.full(n_sim, np.nan)
    n_steps = np.zeros(n_sim, int)

    def comps(arr):
        return [arr[:, i] for i in range(arr.shape[1])]

    def check(t, xa, idx):
        xc = comps(xa)
        hard[idx] |= np.asarray(model.hard_constraint(t, xc)) > 0
        return (np.asarray(model.target(t, xc)) <= 0) & (np.asarray(model.soft_constraint(t, xc)) <= 0)

    done = check(t0, x, np.arange(n_sim))
    landed |= done & ~hard
    t_land[done & ~hard] = t0
    active &= ~done & ~hard
    for k in range(steps):
        idx = np.nonzero(active)[0]
        if len(idx) == 0:
            break
        t = ts[k]
        xa, za = x[idx], z[idx]
        a = model.clip_control(np.asarray(control(t, xa, za), dtype=np.float64).reshape(len(idx), -1))
        b = model.clip_disturbance(np.asarray(disturbance(t, xa, za), dtype=np.float64).reshape(len(idx), -1))
        as_[k, idx], bs[k, idx] = a, b
        h = dt / substeps
        for s in range(substeps):
            ts_ = t + s * h

            def rhs(tt, xx):
                f = model.f(tt, comps(xx), comps(a), comps(b))
                return np.stack([np.broadcast_to(np.asarray(fi, float), (len(xx),)) for fi in f], axis=1)

            def zr(tt, xx):
                return -np.asarray(model.violation_rate(tt, comps(xx), eps), float)

            k1, l1 = rhs(ts_, xa), zr(ts_, xa)
            k2, l2 = rhs(ts_ + h / 2, xa + h / 2 * k1), zr(ts_ + h / 2, xa + h / 2 * k1)
            k3, l3 = rhs(ts_ + h / 2, xa + h / 2 * k2), zr(ts_ + h / 2, xa + h / 2 * k2)
            k4, l4 = rhs(ts_ + h, xa + h * k3), zr(ts_ + h, xa + h * k3)
            xa = xa + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            za = za + h / 6 * (l1 + 2 * l2 + 2 * l3 + l4)
            arrived = check(ts_ + h, xa, idx)
            new = arrived & ~landed[idx] & ~hard[idx]
            landed[idx[new]] = True
            t_land[idx[new]] = ts_ + h
        x[idx], z[idx] = xa, za
        n_steps[idx] += 1
        xs[k + 1, idx], zs[k + 1, idx] = xa, za
        active[idx] = ~landed[idx] & ~hard[idx]
    return Rollout(t=ts, x=xs, z=zs, a=as_, b=bs, landed=landed & ~hard, hard_violation=hard,
                   budget_used=z0 - z, landing_time=t_land, steps=n_steps)
