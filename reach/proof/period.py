"""One held period bounded, compiled: the box of its motion, the largest ``c1`` over it, the budget it may spend,
and whether every run surely lands inside it (the test: :mod:`softreach.reach.proof.lookahead`). The filter's
decision (:mod:`softreach.filters.judge`) runs these for a state, the cells' builder
(:mod:`softreach.reach.proof.cell_game`) for boxes of starts (:func:`period_rows`)."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ..jit import njit
from .kernels import frozen
from .model_kernels import SET_INDEX, call_held_box, call_set_max, held_box_address, set_max_address

# the sets' indices in the model's set-maximum kernel
_TARGET, _HARD, _SOFT = SET_INDEX["target"], SET_INDEX["hard_constraint"], SET_INDEX["soft_constraint"]


class Motion(NamedTuple):
    """The look-ahead's numbers as the compiled code reads them (:func:`motion`)."""

    params: np.ndarray  #: the model's ``held_box_params``
    eps: float  #: the ``h_eps`` width with which the environment drains the budget
    set_params: Any  #: the parameters of the model's compiled set maxima
    set_address: int  #: the address of the model's compiled set maxima
    target_lo: np.ndarray  #: the target box's lower corner (``-inf`` where the model has none)
    target_hi: np.ndarray  #: the target box's upper corner (``+inf`` where the model has none)
    edges: np.ndarray  #: the instants ``0, dt / P, ..., dt`` that cut the period into the budget's ``P`` pieces
    check_edges: np.ndarray  #: a row per landing check instant ``s``: the instants cutting ``[0, s]`` into ``P`` pieces
    horizon: float  #: the table's horizon ``T`` [s]
    #: how far the env's state may lie from an exact motion (:attr:`~softreach.reach.proof.lookahead.Lookahead.slack`)
    slack: np.ndarray
    #: that for the stage states where the env reads the budget's rate
    #: (:attr:`~softreach.reach.proof.lookahead.Lookahead.stage_slack`)
    stage_slack: np.ndarray
    first_check: float  #: the environment's first check instant inside a period [s]
    budget_slack: float  #: added to a positive charge (:func:`~softreach.reach.proof.lookahead.budget_allowance`)
    env_covered: bool  #: the allowances apply (:attr:`~softreach.reach.proof.lookahead.Lookahead.env_covered`)


def motion(la: Any) -> tuple[int, Motion]:
    """The address of the model's compiled enclosure and the :class:`Motion` of the look-ahead ``la`` (whose model
    gives what the filter needs: :func:`~softreach.reach.proof.enclosure_check.missing_extras`)."""
    model, tb = la.model, la.model.target_box
    t_lo, t_hi = ((np.full(la.n, -np.inf), np.full(la.n, np.inf)) if tb is None
                  else (np.asarray(tb[0], dtype=np.float64), np.asarray(tb[1], dtype=np.float64)))
    checks = np.stack([np.linspace(0.0, la.dt * j / la.target_checks, la.pieces + 1)
                       for j in range(1, la.target_checks + 1)])
    M = Motion(np.asarray(model.held_box_params, dtype=np.float64), la.eps,
               np.ascontiguousarray(model.set_max_params, dtype=np.float64), set_max_address(model), t_lo, t_hi,
               np.linspace(0.0, la.dt, la.pieces + 1), checks, la.horizon, frozen(la.slack), frozen(la.stage_slack),
               la.first_check, la.budget_slack, la.env_covered)
    return held_box_address(model), M


@njit(inline="always")
def period(M):
    """The control period ``dt`` of :class:`Motion` ``M``: its last edge."""
    return M.edges[len(M.edges) - 1]


@njit(inline="always")
def widen(lo, hi, slack):
    """The box ``[lo, hi]`` grown in place by ``slack``, so that it holds the environment's states."""
    for i in range(len(lo)):
        lo[i] -= slack[i]
        hi[i] += slack[i]


@njit(inline="always")
def set_max(M, which, lo, hi):
    """The largest value of the model's set ``which`` over the box ``[lo, hi]``."""
    return call_set_max(M.set_address, M.set_params, which, lo, hi)


@njit(inline="always")
def checked_c1(enclose, M, x_lo, x_hi, a, length, tube_lo, tube_hi, lo, hi):
    """The largest ``c1`` over the motion of ``length`` seconds: over the exact tube, and over the widened box of
    the states from the environment's first check instant on (the start is its own number, exact)."""
    c1 = set_max(M, _HARD, tube_lo, tube_hi)
    if not M.env_covered:  # no allowance: the tube alone
        return c1
    call_held_box(enclose, M.params, x_lo, x_hi, a, min(M.first_check, length), length, lo, hi)
    widen(lo, hi, M.slack)
    moved = set_max(M, _HARD, lo, hi)
    # a NaN from either side wins
    return moved if (moved > c1 or math.isnan(moved)) else c1


@njit(inline="always")
def may_spend(enclose, M, x_lo, x_hi, a, length, tube_lo, tube_hi, lo, hi):
    """Whether the environment's cost over ``length`` seconds may be positive: the tube, or the box from half the
    first sub-step on (its first stage states) widened by the stage slack, may leave ``C2``; else every rate it reads
    is 0."""
    if not set_max(M, _SOFT, tube_lo, tube_hi) <= 0:
        return True
    if not M.env_covered:  # no allowance: the tube alone
        return False
    call_held_box(enclose, M.params, x_lo, x_hi, a, min(0.5 * M.first_check, length), length, lo, hi)
    widen(lo, hi, M.stage_slack)
    return not set_max(M, _SOFT, lo, hi) <= 0


