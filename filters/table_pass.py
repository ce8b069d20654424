"""Whether a held action keeps the next state certified, compiled: from the landing cells where the filter has
them, else from the table (the one-period test's item 3, ``docs/filters.md``): every possible end state inside the
certificate, the table's worst value over the end box at most ``-margin``, and in the last
:attr:`~softreach.filters.compiled_args.Motion.exact_periods` sample times before the horizon a witness instead
(:func:`witness`). :func:`~softreach.filters.judge.judge` decides everything else and reads
no table; :func:`table_verdict` adds the table's part where there are no landing cells; :func:`keeps` is the rule's
"one candidate passes again from every possible next state"."""

from __future__ import annotations

import math

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import cover_row
from softreach.reach.proof.model_kernels import call_held_box
from softreach.reach.proof.ranks import TIE_INF

from .judge import _lands, _widen, judge, meets_target, next_value, period


@njit(inline="always")
def in_window(M, t):
    """Whether the sample time ``t`` is one of the last ``exact_periods`` before the horizon (the horizon itself
    excluded): its end boxes are judged by a witness (:func:`witness`)."""
    horizon = M.horizon
    return t < horizon - 1e-9 and t + M.exact_periods * period(M) >= horizon - 1e-9 * max(1.0, horizon)


@njit(inline="always")
def _table_next(T, in_c1, t_next, end_lo, end_hi, z_end, z_hi, work):
    """The table's worst value over the end box and the budgets ``[z_end, z_hi]`` where the motion keeps ``C1``;
    ``+inf`` elsewhere."""
    return next_value(T, t_next, end_lo, end_hi, z_end, z_hi, work) if in_c1 else np.inf


@njit(inline="always")
def _finish(enclose, M, t, x_lo, x_hi, z, a, v, nxt, meets, work):
    """``(passes, lands, next value)`` of an action judged without landing cells (``v``, its
    :class:`~softreach.filters.compiled_args.Verdict`; ``nxt`` the table's value over its end box): it passes where
    its period keeps ``C1`` and the budget and ``nxt <= -margin``; else where it surely lands (then ``-inf``). The
    next value is that of a period that keeps, ``+inf`` where it does not."""
    passes = v.kept and nxt <= -M.margin
    lands = v.lands
    if not passes and not lands and v.kept and v.bounded and meets:
        n = len(x_lo)
        lands = _lands(enclose, M, x_lo, x_hi, z, a, M.check_edges, work.lo, work.hi, work.box_lo[:n],
                       work.box_hi[:n])
    if lands:
        return True, True, -np.inf
    return passes, False, (nxt if v.kept else np.inf)


@njit(_nrt=False)
def witness(enclose, M, C, T, cands, t, lo, hi, z_lo, z_hi, work, space):
    """Does a greedy witness land from every state of the box ``[lo, hi] x [z_lo, z_hi]`` at ``t``
    (``docs/filters.md``, "The last periods before the horizon"): candidates held period after period from the box of
    every state the periods before may have reached, each chosen by the lowest table value of its end box among
    those that keep ``C1`` and the budget, until one surely lands or, at the horizon, ends inside the terminal
    certificate. ``space``: the decision's work space (its ``w_box``, ``w_lo``, ``w_hi``)."""
    J, n = cands.shape[0], len(lo)
    cur_lo, cur_hi, w_lo, w_hi = space.w_box.lo, space.w_box.hi, space.w_lo, space.w_hi
    for i in range(n):
        cur_lo[i], cur_hi[i] = lo[i], hi[i]
    z_lo = max(z_lo, 0.0)
    horizon, dt = M.horizon, period(M)
    while True:
        last = t + dt >= horizon - 1e-9 * max(1.0, horizon)
        best, best_score, best_z, any_pass = -1, np.inf, 0.0, False
        for j in range(J):
            v = judge(enclose, M, C, t, cur_lo, cur_hi, z_lo, cands[j], w_lo[j], w_hi[j], work)
            meets = meets_target(M, work.tube_lo, work.tube_hi)
            nxt = _table_next(T, v.in_c1, v.t_next, w_lo[j], w_hi[j], v.z_end, z_hi, work)
            passes, lands, nxt = _finish(enclose, M, t, cur_lo, cur_hi, z_lo, cands[j], v, nxt, meets, work)
            if lands:
                return True
            any_pass = any_pass or passes
            usable = passes if last else (passes or v.kept)
            # a usable candidate whose end box is off the table still ranks before an unusable one
            score = (TIE_INF if nxt == np.inf else (np.inf if math.isnan(nxt) else nxt)) if usable else np.inf
            if usable and (best < 0 or score < best_score):
                best, best_score, best_z = j, score, v.z_end
        if last and any_pass:
            return True
        if best < 0:
            return False
        for i in range(n):
            cur_lo[i], cur_hi[i] = w_lo[best, i], w_hi[best, i]
        t, z_lo = t + dt, max(best_z, 0.0)


