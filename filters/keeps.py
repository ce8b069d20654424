"""Whether a held action keeps the next state certified, compiled: the rule's "one candidate passes again from every
possible next state" (``docs/filters.md``, "The filter with cells"). An action whose end box lies in the landing
cells keeps by the cells themselves; one whose period keeps ``C1`` and the budget keeps where some candidate,
judged from its whole end box (:func:`~softreach.filters.judge.judge_once`), ends in the landing cells or surely lands.
"""

from __future__ import annotations

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import cover_row
from softreach.reach.proof.model_kernels import call_held_box
from softreach.reach.proof.period import meets_target, period, widen

from .judge import judge_once


@njit(inline="always")
def _may_pass(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """Whether :func:`judge` can find that ``a`` passes or surely lands, asked first as it costs a third of it:
    it passes only where the landing cells cover its end box at the budget left, at most ``z`` (a cell that covers
    at some budget covers at more), and it lands only where its motion meets the target."""
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
    """Whether the next state is certified whatever the wind does, for an action judged from ``t`` that does not
    pass (an action that passes keeps): where its period keeps ``C1`` and the budget (``kept``), ending in
    ``[end_lo, end_hi]`` with at least ``z_end`` left, before the horizon, and some candidate passes or surely
    lands from that whole end box."""
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
