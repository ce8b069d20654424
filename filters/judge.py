"""One held action judged, compiled: the one-period test (docs/filters.md, "The one-period test") for one row, in
parts that :mod:`softreach.filters.compiled` calls only where their answer can decide. :func:`judge` reads no table
(the period's bounds are :mod:`softreach.reach.proof.period`'s); :func:`next_value`, :func:`_safe_end` and
:func:`on_table` read it; :func:`badness` ranks the actions that do not pass. A value over a box is read only where
its lower corner's value (:func:`~softreach.reach.proof.kernels.point_value`, at most the box maximum) cannot settle
the choice, which is that of reading every value.

Inlined or called (:mod:`softreach.reach.proof.kernels`; docs/filters.md, "How"): what a loop runs is inlined into
it, :func:`judge` once, into the decision's loop; each loop, the other searches (:func:`judge_once`) and large parts
run at most once a row are called, as every inlined copy is typed again and typing is superlinear in length.
"""

from __future__ import annotations

import math

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import MAX_NODES, box_max_row, cover_row, point_value, usable_budget
from softreach.reach.proof.period import c1_and_charge, enclose_period, lands, meets_target, period
from softreach.reach.proof.ranks import (LOWEST_BAD, NEXT_CAP, RANK_LEAVES_C1, RANK_OVERSPENT, RANK_PROVEN, RANK_SAFE,
                                  RANK_UNSAFE, TIE_INF, TIE_OVERSPEND)

from .compiled_args import Verdict

# LOWEST_BAD (softreach.reach.proof.ranks) is read here by the decision's callers and tests
__all__ = ["LOWEST_BAD", "badness", "judge", "judge_once", "least_next", "next_value", "on_table", "read_least"]