@njit(inline="always")
def table_verdict(enclose, M, C, T, cands, t, x_lo, x_hi, z, z_hi, a, v, end_lo, end_hi, work, space):
    """``(passes, lands, next value)`` of the action ``a`` that :func:`~softreach.filters.judge.judge` judged
    (``v``; its end box in ``end_lo``, ``end_hi``) from ``[x_lo, x_hi]`` at budget ``z``, the table read over the
    budgets up to ``z_hi``: with landing cells the verdict's own (the next value read later, where it can decide);
    without them by the table (:func:`_finish`), an end box in the witness window by a witness."""
    if C.has_land:
        return v.ok or v.lands, v.lands, (-np.inf if v.lands else np.inf)
    meets = meets_target(M, work.tube_lo, work.tube_hi)
    nxt = _table_next(T, v.in_c1, v.t_next, end_lo, end_hi, v.z_end, z_hi, work)
    if math.isfinite(nxt) and in_window(M, v.t_next):
        won = witness(enclose, M, C, T, cands, v.t_next, end_lo, end_hi, v.z_end, z_hi, work, space)
        nxt = min(nxt, -M.margin) if won else max(nxt, 1e-12)
    return _finish(enclose, M, t, x_lo, x_hi, z, a, v, nxt, meets, work)


@njit(_nrt=False)
def keeps(enclose, M, C, T, cands, t, z, ok, nxt, end_lo, end_hi, z_end, kept, work, work_box, space):
    """Whether the next state is certified whatever the wind does. With landing cells a
    row that passes keeps (its end lies in them). Otherwise a row that surely lands, or whose period is the last,
    keeps where it passes; one whose period keeps ``C1`` and the budget keeps when some candidate passes from its
    whole end box, or, without cells, where its end box lies in the witness
    window with a witness (``nxt <= -margin``: the witness's first candidate passes from the whole box)."""
    horizon = M.horizon
    dt = period(M)
    if ok and C.has_land:
        return True
    if not kept or t + dt >= horizon - 1e-9 * max(1.0, horizon) or nxt == -np.inf:
        return ok
    if not C.has_land and in_window(M, t + dt) and nxt <= -M.margin:
        return True
    e_lo, e_hi = work_box.lo, work_box.hi
    z_lo = max(z_end, 0.0)
    for j in range(cands.shape[0]):
        if C.has_land and not _may_pass(enclose, M, C, t + dt, end_lo, end_hi, z_lo, cands[j], e_lo, e_hi, work):
            continue
        v = judge(enclose, M, C, t + dt, end_lo, end_hi, z_lo, cands[j], e_lo, e_hi, work)
        if table_verdict(enclose, M, C, T, cands, t + dt, end_lo, end_hi, z_lo, z, cands[j], v, e_lo, e_hi, work,
                         space)[0]:
            return True
    return False


@njit(inline="always")
def _may_pass(enclose, M, C, t, x_lo, x_hi, z, a, end_lo, end_hi, work):
    """Whether :func:`judge` can find that ``a`` passes or surely lands, asked first as it costs a third of it:
    it passes only where the landing cells cover its end box at the budget left, at most ``z`` (a cell that covers
    at some budget covers at more), and it lands only where its motion meets the target."""
    params, edges, horizon = M.params, M.edges, M.horizon
    dt = period(M)
    call_held_box(enclose, params, x_lo, x_hi, a, dt, dt, end_lo, end_hi)
    _widen(end_lo, end_hi, M.slack)
    if cover_row(C.land, min(t + dt, horizon), end_lo, end_hi, z):
        return True
    call_held_box(enclose, params, x_lo, x_hi, a, edges[0], dt, work.tube_lo, work.tube_hi)
    return meets_target(M, work.tube_lo, work.tube_hi)


__all__ = ["in_window", "keeps", "table_verdict", "witness"]
