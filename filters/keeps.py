"""Whether a held action keeps the next state certified, compiled: the rule's "some candidate passes again from
every possible next state" (docs/filters.md, "The filter with cells").

For the policy's own action, where no single candidate passes from the whole end box, the end box may be covered by
consecutive slabs along the first state axis, each with a candidate that passes from the whole slab (or lying in the
landing cells itself): every end state lies in some slab, from which that slab's candidate passes, so the next state
is certified. The slabs are found greedily from the box's lower edge, each as long as a bisection finds."""

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import cover_row
from softreach.reach.proof.model_kernels import call_held_box
from softreach.reach.proof.period import meets_target, period, widen

from .judge import judge_once

#: bisection steps per candidate for a slab's upper edge, and the most slabs an end box is covered by
SLAB_STEPS = 8
MAX_SLABS = 4


@njit(inline="always")
def _may_pass(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """Whether :func:`~softreach.filters.judge.judge` may find that ``a`` passes or surely lands, a cheaper test asked
    first: the landing cells cover its end box at ``z``, at least the budget left (a cell that covers at some budget
    covers at more), or its motion meets the target."""
    dt = period(M)
    call_held_box(enclose, M.params, x_lo, x_hi, a, dt, dt, end_lo, end_hi)
    widen(end_lo, end_hi, M.slack)
    if cover_row(C.land, min(t + dt, M.horizon), end_lo, end_hi, z):
        return True
    call_held_box(enclose, M.params, x_lo, x_hi, a, M.edges[0], dt, work.tube_lo, work.tube_hi)
    return meets_target(M, work.tube_lo, work.tube_hi)


@njit(_nrt=False)
def _passes(enclose, M, C, cands, j, t, x_lo, x_hi, z, e_lo, e_hi, work):
    """Whether candidate ``j`` passes or surely lands from the whole box ``[x_lo, x_hi]`` at ``t`` with ``z`` left;
    ``j = -1``: whether the box itself lies in the landing cells at ``t``, where the state is certified by its cell."""
    if j < 0:
        return cover_row(C.land, min(t, M.horizon), x_lo, x_hi, z)
    a = cands[j]
    if not _may_pass(enclose, M, C, t, x_lo, x_hi, z, a, e_lo, e_hi, work):
        return False
    v = judge_once(enclose, M, C, t, x_lo, x_hi, z, a, e_lo, e_hi, work)
    return v.ok or v.lands


@njit(_nrt=False)
def _covers(enclose, M, C, cands, t, end_lo, end_hi, z, work, e_lo, e_hi, s_lo, s_hi):
    """Whether at most :data:`MAX_SLABS` slabs ``[cur, s] x`` (the end box's other axes), consecutive along axis 0 from
    ``end_lo[0]`` to ``end_hi[0]``, each pass by one candidate (or lie in the landing cells), each upper edge the
    largest any candidate's bisection of :data:`SLAB_STEPS` steps finds; a slab :func:`_passes` does not judge to pass
    is never used. Asked only where no candidate passes from the whole box, which the first slab skips."""
    n = len(end_lo)
    J = cands.shape[0]
    top = end_hi[0]
    # a cheap rejection first: from each of the box's two corners, some candidate passes (or it lies in the cells)
    for corner in range(2):
        for i in range(n):
            s_lo[i] = end_lo[i] if corner == 0 else end_hi[i]
            s_hi[i] = s_lo[i]
        for j in range(-1, J):
            if _passes(enclose, M, C, cands, j, t, s_lo, s_hi, z, e_lo, e_hi, work):
                break
        else:
            return False
    for i in range(n):
        s_lo[i], s_hi[i] = end_lo[i], end_hi[i]
    cur = end_lo[0]
    for slab in range(MAX_SLABS):
        best = cur
        for j in range(-1, J):
            # one that does not pass from [cur, best] (from the face at cur where best = cur) cannot do better
            s_lo[0], s_hi[0] = cur, best
            if not _passes(enclose, M, C, cands, j, t, s_lo, s_hi, z, e_lo, e_hi, work):
                continue
            # the whole rest, known to fail for the first slab (the box itself)
            if slab > 0:
                s_hi[0] = top
                if _passes(enclose, M, C, cands, j, t, s_lo, s_hi, z, e_lo, e_hi, work):
                    return True
            good, bad = best, top
            for _ in range(SLAB_STEPS):
                mid = 0.5 * (good + bad)
                s_hi[0] = mid
                if _passes(enclose, M, C, cands, j, t, s_lo, s_hi, z, e_lo, e_hi, work):
                    good = mid
                else:
                    bad = mid
            # good is best or a judged upper edge
            best = max(best, good)
        if not best > cur:
            return False
        cur = best
    return False


@njit(_nrt=False)
def keeps(enclose, M, C, cands, t, end_lo, end_hi, z_end, kept, work, work_box, slab_box, slabs):
    """Whether the next state of an action that does not pass is certified whatever the wind does: its period keeps
    ``C1`` and the budget (``kept``) before the horizon, and some candidate passes or surely lands from the whole end
    box ``[end_lo, end_hi]`` with ``z_end`` left, or, where ``slabs`` (the policy's own action), from each of
    consecutive slabs covering it (:func:`_covers`)."""
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
    return slabs and _covers(enclose, M, C, cands, t + dt, end_lo, end_hi, z_lo, work, e_lo, e_hi, slab_box.lo,
                             slab_box.hi)


__all__ = ["keeps"]