@njit(inline="always")
def judge(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """The one-period test of one row, which reads no table: a :class:`~softreach.filters.compiled_args.Verdict`;
    writes the end box into ``end_lo``, ``end_hi``. ``lands`` is asked only of an action that does not pass."""
    tube_lo, tube_hi, lo, hi = work.tube_lo, work.tube_hi, work.lo, work.hi
    n = len(x_lo)
    dt = period(M)
    bounded = enclose_period(enclose, M, x_lo, x_hi, a, dt, tube_lo, tube_hi, end_lo, end_hi)
    c1, charge = c1_and_charge(enclose, M, x_lo, x_hi, a, M.edges, tube_lo, tube_hi, lo, hi)
    z_end = z - charge
    horizon = M.horizon
    t_next = t + dt
    in_time = t_next <= horizon + 1e-9 * max(1.0, horizon)
    t_next = min(t_next, horizon)
    kept = bounded and c1 <= 0 and z_end >= 0 and in_time
    in_c1 = bounded and c1 <= 0 and in_time
    safe_end = kept and (not C.has_safe or cover_row(C.safe, t_next, end_lo, end_hi, z_end))
    ok = safe_end and cover_row(C.land, t_next, end_lo, end_hi, z_end)
    landed = False
    if not ok and bounded and in_time and meets_target(M, tube_lo, tube_hi):
        landed = lands(enclose, M, x_lo, x_hi, z, a, tube_lo, tube_hi, work.box_lo[:n], work.box_hi[:n], lo, hi)
    return Verdict(ok, landed, bounded, in_c1, kept, safe_end and C.has_safe, c1, z_end, t_next)


@njit(_nrt=False)
def judge_once(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """:func:`judge`, compiled once, for the searches from a whole box or outside the decision."""
    return judge(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work)


@njit(inline="always")
def next_value(T, t_next, end_lo, end_hi, z_end, z_hi, work):
    """The worst certificate over a period's end box, the budget between ``z_end`` and ``z_hi`` (``+inf`` where
    the table has no number): the next value of an action whose motion keeps ``C1``."""
    W, z_floor, V, has_V = T.W, T.z_floor, T.V, T.has_V
    box_lo, box_hi, scratch_W, scratch_V = work.box_lo, work.box_hi, work.scratch_W, work.scratch_V
    n = len(end_lo)
    z_lo = max(usable_budget(z_end, np.inf, T.z_left, t_next), z_floor)
    for i in range(n):
        box_lo[i], box_hi[i] = end_lo[i], end_hi[i]
    box_lo[n], box_hi[n] = z_lo, max(usable_budget(z_hi, T.z_top, T.z_left, t_next), z_lo)
    best = box_max_row(W, t_next, box_lo, box_hi, MAX_NODES, scratch_W)
    if has_V and z_end >= 0 and not math.isnan(best):
        # V's box maximum is at least its corner value (up to rounding): where that lies above W's maximum, V's box
        # need not be read (a NaN it might hold aside: table.py refuses non-finite snapshots)
        corner = point_value(V, t_next, end_lo, scratch_V[2], scratch_V[8])
        if not corner - _ROUNDING * max(1.0, abs(corner)) >= best:
            v = box_max_row(V, t_next, end_lo, end_hi, MAX_NODES, scratch_V)
            best = np.nan if math.isnan(v) else min(best, v)
    return np.inf if math.isnan(best) else best


@njit(inline="always")
def _safe_end(T, t_next, end_lo, end_hi, work):
    """Whether the safe value ``V_safe`` (where the table has it) is at most 0 over a period's end box."""
    S, scratch = T.S, work.scratch_V
    if not T.has_S:
        return True
    # the corner value is at most the box maximum (up to rounding, which the tolerance covers)
    corner = point_value(S, t_next, end_lo, scratch[2], scratch[8])
    if corner > _ROUNDING * max(1.0, abs(corner)):
        return False
    return box_max_row(S, t_next, end_lo, end_hi, MAX_NODES, scratch) <= 0


@njit(inline="always")
def next_floor(T, t_next, end_lo, z_end, work):
    """A lower bound of :func:`next_value` over the box from ``end_lo`` (``-inf`` where it has none): the
    certificate at the box's lower corner and lowest budget, which the box maximum's lattice holds."""
    point, scratch_W, scratch_V = work.box_lo, work.scratch_W, work.scratch_V
    n = len(end_lo)
    for i in range(n):
        point[i] = end_lo[i]
    point[n] = max(usable_budget(z_end, np.inf, T.z_left, t_next), T.z_floor)
    low = point_value(T.W, t_next, point, scratch_W[2], scratch_W[8])
    if T.has_V and z_end >= 0:
        low = min(low, point_value(T.V, t_next, end_lo, scratch_V[2], scratch_V[8]))
    return -np.inf if math.isnan(low) else low


#: relative tolerance of a bound that settles a choice: far above interpolation rounding, far below a deciding gap
_ROUNDING = 1e-9


@njit(_nrt=False)
def read_least(T, t_next, end_lo, end_hi, z_hi, work, c_zend, c_low, least, below, ties, out):
    """Into ``out``, the candidates' next values (ties, :func:`_tie`, where ``ties``) in the order of their finite lower
    bounds ``c_low``, until the next bound lies above a least (from ``least``) below ``below``; one not read gets its
    bound, so the least is that of reading all. Leaves ``c_low`` at ``+inf``."""
    J = len(c_low)
    while True:
        k = np.argmin(c_low)
        if c_low[k] == np.inf:
            return
        bar = least + _ROUNDING * max(1.0, abs(least)) if least > -np.inf else -np.inf
        if least < below and c_low[k] > bar:
            for j in range(J):
                if c_low[j] < np.inf:
                    out[j], c_low[j] = c_low[j], np.inf
            return
        value = next_value(T, t_next, end_lo[k], end_hi[k], c_zend[k], z_hi, work)
        out[k] = _tie(value, c_zend[k]) if ties else value
        least = min(least, out[k])
        c_low[k] = np.inf


@njit(_nrt=False)
def least_next(T, t_next, end_lo, end_hi, z_hi, work, pick, c_next, c_zend, c_low):
    """:func:`next_value` of the candidates ``pick`` where it can be the least (:func:`read_least`), while the least
    is below :data:`~softreach.reach.proof.ranks.NEXT_CAP`; one whose bound is ``+inf`` is off the grid, where its
    value is ``+inf`` too, as ``c_next`` holds."""
    # the least so far: of those not picked (one that surely lands has -inf)
    least = np.inf
    for k in range(len(pick)):
        c_low[k] = next_floor(T, t_next, end_lo[k], c_zend[k], work) if pick[k] else np.inf
        if not pick[k]:
            least = min(least, c_next[k])
    # np.bool_: for a literal False read_least would compile once more
    read_least(T, t_next, end_lo, end_hi, z_hi, work, c_zend, c_low, least, NEXT_CAP, np.bool_(False), c_next)


@njit(inline="always")
def _rank(bounded, in_c1, proven, is_safe, kept, c1):
    """The badness of an action that does not pass, but for its tie: its rank (:mod:`softreach.reach.proof.ranks`)."""
    if not bounded:
        return np.inf
    if not in_c1:
        return RANK_LEAVES_C1 + max(c1, 0.0)
    return RANK_PROVEN if proven else (RANK_SAFE if is_safe else RANK_UNSAFE) + (0.0 if kept else RANK_OVERSPENT)


@njit(inline="always")
def _tie(nxt, z_end):
    """Within a rank, the lower next table value first (mapped into ``(-0.5, 0.5)``), then the smaller overspend."""
    return math.atan(TIE_INF if nxt == np.inf else nxt) / math.pi + TIE_OVERSPEND * max(-z_end, 0.0)


@njit(_nrt=False)
def badness(T, t_next, end_lo, end_hi, z_hi, work, c_ok, c_in, c_bounded, c_proven, c_kept, c_c1, c_zend, keeps_j,
             contest, c_bad, c_score, c_low, c_tie):
    """The badness and score of every failing candidate, the table read only where it can decide: where ``contest``
    (no other scores below :data:`~softreach.reach.proof.ranks.LOWEST_BAD`), for the lowest rank, and for the smooth
    rule's kept candidate ``keeps_j``, whose badness decides the safe plans. Every other gets its rank alone, at least
    :data:`~softreach.reach.proof.ranks.NEXT_CAP` above the lowest rank's badness: the exact badness's choice."""
    J = len(c_ok)
    if keeps_j >= 0 and not c_ok[keeps_j]:
        k = keeps_j
        is_safe = c_in[k] and _safe_end(T, t_next, end_lo[k], end_hi[k], work)
        c_bad[k] = _rank(c_bounded[k], c_in[k], c_proven[k], is_safe, c_kept[k], c_c1[k])
        if c_in[k]:
            c_bad[k] += _tie(next_value(T, t_next, end_lo[k], end_hi[k], c_zend[k], z_hi, work), c_zend[k])
    # a proven end ranks first: then no other's safe value can decide
    proven = False
    for k in range(J):
        proven = proven or (not c_ok[k] and k != keeps_j and c_in[k] and c_proven[k])
    lowest = np.inf
    for k in range(J):
        if c_ok[k] or k == keeps_j:
            continue
        is_safe = c_in[k] and (proven or not contest or _safe_end(T, t_next, end_lo[k], end_hi[k], work))
        c_bad[k] = _rank(c_bounded[k], c_in[k], c_proven[k], is_safe, c_kept[k], c_c1[k])
        lowest = min(lowest, c_bad[k])
    # the lowest rank's ties, each read where it can be the least (read_least)
    for k in range(J):
        eligible = contest and not c_ok[k] and k != keeps_j and c_in[k] and c_bad[k] == lowest
        c_low[k] = _tie(next_floor(T, t_next, end_lo[k], c_zend[k], work), c_zend[k]) if eligible else np.inf
        c_tie[k] = 0.0
    read_least(T, t_next, end_lo, end_hi, z_hi, work, c_zend, c_low, np.inf, np.inf, np.bool_(True), c_tie)
    for k in range(J):
        if not (c_ok[k] or k == keeps_j):
            c_bad[k] += c_tie[k]
            c_score[k] = c_bad[k]


@njit(_nrt=False)
def on_table(W, t, x, z, point, scratch):
    """:meth:`Table.inside` of a ``W_eps`` table: the interpolant of ``W`` is finite at ``(t, x, z)`` (a budget above
    the grid is read at its top)."""
    # a field's (values, times, shape, glo, ghi, ...) (softreach.reach.proof.box_max.kernel_field)
    times, glo, ghi = W[1], W[3], W[4]
    n = len(x)
    if not (t >= times[0] - 1e-9 and t <= times[-1] + 1e-9) or not z >= glo[n]:
        return False
    for a in range(n):
        point[a] = x[a]
    point[n] = min(z, ghi[n])
    # the interpolant at a point is the box maximum of a box of no width, by the same arithmetic
    return math.isfinite(point_value(W, t, point, scratch[2], scratch[8]))
