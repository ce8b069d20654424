"""Landing inside a control period: does every run of a held action surely end landed before the period is over?

The environments check ``C1`` and the target at ``target_checks`` equally spaced instants of each period (their
integrator's sub-step ends), and the paper's game ends at the first instant in the target. So a held action also
passes the one-period test (:class:`~softreach.reach.proof.lookahead.Lookahead`) when, for some check instant ``s``:

* the box of the states at ``s`` lies in the target and inside ``C2`` (every corner: the target and ``c2`` are
  convex or monotone along each axis on such boxes),
* the motion over ``[0, s]`` stays in ``C1``,
* and the budget spent until ``s`` is at most ``z``,

each box widened by the allowance for the environment's rounding
(:meth:`~softreach.reach.proof.lookahead.Lookahead.widen`, :meth:`~softreach.reach.proof.lookahead.Lookahead.checked_c1`).

Every run then ends landed at ``s`` at the latest, whatever the wind did. The cells
(:mod:`softreach.reach.proof.cell_certificate`) ask the same of their plans, and the compiled filter mirrors it
(:func:`softreach.filters.judge.judge`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..dynamics import row_time


def meets_target(la: Any, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Rows whose box ``[lo, hi]`` meets the model's :attr:`~softreach.reach.problem.Model.target_box`: a period
    whose whole motion misses it cannot land (``True`` everywhere when the model gives no box).

    :param la: the :class:`~softreach.reach.proof.lookahead.Lookahead` asking
    """
    if la.target_lo is None:
        return np.ones(len(lo), bool)
    return ((hi >= la.target_lo) & (lo <= la.target_hi)).all(axis=1)


def lands_within(la: Any, t: np.ndarray, x: np.ndarray, z: np.ndarray, a: np.ndarray,
                 x_hi: np.ndarray | None, rows: np.ndarray) -> np.ndarray:
    """Rows (among ``rows``) whose every run surely lands at one of the period's check instants (the module
    docstring), staying in ``C1`` and within the budget until then.

    :param la: the :class:`~softreach.reach.proof.lookahead.Lookahead` asking: its model, period, check instants, pieces
    :param t, x, z, a: ``(N,)`` times, ``(N, n)`` states (or boxes' lower corners), ``(N,)`` budgets, ``(N, m)``
        held actions
    :param x_hi: the boxes' upper corners, or ``None`` for states
    :param rows: ``(N,)`` bool, the rows to ask
    :return: ``(N,)`` bool
    """
    out = np.zeros(len(x), bool)
    todo = np.nonzero(rows)[0]
    model = la.model
    for j in range(1, la.target_checks + 1):
        # only rows whose motion over the period comes near the target can land; cheap rows first
        if len(todo) == 0:
            break
        s = la.dt * j / la.target_checks
        tr = t[todo]
        lo = x[todo]
        hi = lo if x_hi is None else x_hi[todo]
        if x_hi is None:
            (tube_lo, tube_hi, end_lo, end_hi), good = la._enclose(tr, lo, a[todo], s)
        else:
            tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure_box(row_time(tr), lo, hi, a[todo], s)
            good = np.isfinite(tube_lo).all(axis=1) & np.isfinite(tube_hi).all(axis=1)
        ts = tr + s
        # the environment's states, with its rounding (Lookahead.widen, checked_c1), are what must have landed
        end_lo, end_hi = la.widen(end_lo, end_hi)
        good &= la._corner_max(model.target, ts, end_lo, end_hi) <= 0
        good &= la._corner_max(model.soft_constraint, ts, end_lo, end_hi) <= 0
        good &= la.checked_c1(tr, lo, hi, a[todo], s, tube_lo, tube_hi) <= 0
        idx = np.nonzero(good)[0]
        if len(idx):
            if x_hi is None:
                piece_lo, piece_hi = model.held_tube_pieces(row_time(tr[idx]), lo[idx], a[todo][idx], s, la.pieces)
            else:
                piece_lo, piece_hi = model.held_tube_pieces_box(row_time(tr[idx]), lo[idx], hi[idx], a[todo][idx],
                                                                s, la.pieces)
            spent = la._budget_spent(tr[idx], *la.widen(piece_lo, piece_hi), s)
            spent = np.where(la.may_spend(tr[idx], lo[idx], hi[idx], a[todo][idx], s, tube_lo[idx], tube_hi[idx]),
                             spent, 0.0)
            done = idx[z[todo][idx] - spent >= 0]
            out[todo[done]] = True
            todo = np.delete(todo, done)
    return out
