"""One held action judged, compiled: the one-period test (docs/filters.md, "The one-period test") for one row.
:func:`judge` reads no table (the period's bounds are :mod:`softreach.reach.proof.period`'s); :func:`next_value` and
:func:`on_table` read it, to rank; :func:`badness` ranks the actions that do not pass.

Inlined or called (:mod:`softreach.reach.proof.kernels`; docs/filters.md, "How"): what a loop runs is inlined into
it, :func:`judge` once, into the decision's loop; each loop, the other searches (:func:`judge_once`) and large parts
run at most once a row are called, as every inlined copy is typed again and typing is superlinear in length. Small
helpers of numbers only (outward rounding, ranks, a cell's look-up) are inlined by LLVM instead
(``forceinline=True``): typed once, then inlined at each call site where LLVM compiles the caller."""

import math

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import TOL, certificate_row, cover_row, point_value
from softreach.reach.proof.period import c1_and_charge, enclose_period, lands, meets_target, period

from .compiled_args import Verdict
from .reasons import RANK_KEPT, RANK_LEAVES_C1, RANK_OVERSPENT, TIE_INF, TIE_OVERSPEND

__all__ = ["badness", "judge", "judge_once", "next_value", "on_table"]


@njit(inline="always")
def judge(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """The one-period test of one row: a :class:`~softreach.filters.compiled_args.Verdict`; writes the end box into
    ``end_lo``, ``end_hi``. ``lands`` is asked only of an action that does not pass."""
    tube_lo, tube_hi, lo, hi = work.tube_lo, work.tube_hi, work.lo, work.hi
    n = len(x_lo)
    dt = period(M)
    bounded = enclose_period(enclose, M, x_lo, x_hi, a, dt, tube_lo, tube_hi, end_lo, end_hi)
    c1, charge = c1_and_charge(enclose, M, x_lo, x_hi, a, M.edges, tube_lo, tube_hi, lo, hi)
    z_end, horizon, t_next = z - charge, M.horizon, t + dt
    in_time = t_next <= horizon + 1e-9 * max(1.0, horizon)
    t_next = min(t_next, horizon)
    in_c1 = bounded and c1 <= 0 and in_time
    kept = in_c1 and z_end >= 0
    ok = kept and cover_row(C.land, t_next, end_lo, end_hi, z_end)
    landed = False
    if not ok and bounded and in_time and meets_target(M, tube_lo, tube_hi):
        landed = lands(enclose, M, x_lo, x_hi, z, a, tube_lo, tube_hi, work.box_lo[:n], work.box_hi[:n], lo, hi)
    return Verdict(ok, landed, bounded, in_c1, kept, c1, z_end, t_next)


@njit(_nrt=False)
def judge_once(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """:func:`judge`, compiled once, for the searches from a whole box or outside the decision."""
    return judge(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work)


@njit(_nrt=False)
def next_value(T, t_next, end_lo, end_hi, z_end, work):
    """An action's next value: the certificate ``D`` (:func:`~softreach.reach.proof.kernels.certificate_row`) at its
    end box's centre and the budget ``z_end`` the period may leave; ``+inf`` off the table or below its budget grid."""
    centre = work.centre
    for i in range(len(end_lo)):
        centre[i] = 0.5 * (end_lo[i] + end_hi[i])
    return certificate_row(T.W, T.z_top, T.z_floor, T.z_left, T.V, T.has_V, t_next, centre, z_end, work.point,
                           work.buf, work.node)


@njit(forceinline=True)
def _rank(bounded, in_c1, kept, c1):
    """The badness of an action that does not pass, but for its tie: its rank (:mod:`softreach.filters.reasons`)."""
    if not bounded:
        return np.inf
    if not in_c1:
        return RANK_LEAVES_C1 + max(c1, 0.0)
    return RANK_KEPT if kept else RANK_OVERSPENT


@njit(forceinline=True)
def _tie(nxt, z_end):
    """Within a rank, the lower next table value first (mapped into ``(-0.5, 0.5)``), then the smaller overspend."""
    return math.atan(TIE_INF if nxt == np.inf else nxt) / math.pi + TIE_OVERSPEND * max(-z_end, 0.0)


@njit(_nrt=False)
def badness(T, t_next, end_lo, end_hi, work, c_in, c_bounded, c_kept, c_c1, c_zend, c_bad):
    """Into ``c_bad``, every candidate's badness where none passes: its rank, plus its tie where it keeps ``C1``."""
    for k in range(len(c_bad)):
        c_bad[k] = _rank(c_bounded[k], c_in[k], c_kept[k], c_c1[k])
        if c_in[k]:
            c_bad[k] += _tie(next_value(T, t_next, end_lo[k], end_hi[k], c_zend[k], work), c_zend[k])


@njit(_nrt=False)
def on_table(W, t, x, z, point, buf, node):
    """:meth:`Table.inside` of a ``W_eps`` table: the interpolant of ``W`` is finite at ``(t, x, z)`` (a budget above
    the grid is read at its top)."""
    # a field as softreach.reach.proof.lookahead.kernel_field makes it
    _, times, _, glo, ghi, _, _, _ = W
    n = len(x)
    if not (t >= times[0] - TOL and t <= times[-1] + TOL) or not z >= glo[n]:
        return False
    for a in range(n):
        point[a] = x[a]
    point[n] = min(z, ghi[n])
    return math.isfinite(point_value(W, t, point, buf, node))
