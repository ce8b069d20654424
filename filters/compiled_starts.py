"""The start-plan search of :meth:`~softreach.filters.compiled.CompiledDecision.start_plans`, compiled, in its order:
each period is :func:`~softreach.filters.judge.judge_once`, which reads no table. ``tests/test_filters_soundness.py``
flies the plans it finds against switching winds."""

import math

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.period import Motion, period

from .compiled_args import Cells, Work
from .judge import judge_once
from .plans import PLAN_LAND


@njit(inline="always")
def _hold_period(enclose, M, C, t, lo, hi, z, a, e_lo, e_hi, work):
    """One period of ``a`` held from the box ``[lo, hi]`` at budget ``z``: ``(passes, goes on, z_end)``; goes on: kept
    ``C1`` and the budget with a finite end box, which then replaces ``[lo, hi]``. Inlined: a few lines around
    :func:`~softreach.filters.judge.judge_once`, which a function of its own would only link once more."""
    v = judge_once(enclose, M, C, t, lo, hi, z, a, e_lo, e_hi, work)
    kept = v.kept
    for i in range(len(e_lo)):
        kept = kept and math.isfinite(e_lo[i]) and math.isfinite(e_hi[i])
    if kept:
        for i in range(len(e_lo)):
            lo[i], hi[i] = e_lo[i], e_hi[i]
    return v.ok or v.lands, kept, v.z_end


@njit(_nrt=False)
def _segment_row(enclose, M, C, cands, periods, t, lo0, hi0, z, from_state, lo, hi, e_lo, e_hi, work):
    """One segment's search for one row: ``(candidate or -1, periods, once)``, the first candidate of the fewest
    periods; ``once``: from the state itself (``from_state``) one passes in one period."""
    dt = period(M)
    best, best_j, once = periods + 1, -1, False
    for j in range(cands.shape[0]):
        for i in range(len(lo0)):
            lo[i], hi[i] = lo0[i], hi0[i]
        zz, tt = z, t
        # does the candidate pass after k periods held: a run of k + 1, searched while shorter than the best
        for k in range(min(periods, best - 1)):
            passes, goes, zz = _hold_period(enclose, M, C, tt, lo, hi, zz, cands[j], e_lo, e_hi, work)
            if passes:
                if k == 0 and from_state:
                    once = True
                else:
                    best, best_j = k + 1, j
                break
            if not goes:
                break
            tt = tt + dt
        if once:
            break
    return best_j, best, once


@njit(nogil=True, _nrt=False)
def start_plan_rows(enclose, m_args, c_args, cands, periods, t, x, z, second, out, work_args, boxes):
    """:meth:`~softreach.filters.compiled.CompiledDecision.start_plans` row by row: ``out[r]`` gets its
    ``(START_SEGMENTS, 3)`` segments; the ``*_args`` as plain tuples (:mod:`softreach.filters.compiled_args`)."""
    M, C, work = Motion(*m_args), Cells(*c_args), Work(*work_args)
    N, n = x.shape
    dt = period(M)
    lo, hi, e_lo, e_hi, c_lo, c_hi, c_elo, c_ehi = (boxes[0], boxes[1], boxes[2], boxes[3], boxes[4], boxes[5],
                                                    boxes[6], boxes[7])
    for r in range(N):
        for g in range(out.shape[1]):
            out[r, g, 0], out[r, g, 1], out[r, g, 2] = -1, 0, 0
        # np.bool_: for a literal True or False _segment_row would compile once each
        j1, k1, once = _segment_row(enclose, M, C, cands, periods, t[r], x[r], x[r], z[r], np.bool_(True), lo, hi,
                                    e_lo, e_hi, work)
        # a row some candidate passes from at once is certified by one period: it needs no plan
        if once:
            continue
        if j1 >= 0:
            out[r, 0, 0], out[r, 0, 1], out[r, 0, 2] = j1, k1, PLAN_LAND
            continue
        if not second[r]:
            continue
        # two segments: the shortest first one that a second can follow, the first candidate among those
        best1 = periods
        for j in range(cands.shape[0]):
            for i in range(n):
                c_lo[i], c_hi[i] = x[r, i], x[r, i]
            zz, tt = z[r], t[r]
            for k in range(1, min(periods, best1)):
                _, goes, zz = _hold_period(enclose, M, C, tt, c_lo, c_hi, zz, cands[j], c_elo, c_ehi, work)
                if not goes:
                    break
                tt = tt + dt
                j2, k2, _ = _segment_row(enclose, M, C, cands, periods - k, tt, c_lo, c_hi, zz, np.bool_(False), lo,
                                         hi, e_lo, e_hi, work)
                if j2 >= 0:
                    best1 = k
                    out[r, 0, 0], out[r, 0, 1], out[r, 0, 2] = j, k, PLAN_LAND
                    out[r, 1, 0], out[r, 1, 1], out[r, 1, 2] = j2, k2, PLAN_LAND
                    break
