"""The exact soft-constrained reach-avoid sets ``RA~_Q`` (paper Def. 1) of the point mass, and ``Q_min``.

A reference that grades every solver of the point mass (issue 14, spec §2 and §4). Notation: start ``(v0, y0)``,
time left ``S = T - t``, budget ``Q``; speed bands ``[h_lo, h_hi]`` (hard, ``C1``), ``[s_lo, s_hi]`` (soft,
``C2``), ``[vt_lo, 0]`` (target), altitude band ``[0, y_max]`` with the target's ``[0, yt_hi]`` on the ground.

**Reduction.** ``y'' = u - g + d`` with ``d`` entering where ``u`` does: ``min_u max_d p (u + d) =
-(u_max - d_max)|p|``, so the game has the Hamiltonian, hence the value, of the control-only double integrator
``v' = a``, ``a in [-D, U]``, ``D = u_max - d_max + g`` (fastest speed-up downwards), ``U = u_max - d_max - g``
(hardest braking). A profile ``a(s)`` is realised against any disturbance by ``u = a + g - d``.

**Necessary conditions.** (i) ``x0`` in ``C1``. (ii) A climb ``v0 > 0`` must be stopped (the target's speeds are
``<= 0``); full down-thrust stops it soonest (``v0 <= D S``), with the lowest peak ``y0 + v0^2 / 2D <= y_max`` and
the least time above ``s_hi``, ``q_up = (v0 - s_hi)^+ / D``, which every profile spends: ``Q' = Q - q_up >= 0``.
(iii) A fall ``v0 < vt_lo`` must be braked: until ``v`` first reaches ``vt_lo`` the altitude decreases, and full
braking reaches it soonest (``(vt_lo - v0) / U <= S``), highest (``y0 - (v0^2 - vt_lo^2) / 2U >= 0``) and with the
least time below ``s_lo``, ``b = (s_lo - v0)^+ / U <= Q'``. (iv) Descent: every admissible profile on
``[0, tau]``, ``tau <= S``, satisfies ``v >= v* = max(v0 - D s, h_lo, vt_lo - U (tau - s))`` (slope bounds, hard
limit, final speed ``>= vt_lo``), and lengthening ``tau`` to ``S`` at the final speed costs no budget, so take
``tau = S``. ``Q'`` bounds the time below ``s_lo``. Outside the excursions below ``s_lo`` a profile descends at
most ``min(|s_lo|, -v*)`` per unit time; an excursion of length ``L`` (it leaves and re-enters ``s_lo`` with the
slopes bounded) descends at most ``G(L) = int_0^L min(D x, U (L - x), s_lo - h_lo) dx`` further, and ``G`` is convex
with ``G(0) = 0``, hence superadditive: one excursion beats several. When ``v0 < s_lo`` the excursion forced at
``s = 0`` takes the whole budget (prolonging it gains at least ``G`` of the added length). So the largest descent
is ``Dmax(S, Q') = -int_0^S v_opt`` with

    v_opt(s) = max(v*(s), s_lo - U (e - s)^+),   e = (v0 - s_lo)^+ / D + Q',

down-thrust to ``s_lo``, on down to at most ``h_lo`` and back up to ``s_lo`` by ``e``, hold ``s_lo``, brake to
``vt_lo`` at ``S`` (``v_opt = v*`` once ``Q'`` exceeds the time ``v*`` spends below ``s_lo``). Condition:
``y0 - Dmax <= yt_hi``. ``v_opt`` is piecewise linear with kinks at ``e`` and where two of its lines cross, so the
trapezoid rule on those points integrates it exactly.

**Sufficiency.** With (i)-(iv), the profiles ``v_opt`` for horizons ``S'`` from the end of the stop/brake of
(ii)/(iii) up to ``S`` are admissible (budget ``<= Q``, ``v <= 0`` after the stop, so ``0 <= y <= y_max`` until they
end, in the target's speed band); their final altitude moves continuously from the altitude after the stop/brake
(``>= 0``) down to ``y0 - Dmax(S) <= yt_hi``, so one ends in ``[0, yt_hi]``: a member.

``Q_min = q_up + min{Q' >= b : y0 - Dmax(S, Q') <= yt_hi}`` (``+inf`` if (i)-(iii) fail or no ``Q' <= S`` does),
found by bisection: ``Dmax`` is continuous and nondecreasing in ``Q'``. The sets are closed (as ``W <= 0``): the
inequalities hold up to ``tol``. These are Def. 1's sets, the ``eps -> 0`` limit: ``W_eps`` charges
``h_eps = min(1, c2^+ / eps) <= 1{c2 > 0}``, so its sets contain these, by a margin of order ``eps`` (a speed
``eps`` past ``s_lo`` costs a full unit of budget), far below a grid cell. Assumes what the paper's parameters satisfy: ``h_lo <= s_lo <= vt_lo`` and
``s_hi <= h_hi`` (target inside ``C2`` inside ``C1``), the target's speeds end at 0 and its floor is the ground,
``U > 0``; other parameters raise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

import numpy as np

from ..models.pointmass import PointMassParams


@dataclass(frozen=True)
class _Consts:
    D: float
    U: float
    h_lo: float
    h_hi: float
    s_lo: float
    s_hi: float
    vt_lo: float
    y_max: float
    yt_hi: float


def _constants(params: PointMassParams | None) -> _Consts:
    p = params or PointMassParams()
    authority = p.u_max - p.d_max
    c = _Consts(D=authority + p.gravity, U=authority - p.gravity, h_lo=p.hard_speed[0], h_hi=p.hard_speed[1],
                s_lo=p.soft_speed[0], s_hi=p.soft_speed[1], vt_lo=p.target_speed[0], y_max=p.altitude[1],
                yt_hi=p.target_altitude[1])
    checks = {"u_max - d_max > gravity (braking authority)": c.U > 0,
              "target speeds end at 0": p.target_speed[1] == 0.0,
              "target floor is the ground": p.target_altitude[0] == p.altitude[0] == 0.0,
              "hard_lo <= soft_lo <= target_lo": c.h_lo <= c.s_lo <= c.vt_lo,
              "soft_hi <= hard_hi": 0.0 <= c.s_hi <= c.h_hi,
              "target altitude inside the altitude band": c.yt_hi <= c.y_max}
    failed = [k for k, ok in checks.items() if not ok]
    if failed:
        raise ValueError(f"the exact point-mass reference does not cover these parameters: {failed}")
    return c


def _arrays(*xs: Any) -> list[np.ndarray]:
    return list(np.broadcast_arrays(*[np.asarray(x, dtype=np.float64) for x in xs]))


def speed_profile(s: Any, v0: Any, time_left: Any, budget: Any, params: PointMassParams | None = None) -> np.ndarray:
    """The speed ``v_opt(s)`` of the largest-descent profile (module docstring, (iv)) over ``s in [0, time_left]``.

    :param s: times since the start [s]
    :param v0: start speeds [m/s]
    :param time_left: ``S``, the horizon of the profile [s]
    :param budget: total budget ``Q`` [s] (the forced time above ``s_hi`` is taken off here)
    :param params: model parameters (default: the paper's)
    :returns: ``v_opt(s)`` [m/s], broadcast over the arguments; meaningful where :func:`exact_member`'s
        conditions (i)-(iii) hold
    """
    c = _constants(params)
    s, v0, S, q = _arrays(s, v0, time_left, budget)
    e = np.maximum(v0 - c.s_lo, 0.0) / c.D + q - np.maximum(v0 - c.s_hi, 0.0) / c.D
    return np.maximum.reduce([v0 - c.D * s, np.full_like(s, c.h_lo), c.vt_lo - c.U * (S - s),
                              c.s_lo - c.U * np.maximum(e - s, 0.0)])


def max_descent(v0: Any, time_left: Any, budget: Any, params: PointMassParams | None = None) -> np.ndarray:
    """``Dmax = -int_0^S v_opt``: the most altitude any admissible profile loses in ``S`` with budget ``Q`` [m].

    Exact: ``v_opt`` is linear between its kinks, which are among ``0``, ``S``, ``e`` and the pairwise crossings of
    its five lines, so the trapezoid rule on those points is its integral.

    :param v0: start speeds [m/s]
    :param time_left: ``S`` [s]
    :param budget: total budget ``Q`` [s]
    :param params: model parameters (default: the paper's)
    """
    c = _constants(params)
    v0, S, q = _arrays(v0, time_left, budget)
    e = np.maximum(v0 - c.s_lo, 0.0) / c.D + q - np.maximum(v0 - c.s_hi, 0.0) / c.D
    # the lines as (intercept, slope) in s
    lines = [(v0, -c.D), (np.full_like(v0, c.h_lo), 0.0), (c.vt_lo - c.U * S, c.U), (c.s_lo - c.U * e, c.U),
             (np.full_like(v0, c.s_lo), 0.0)]
    knots = [np.zeros_like(v0), S, np.clip(e, 0.0, S)]
    for i, (a_i, b_i) in enumerate(lines):
        for a_j, b_j in lines[i + 1:]:
            if b_i != b_j:
                knots.append(np.clip((a_j - a_i) / (b_i - b_j), 0.0, S))
    knots = np.sort(np.stack(knots, axis=-1), axis=-1)
    v = speed_profile(knots, v0[..., None], S[..., None], q[..., None], params)
    return -np.sum(0.5 * (v[..., 1:] + v[..., :-1]) * np.diff(knots, axis=-1), axis=-1)


def _stop_and_brake(v: np.ndarray, y: np.ndarray, S: np.ndarray, c: _Consts, tol: float
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Conditions (i)-(iii) without the budget; the forced time above ``s_hi`` and below ``s_lo``."""
    ok = (v >= c.h_lo - tol) & (v <= c.h_hi + tol) & (y >= -tol) & (y <= c.y_max + tol) & (S >= 0)
    up = np.maximum(v, 0.0)
    ok &= (y + up**2 / (2 * c.D) <= c.y_max + tol) & (up <= c.D * S + tol)
    fall = np.maximum(c.vt_lo - v, 0.0)
    ok &= (fall <= c.U * S + tol) & (y - (v**2 - c.vt_lo**2) * (fall > 0) / (2 * c.U) >= -tol)
    return ok, np.maximum(v - c.s_hi, 0.0) / c.D, np.maximum(c.s_lo - v, 0.0) / c.U


def exact_member(v: Any, y: Any, budget: Any, time_left: Any = 1.0, params: PointMassParams | None = None,
                 tol: float = 1e-9) -> np.ndarray:
    """Whether each state ``(v, y)`` lies in the exact ``RA~_Q`` with ``time_left`` to go (Def. 1).

    :param v: vertical speeds [m/s]
    :param y: altitudes [m]
    :param budget: ``Q`` [s], scalar or per state
    :param time_left: ``T - t`` [s], scalar or per state (``0``: membership of the target)
    :param params: model parameters (default: the paper's)
    :param tol: slack of every inequality (m, m/s or s): the sets are closed, this absorbs rounding on their boundary
    :returns: boolean array, broadcast over the arguments
    """
    c = _constants(params)
    v, y, q, S = _arrays(v, y, budget, time_left)
    ok, q_up, q_fall = _stop_and_brake(v, y, S, c, tol)
    ok &= q - q_up >= q_fall - tol
    return ok & (y - max_descent(v, S, q, params) <= c.yt_hi + tol)


def exact_q_min(v: Any, y: Any, time_left: Any = 1.0, params: PointMassParams | None = None, tol: float = 1e-9,
                iterations: int = 60) -> np.ndarray:
    """The exact least budget ``Q_min`` [s] of each state (``+inf`` where no budget suffices).

    ``exact_member(v, y, Q) == (exact_q_min(v, y) <= Q)`` up to the bisection's resolution, ``S / 2**iterations``.

    :param v: vertical speeds [m/s]
    :param y: altitudes [m]
    :param time_left: ``T - t`` [s]
    :param params: model parameters (default: the paper's)
    :param tol: as in :func:`exact_member`
    :param iterations: bisection steps on the budget below ``s_lo``
    """
    c = _constants(params)
    v, y, S = _arrays(v, y, time_left)
    ok, q_up, lo = _stop_and_brake(v, y, S, c, tol)
    hi = np.maximum(S, lo)

    def lands(q_down: np.ndarray) -> np.ndarray:
        return y - max_descent(v, S, q_up + q_down, params) <= c.yt_hi + tol

    ok &= lands(hi)
    at_lo = lands(lo)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        good = lands(mid)
        hi, lo = np.where(good, mid, hi), np.where(good, lo, mid)
    return np.where(ok, q_up + np.where(at_lo, lo, hi), np.inf)


def exact_mask(table: Any, budget: float, t: float = 0.0, params: PointMassParams | None = None,
               tol: float = 1e-9) -> np.ndarray:
    """The exact ``RA~_Q`` at time ``t`` on a table's state nodes, the convention of ``Table.set_mask``.

    :param table: a point-mass :class:`softreach.reach.tables.query.Table`
    :param budget: ``Q`` [s]
    :param t: time [s] (time left: the table's last snapshot time minus ``t``)
    :param params: model parameters (default: the table's model's)
    :param tol: as in :func:`exact_member`
    """
    vv, yy = np.meshgrid(*table.state_axes(), indexing="ij")
    params = params or table.model.params
    return exact_member(vv, yy, budget, table.horizon - t, params, tol)


def grade(table: Any, budgets: Iterable[float] = (0.0, 0.06, 0.3, 0.6), t: float = 0.0,
          params: PointMassParams | None = None) -> dict[float, dict[str, float]]:
    """Soundness and tightness of a table's ``RA~_Q`` against the exact sets, on the table's own nodes.

    Both sets are read at the nodes (``Table.set_mask(t, Q)``, and :func:`exact_mask`) and each node stands for one
    cell of area ``Table.cell_volume()`` [m^2/s], as ``Table.set_measure`` counts.

    :param table: a point-mass table with ``W_eps``
    :param budgets: the budgets ``Q`` [s] to grade
    :param t: time [s]
    :param params: model parameters (default: the table's model's)
    :returns: per ``Q``: ``exact_area``, ``claimed_area``, ``unsound_area`` (claimed, proved infeasible),
        ``missed_area`` (exact, not claimed), ``symmetric_difference`` (their sum) and ``relative_difference``
        (symmetric difference over exact area), areas in m^2/s
    """
    cell = table.cell_volume()
    out: dict[float, dict[str, float]] = {}
    for q in budgets:
        exact = exact_mask(table, q, t, params)
        claimed = np.asarray(table.set_mask(t, q), dtype=bool)
        unsound, missed = float((claimed & ~exact).sum()) * cell, float((exact & ~claimed).sum()) * cell
        area = float(exact.sum()) * cell
        out[float(q)] = {"exact_area": area, "claimed_area": float(claimed.sum()) * cell, "unsound_area": unsound,
                         "missed_area": missed, "symmetric_difference": unsound + missed,
                         "relative_difference": (unsound + missed) / area if area > 0 else float("nan")}
    return out
