"""Whether a held action keeps the next state certified, compiled: the rule's "some candidate passes again from
every possible next state" (docs/filters.md, "The filter with cells").
"""

from __future__ import annotations

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import cover_row
from softreach.reach.proof.model_kernels import call_held_box
from softreach.reach.proof.period import meets_target, period, widen

from .judge import judge_once


@njit(inline="always")
def _may_pass(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """Whether :func:`~softreach.filters.judge.judge` may find that ``a`` passes or surely lands, a cheaper test asked
    first: the landing cells cover its end box at ``z``, at least the budget left (a cell that covers at some budget
    covers at more), or its motion meets the target."""
    params, edges, horizon = M.params, M.edges, M.horizon
    dt = period(M)
    call_held_box(enclose, params, x_lo, x_hi, a, dt, dt, end_lo, end_hi)
    widen(end_lo, end_hi, M.slack)
    if cover_row(C.land, min(t + dt, horizon), end_lo, end_hi, z):
        return True
    call_held_box(enclose, params, x_lo, x_hi, a, edges[0], dt, work.tube_lo, work.tube_hi)
    return meets_target(M, work.tube_lo, work.tube_hi)


@njit(_nrt=False)
def keeps(enclose, M, C, cands, t, end_lo, end_hi, z_end, kept, work, work_box):
    """Whether the next state of an action that does not pass is certified whatever the wind does: its period keeps
    ``C1`` and the budget (``kept``) before the horizon, and some candidate passes or surely lands from the whole end
    box ``[end_lo, end_hi]`` with ``z_end`` left."""
    horizon = M.horizon
    dt = period(M)
    if not kept or t + dt >= horizon - 1e-9 * max(1.0, horizon):
        return False
    e_lo, e_hi = work_box.lo, work_box.hi
    z_lo = max(z_end, 0.0)
    for j in range(cands.shape[0]):
        if not _may_pass(enclose, M, C, t + dt, end_lo, end_hi, z_lo, cands[j], e_lo, e_hi, work):
            continue
        v = judge_once(enclose, M, C, t + dt, end_lo, end_hi, z_lo, cands[j], e_lo, e_hi, work)
        if v.ok or v.lands:
            return True
    return False


__all__ = ["keeps"]
