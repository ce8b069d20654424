"""The integrator of softreach: one control period with the action and the wind held, and the budget with it.

Used by the environments (one state per step, :func:`integrate_period`) and by the rollouts and plots
(:func:`integrate_batch`, ``N`` states at once, through :func:`softreach.reach.sim.simulate.rollout`), so that a
rollout moves exactly as an episode does.

Integration: the control and the wind are held constant over a control period (zero-order hold) and the state
is advanced by ``n_substeps`` classical Runge-Kutta (RK4) steps (:mod:`softreach.reach.sim.rk4`). The budget ``z`` follows
``z' = -h_eps(t, x)``: its increment over a sub-step comes from ``h_eps`` at the same four RK4 stage states,
exact at the kinks of ``h_eps`` (:mod:`softreach.reach.sim.budget_quadrature`). The state path does not depend on
the budget; excursions out of ``C2`` shorter than a sub-step that no RK4 stage sees are missed.

Events: ``stop`` is asked at every sub-step end but the last; the period ends at the first one where it says
yes. The environments stop where the state is out of ``C1`` or landed, as in the paper's game, which ends when
the target is reached at any instant (:func:`episode_ends` is that rule for ``N`` states, the rollouts' stop);
the safety filter counts on landing only at those instants (:class:`~softreach.reach.proof.lookahead.Lookahead`,
``target_checks``).

One algorithm, three entry points that share every step of it: one RK4 step
(:func:`~softreach.reach.sim.rk4.rk4_step`) on numpy component arrays (``N`` states, :func:`_period`) or Python
floats (one state, :func:`_period` and :func:`_integrate_period_scalar`), the same stage times, stage rates and
budget rule.
:func:`_integrate_period_scalar` is :func:`_period`'s loop on a model's scalar methods
(:mod:`softreach.reach.sim.scalar_model`): it evaluates ``h_eps`` stage by stage on floats and decides the two cases
that need no arithmetic (all stages inside ``C2``: ``0``; all beyond the band: the sub-step's length) inline,
leaving every other sub-step to the same :func:`budget_piece` and :func:`kink_costs`. tests/test_integrator.py
checks the three against each other.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from .budget_quadrature import FLOATS, budget_piece, kink_costs
from ..problem import Model
from .rk4 import rk4_stages, rk4_step
from .scalar_model import ScalarModel, scalar_model

__all__ = ["BatchPeriod", "ScalarModel", "episode_ends", "integrate_batch", "integrate_period", "rk4_stages",
           "rk4_step", "scalar_model", "stage_rates"]

def stage_rates(model: Model, times: Sequence[float], points: Sequence[Sequence[Any]], eps: float) -> np.ndarray:
    """``h_eps`` at many points in one vectorised call of ``model.violation_rate``.

    :param times: the time of each point [s]
    :param points: ``P`` states, one float (one state) or ``(N,)`` array (``N`` states) per component
    :return: ``(P, N)`` (``N = 1`` for floats)
    """
    comps = [np.array([p[i] for p in points], dtype=np.float64) for i in range(len(points[0]))]
    shape = (len(points), comps[0].size // len(points))
    t = np.asarray(times, dtype=np.float64)
    if shape[1] > 1:
        t = np.repeat(t, shape[1])
        comps = [c.reshape(-1) for c in comps]
    r = model.violation_rate(t, comps, eps)
    if not (type(r) is np.ndarray and r.dtype == np.float64 and r.size == shape[0] * shape[1]):
        r = np.broadcast_to(np.asarray(r, dtype=np.float64), (shape[0] * shape[1],))
    return r.reshape(shape)


def episode_ends(model: Model, t: float, x: Sequence[Any], rate: Any) -> Any:
    """The environments' events at a sub-step end: out of ``C1``, or landed (in the target with ``h_eps = 0``,
    i.e. inside ``C2``).

    :param model: a :class:`Model`, or its :class:`ScalarModel` for one state in Python floats
    :param x: the state(s), one float or array per component
    :param rate: ``h_eps`` there
    :return: a bool, or a mask over the states
    """
    hard = model.hard_constraint(t, x) > 0.0
    # one state (the envs' sub-steps, in Python floats first): short-circuit, the target only where it decides
    if hard is False:
        return rate == 0.0 and model.target(t, x) <= 0.0
    if hard is True or type(hard) is np.bool_:
        return hard or (rate == 0.0 and model.target(t, x) <= 0.0)
    return np.asarray(hard) | ((np.asarray(rate) == 0.0) & (np.asarray(model.target(t, x)) <= 0.0))


class BatchPeriod(NamedTuple):
    """One control period of ``N`` states (:func:`integrate_batch`)."""

    #: ``(N, n)`` the states where the period ended
    x: np.ndarray
    #: ``(N,)`` the budget spent until then, ``int h_eps dt``
    cost: np.ndarray
    #: ``(N,)`` ``h_eps`` at the end state (``> 0`` exactly when it is outside ``C2``)
    rate: np.ndarray
    #: ``(N,)`` the time elapsed (the period's length unless ``stop`` ended it early)
    elapsed: np.ndarray


def integrate_batch(model: Model, t: float, x: np.ndarray, a: np.ndarray, b: np.ndarray, h: float,
                    n_substeps: int, eps: float, budget_resolution: float, *, stop: Callable | None = None
                    ) -> BatchPeriod:
    """Advance ``N`` budget-augmented states over one control period with their ``a`` and ``b`` held.

    :param model: the model whose vectorised ``f`` and ``violation_rate`` are integrated
    :param t: start time [s]
    :param x: ``(N, n)`` start states (physical)
    :param a: ``(N, m)`` physical controls
    :param b: ``(N, k)`` physical disturbances
    :param h: period length [s]
    :param n_substeps: RK4 steps per period
    :param eps: the ``eps`` of ``h_eps``
    :param budget_resolution: resolve the kinks of ``h_eps`` (entering or leaving ``C2``) to this length [s]
    :param stop: ``stop(t, x, rate) -> (N,) bool`` (``x``: one ``(N,)`` array per component, ``rate``: ``h_eps``
        there) asked at every sub-step end but the last; each state's period ends at the first where it says yes
        (:func:`episode_ends` is the environments' rule)
    """
    cols = [[c for c in np.asarray(v, dtype=np.float64).reshape(len(x), -1).T] for v in (x, a, b)]
    xe, cost, rate, elapsed = _period(model, t, *cols, h, n_substeps, eps, budget_resolution, stop)
    return BatchPeriod(np.stack(xe, axis=1), cost, rate, elapsed)


def _period(model: Model, t: float, x: list[Any], a: list[Any], b: list[Any], h: float, n_substeps: int,
            eps: float, resolution: float, stop: Callable | None) -> tuple[list[Any], Any, Any, Any]:
    """:func:`integrate_batch` on components that are ``(N,)`` arrays, or Python floats (one state).

    One state keeps its bookkeeping in Python scalars: numpy's cost per call (about a microsecond) would be a
    tenth of an environment step.

    :return: the end state (one float or ``(N,)`` array per component), the costs, the end rates and the times
        elapsed (floats for one state, else ``(N,)`` arrays)
    """
    one = type(x[0]) is not np.ndarray
    rows = 1 if one else len(x[0])
    hs = h / n_substeps
    hh = 0.5 * hs
    h6 = hs / 6.0
    path, points, times = [x], [x], [t]
    # set once a period ends early: the sub-steps done where each one ended (an int for one state, else (N,))
    # and h_eps there
    ended_at: Any = None
    end_rate: Any = None
    xc = x
    for j in range(n_substeps):
        tc = t + j * hs
        tm = tc + hh
        te = tc + hs
        xc, x2, x3, x4 = rk4_step(model.f, tc, tm, te, hh, hs, h6, xc, a, b)
        path.append(xc)
        points += (x2, x3, x4, xc)
        times += (tm, tm, te, t + h if j == n_substeps - 1 else te)
        if stop is None or j == n_substeps - 1:
            continue
        r = model.violation_rate(te, xc, eps)
        ended = stop(te, xc, r)
        if one:
            if ended:
                ended_at, end_rate = j + 1, float(r)
                break
        elif np.any(ended):
            if ended_at is None:
                ended_at, end_rate = np.full(rows, n_substeps), np.zeros(rows)
            new = np.asarray(ended, dtype=bool) & (ended_at == n_substeps)
            ended_at[new] = j + 1
            end_rate[new] = np.broadcast_to(np.asarray(r, dtype=np.float64), (rows,))[new]
            if (ended_at <= j + 1).all():
                break
    done = len(path) - 1
    r = stage_rates(model, times, points, eps)  # (1 + 4 done, rows): x, then x2, x3, x4, x_end per sub-step
    if one:
        partial = False
        if ended_at is None:
            end_rate = float(r[4 * done, 0])
    elif ended_at is None:
        partial, end_rate = False, r[4 * done]
    else:
        live = ended_at == n_substeps
        partial = not (ended_at == done).all()  # some states ended before the others
        end_rate[live] = r[4 * done, live]
    cost: Any = 0.0 if one else np.zeros(rows)
    if r[:4 * done].any():
        refine = hs > resolution
        if one:  # sub-step by sub-step on floats, refining a kink where one is met
            v = r[:, 0].tolist()
            costs = []
            for k in range(done):
                piece, kink = budget_piece(v[4 * k], v[4 * k + 1], v[4 * k + 2], v[4 * k + 3], hs, FLOATS)
                if kink and refine:
                    piece = float(_kink_pieces(model, t, hs, path, a, b, [k], [0], eps, resolution)[0])
                costs.append(piece)
            cost = math.fsum(costs)
        else:  # every sub-step of every state at once
            v = r[:4 * done].reshape(done, 4, rows)
            pieces, kink = budget_piece(v[:, 0], v[:, 1], v[:, 2], v[:, 3], hs)
            if partial:
                counted = np.arange(done)[:, None] < ended_at[None, :]
                pieces, kink = np.where(counted, pieces, 0.0), kink & counted
            if refine and kink.any():
                js, ks = np.nonzero(kink)
                pieces[js, ks] = _kink_pieces(model, t, hs, path, a, b, js, ks, eps, resolution)
            cost = _exact_sums(pieces, hs)
    if ended_at is None:
        return xc, cost, end_rate, (h if one else np.full(rows, h))
    if one:
        return xc, cost, end_rate, ended_at * hs
    elapsed = np.where(ended_at == n_substeps, h, ended_at * hs)
    if not partial:
        return xc, cost, end_rate, elapsed
    P = np.array(path, dtype=np.float64).reshape(done + 1, len(x), rows)
    return list(P[ended_at, :, np.arange(rows)].T), cost, end_rate, elapsed


def _kink_pieces(model: Model, t: float, hs: float, path: list[list[Any]], a: list[Any], b: list[Any],
                 js: Sequence[int], ks: Sequence[int], eps: float, resolution: float) -> np.ndarray:
    """:func:`kink_costs` of sub-steps ``js`` of states ``ks`` of a period.

    :param path: the state at every sub-step end, from the start (one float or ``(N,)`` array per component)
    :param a: the controls; ``b``: the disturbances (one float or ``(N,)`` array per component)
    """
    n, rows = len(path[0]), np.size(path[0][0])
    P = np.array(path, dtype=np.float64).reshape(len(path), n, rows)
    A, B = (np.array(u, dtype=np.float64).reshape(len(u), rows)[:, ks] for u in (a, b))
    js, ks = np.asarray(js), np.asarray(ks)
    t0 = t + js * hs
    x0, x1 = P[js, :, ks], P[js + 1, :, ks]
    return kink_costs(model, t0, hs, x0, _field(model, t0, x0, A, B), x1, _field(model, t0 + hs, x1, A, B), eps,
                      resolution)


def _exact_sums(pieces: np.ndarray, hs: float) -> np.ndarray:
    """Per state, the sum of its sub-steps' costs ``pieces`` ``(S, N)``, correctly rounded (``math.fsum``): whole
    sub-steps out of ``C2`` then add up to the period's length exactly. A state whose pieces are all ``0`` or
    ``hs`` sums to ``count * hs``, which one rounding makes the correctly rounded sum too."""
    whole = np.count_nonzero(pieces == hs, axis=0)
    out = whole * hs
    mixed = np.flatnonzero(np.count_nonzero(pieces, axis=0) != whole)
    if len(mixed):
        out[mixed] = [math.fsum(c) for c in pieces[:, mixed].T.tolist()]
    return out


def _field(model: Model, t: np.ndarray, x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``model.f`` as ``(K, n)`` at ``K`` states.

    :param t: ``(K,)`` times [s]
    :param x: ``(K, n)`` states
    :param a: ``(m, K)`` controls
    :param b: ``(k, K)`` disturbances
    """
    out = model.f(t, list(x.T), list(a), list(b))
    return np.stack([np.broadcast_to(np.asarray(c, dtype=np.float64), (len(x),)) for c in out], axis=1)


_AUTO: Any = object()  # integrate_period(fast=...): look the model's scalar fast path up


def integrate_period(model: Model, t: float, x: Sequence[float], a: Sequence[float], b: Sequence[float],
                     h: float, n_substeps: int, eps: float, budget_resolution: float, *, fast: Any = _AUTO,
                     rate0: float | None = None, stop: Callable | None = None
                     ) -> tuple[list[float], float, float, float]:
    """Advance one budget-augmented state over one control period with ``a`` and ``b`` held.

    :param model: the model whose ``f`` and ``violation_rate`` are integrated
    :param t: start time [s]
    :param x: start state (physical), one float per component
    :param a: physical control
    :param b: physical disturbance
    :param h: period length [s]
    :param n_substeps: RK4 steps per period
    :param eps: the ``eps`` of ``h_eps``
    :param budget_resolution: resolve the kinks of ``h_eps`` (entering or leaving ``C2``) to this length [s]
    :param fast: the model's scalar fast path (:func:`scalar_model`), ``None`` for the vectorised methods;
        by default it is looked up. Both give the same numbers.
    :param rate0: ``h_eps(t, x)`` if already known (the fast path then does not evaluate it again)
    :param stop: ``stop(t, x, rate) -> bool`` asked at every sub-step end but the last (``x`` a list of floats,
        ``rate`` ``h_eps`` there); the period ends at the first where it says yes
    :return: ``(x_end, cost, rate_end, elapsed)``: the state where the period ended, the budget spent
        ``int h_eps dt`` until then, ``h_eps`` at that state (``> 0`` exactly when it is outside ``C2``), and the
        time elapsed (``h`` unless ``stop`` ended it early)
    """
    if fast is _AUTO:
        fast = scalar_model(model)
    if fast is not None:
        return _integrate_period_scalar(fast, model, t, x, a, b, h, n_substeps, eps, budget_resolution, rate0,
                                        stop)
    floats = None if stop is None else (lambda te, xe, r: stop(te, [float(v) for v in xe], float(r)))
    xe, cost, rate, elapsed = _period(model, t, [float(v) for v in x], [float(v) for v in a],
                                      [float(v) for v in b], h, n_substeps, eps, budget_resolution, floats)
    return [float(v) for v in xe], cost, rate, elapsed


def _integrate_period_scalar(fast: ScalarModel, model: Model, t: float, x: Sequence[float], a: Sequence[float],
                             b: Sequence[float], h: float, n_substeps: int, eps: float, budget_resolution: float,
                             rate0: float | None, stop: Callable | None = None
                             ) -> tuple[list[float], float, float, float]:
    """:func:`integrate_period` on the model's scalar fast path: :func:`_period`'s loop with ``h_eps`` taken
    stage by stage on Python floats (the same stages, stage times and budget rule). The two sub-steps that need
    no arithmetic are decided here: all stages inside ``C2`` cost ``0``, all beyond the band the sub-step's
    length; every other goes to :func:`budget_piece` and, at a kink, :func:`kink_costs`."""
    f, rate = fast.f, fast.violation_rate
    xc = x if type(x) is list else list(x)
    r0 = rate(t, xc, eps) if rate0 is None else rate0
    hs = h / n_substeps
    hh = 0.5 * hs
    h6 = hs / 6.0
    last = n_substeps - 1
    costs = []  # sub-steps inside C2 cost 0 and are left out of the sum
    for j in range(n_substeps):
        tc = t + j * hs
        tm = tc + hh
        te = tc + hs
        xn, x2, x3, x4 = rk4_step(f, tc, tm, te, hh, hs, h6, xc, a, b)
        r2, r3, r4 = rate(tm, x2, eps), rate(tm, x3, eps), rate(te, x4, eps)
        if r0 == 0.0 and r2 == 0.0 and r3 == 0.0 and r4 == 0.0:
            pass
        elif r0 == 1.0 and r2 == 1.0 and r3 == 1.0 and r4 == 1.0:
            costs.append(hs)
        else:
            piece, kink = budget_piece(r0, r2, r3, r4, hs, FLOATS)
            if kink and hs > budget_resolution:
                piece = float(kink_costs(model, np.array([tc]), hs, np.array([xc]), np.array([f(tc, xc, a, b)]),
                                         np.array([xn]), np.array([f(te, xn, a, b)]), eps, budget_resolution)[0])
            costs.append(piece)
        xc = xn
        if j == last:
            return xc, math.fsum(costs), rate(t + h, xn, eps), h
        r0 = rate(te, xn, eps)
        if stop is not None and stop(te, xn, r0):
            return xc, math.fsum(costs), r0, (j + 1) * hs
    raise ValueError(f"n_substeps must be a positive integer, got {n_substeps!r}")
