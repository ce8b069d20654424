"""The last periods before the horizon, judged by a witness instead of the table.

Near the horizon the certificate is a short game against the terminal value, and its interpolant between nodes
can promise a landing that no held action delivers: the target's edge (``y = 0.7`` for the point mass) runs
between a node that lands in time and one that cannot. A policy that hovers just above the target is then let
through until no action can land any more. So an end box at one of the last ``window`` sample times before the
horizon is certified only by a **witness**: a sequence of held candidates that, applied to every state of the
box at once (the model's box enclosure), keeps ``C1`` and the budget in every period and ends landed inside a
period or, at the horizon, inside the terminal value's certificate (convex, so its interpolant is sound). The
candidates are chosen greedily, lowest table value of their end box first: the table guides, the enclosures
decide. A witness proves the box certified; its absence says "not certified", which is conservative.

A witness's first action passes from the state reached, and its end box carries the rest; the next decision
searches again from that state's own end box and may choose differently (nothing remembers the witness), so this
makes the chain hold in practice, not by proof. Before the window the table's certificate decides.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def witness_lands(la: Any, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, z_lo: np.ndarray,
                  z_hi: np.ndarray) -> np.ndarray:
    """Does a greedy witness (module docstring) land from every state of each box ``[lo, hi] x [z_lo, z_hi]``
    at time ``t``?

    :param la: the :class:`~softreach.reach.proof.lookahead.Lookahead` (its model, candidates, table and horizon)
    :return: ``(N,)`` bool
    """
    N, J = len(lo), len(la.candidates)
    won = np.zeros(N, bool)
    rows = np.arange(N)
    t, lo, hi = np.asarray(t, float).copy(), lo.copy(), hi.copy()
    z_lo, z_hi = np.maximum(z_lo, 0.0), z_hi.copy()
    tol = 1e-9 * max(1.0, la.horizon)
    while len(rows):
        tt, xl, zl, xh, zh, a = la._each_candidate(t, lo, z_lo, hi, z_hi)
        passing, nxt, _, end_lo, end_hi, z_end, kept = la.assess(tt, xl, zl, a, x_hi=xh, z_hi=zh, ends=True,
                                                                 exact=False)
        passing, nxt, kept = (v.reshape(len(rows), J) for v in (passing, nxt, kept))
        last = t + la.dt >= la.horizon - tol
        # at the horizon only the terminal certificate counts (passing); before it, any period that keeps C1
        # and the budget may continue, the table's value ranking the choices
        usable = np.where(last[:, None], passing, kept | passing)
        landed = (passing & (nxt == -np.inf)).any(axis=1) | (last & passing.any(axis=1))
        won[rows[landed]] = True
        go = ~landed & usable.any(axis=1)
        if not go.any():
            break
        score = np.where(usable, np.nan_to_num(nxt, nan=np.inf, posinf=1e12), np.inf)
        j = np.argmin(score, axis=1)
        pick = np.nonzero(go)[0]
        flat = pick * J + j[pick]
        rows, t = rows[pick], t[pick] + la.dt
        lo, hi = end_lo[flat], end_hi[flat]
        z_hi, z_lo = z_hi[pick], np.maximum(z_end[flat], 0.0)
    return won


def in_window(la: Any, t: np.ndarray) -> np.ndarray:
    """Sample times ``t`` among the last ``la.exact_periods`` before the horizon (the horizon itself excluded)."""
    return (t < la.horizon - 1e-9) & (t + la.exact_periods * la.dt >= la.horizon - 1e-9 * max(1.0, la.horizon))


def exact_before_horizon(la: Any, t_next: np.ndarray, end_lo: np.ndarray, end_hi: np.ndarray,
                         z_lo: np.ndarray, z_hi: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """``nxt`` (the table's worst value over each end box) with the end boxes in the last ``la.exact_periods``
    sample times before the horizon judged by a witness instead: ``min(nxt, -margin)`` where one lands from the
    whole box, ``max(nxt, tiny)`` (not certified) where none is found. Unchanged without a box enclosure."""
    window = in_window(la, t_next) & np.isfinite(nxt)
    if not (la.box_support and window.any()):
        return nxt
    idx = np.nonzero(window)[0]
    ok = witness_lands(la, t_next[idx], end_lo[idx], end_hi[idx], z_lo[idx], z_hi[idx])
    out = nxt.copy()
    out[idx] = np.where(ok, np.minimum(nxt[idx], -la.margin), np.maximum(nxt[idx], 1e-12))
    return out


__all__ = ["exact_before_horizon", "in_window", "witness_lands"]