@njit(inline="always")
def spent(enclose, M, x_lo, x_hi, a, edges, lo, hi):
    """The budget the motion over the pieces ``[edges[j], edges[j + 1]]`` may spend: each its share of the length
    times the largest ``h_eps`` over its box widened by the stage slack, plus the rounding allowance where
    positive."""
    P = len(edges) - 1
    length = edges[P]
    out = 0.0
    for j in range(P):
        call_held_box(enclose, M.params, x_lo, x_hi, a, edges[j], edges[j + 1], lo, hi)
        widen(lo, hi, M.stage_slack)
        out += (length / P) * min(max(set_max(M, _SOFT, lo, hi) / M.eps, 0.0), 1.0)
    return out + M.budget_slack if out > 0 else out


@njit(inline="always")
def enclose_period(enclose, M, x_lo, x_hi, a, length, tube_lo, tube_hi, end_lo, end_hi):
    """Writes the tube over ``[0, length]`` of ``a`` held from ``[x_lo, x_hi]`` and its widened end box; returns
    whether the tube is finite (the enclosure writes NaN where it finds no box)."""
    call_held_box(enclose, M.params, x_lo, x_hi, a, 0.0, length, tube_lo, tube_hi)
    call_held_box(enclose, M.params, x_lo, x_hi, a, length, length, end_lo, end_hi)
    widen(end_lo, end_hi, M.slack)
    bounded = True
    for i in range(len(tube_lo)):
        bounded = bounded and math.isfinite(tube_lo[i]) and math.isfinite(tube_hi[i])
    return bounded


@njit(inline="always")
def c1_and_charge(enclose, M, x_lo, x_hi, a, edges, tube_lo, tube_hi, lo, hi):
    """:func:`checked_c1` until ``edges[-1]`` and the charge (:func:`spent` where it :func:`may_spend`, else 0)."""
    length = edges[len(edges) - 1]
    c1 = checked_c1(enclose, M, x_lo, x_hi, a, length, tube_lo, tube_hi, lo, hi)
    charge = spent(enclose, M, x_lo, x_hi, a, edges, lo, hi) if may_spend(
        enclose, M, x_lo, x_hi, a, length, tube_lo, tube_hi, lo, hi) else 0.0
    return c1, charge


@njit(inline="always")
def meets_target(M, tube_lo, tube_hi):
    """Whether the period's tube meets the target box (only then can it surely land)."""
    meets = True
    for i in range(len(tube_lo)):
        meets = meets and tube_hi[i] >= M.target_lo[i] and tube_lo[i] <= M.target_hi[i]
    return meets


@njit(_nrt=False)
def lands(enclose, M, x_lo, x_hi, z, a, tube_lo, tube_hi, end_lo, end_hi, lo, hi):
    """Whether every run of ``a`` held from the box surely lands at a check instant ``s`` (:attr:`Motion.check_edges`):
    the widened box at ``s`` lies in the target inside ``C2`` (maxima at corners: these sets are convex or monotone
    along each axis), the motion until ``s`` keeps ``C1`` and spends at most ``z``. The episode ends at the first
    instant in the target, so every run ends landed by ``s``."""
    for j in range(M.check_edges.shape[0]):
        edges = M.check_edges[j]
        s = edges[len(edges) - 1]
        if not enclose_period(enclose, M, x_lo, x_hi, a, s, tube_lo, tube_hi, end_lo, end_hi):
            continue
        if not (set_max(M, _TARGET, end_lo, end_hi) <= 0 and set_max(M, _SOFT, end_lo, end_hi) <= 0):
            continue
        c1, charge = c1_and_charge(enclose, M, x_lo, x_hi, a, edges, tube_lo, tube_hi, lo, hi)
        if c1 <= 0 and z - charge >= 0:
            return True
    return False


@njit(nogil=True)
def period_rows(enclose, M, x_lo, x_hi, a, ask, kept, charge, end_lo, end_hi, landed):
    """The cells' builder's period per row (2-d C-contiguous arrays): ``a[r]`` held from ``[x_lo[r], x_hi[r]]``.
    Writes ``kept`` (bounded, keeps ``C1``), ``charge`` (``+inf`` for NaN), the widened end box, and ``landed``
    where ``ask[r]`` and kept (surely lands with any budget; the builder charges the plan's own bound)."""
    n = x_lo.shape[1]
    tube_lo, tube_hi, lo, hi, w_lo, w_hi = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for r in range(x_lo.shape[0]):
        bounded = enclose_period(enclose, M, x_lo[r], x_hi[r], a[r], period(M), tube_lo, tube_hi, end_lo[r], end_hi[r])
        c1, c = c1_and_charge(enclose, M, x_lo[r], x_hi[r], a[r], M.edges, tube_lo, tube_hi, lo, hi)
        kept[r] = bounded and c1 <= 0
        charge[r] = np.inf if math.isnan(c) else c
        landed[r] = (ask[r] and kept[r] and meets_target(M, tube_lo, tube_hi)
                     and lands(enclose, M, x_lo[r], x_hi[r], np.inf, a[r], tube_lo, tube_hi, w_lo, w_hi, lo, hi))
