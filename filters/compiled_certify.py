"""Whether states are certified, compiled: the numbers :meth:`~softreach.filters.ValueFilter.certify` needs of
each row, by the decision's own parts (:mod:`softreach.filters.judge`) in the same arithmetic:

* :meth:`~softreach.reach.lookahead.Lookahead.best_candidate`: the candidate of least badness (a passing one by its
  worst next certificate, else the least bad), whether it passes, and its next certificate (``+inf`` where it
  does not);
* the certificate at the state, whether the state lies on the table and whether a landing cell holds it.

``tests/test_compiled_filter.py`` compares :meth:`ValueFilter.certify` with its numpy path row by row.
"""

from __future__ import annotations

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.kernels import certificate_row, cover_row

from .judge import LOWEST_BAD, badness, judge_once, next_value, on_table


@njit(nogil=True, _nrt=False)
def certify_rows(enclose, M, C, T, cands, t, x, z, ok, nxt, value, inside, in_cells, space):
    """Per row: ``ok`` and ``nxt`` of the best candidate, ``value`` the certificate at the state, ``inside`` on the
    table (at the budget ``max(z, 0)``), ``in_cells`` in a landing cell; in the work space ``space``
    (:func:`~softreach.filters.compiled.decision_space`). Every passing candidate's next value is read: the
    least of them decides unless it lies above every failing one's badness, which is then read where it can decide
    (:func:`~softreach.filters.judge.badness`)."""
    N = x.shape[0]
    J = cands.shape[0]
    W, z_top, z_floor, V, has_V = T[0], T[1], T[2], T[3], T[4]
    work, end_lo, end_hi, c_ok, c_next, c_bad, c_zend, c_kept, c_score = (space[0], space[2], space[3], space[4],
                                                                           space[5], space[6], space[7], space[8],
                                                                           space[9])
    point, c_in, c_bounded, c_proven, c_c1, c_low, c_tie = (space[13], space[14], space[15], space[16], space[17],
                                                           space[19], space[20])
    for r in range(N):
        tr, xr, zr = t[r], x[r], z[r]
        value[r] = certificate_row(W, z_top, z_floor, V, has_V, tr, xr, zr, point, work[6], work[7])
        t_next = tr
        least, best = np.inf, -1
        for j in range(J):
            a_ok, a_lands, c_bounded[j], c_in[j], a_kept, c_proven[j], c_c1[j], c_zend[j], t_next = judge_once(
                enclose, M, C, tr, xr, xr, zr, cands[j], end_lo[j], end_hi[j], work)
            c_ok[j], c_kept[j] = a_ok or a_lands, a_kept or a_lands
            # a passing candidate's badness is its next value (-inf: it surely lands)
            c_next[j] = -np.inf if a_lands else (next_value(T, t_next, end_lo[j], end_hi[j], c_zend[j], zr, work)
                                                 if a_ok else np.inf)
            c_score[j] = c_next[j]
            # the first of the least, as np.argmin
            if c_ok[j] and (best < 0 or c_next[j] < least):
                least, best = c_next[j], j
        if best < 0 or not least < LOWEST_BAD:
            # no passing candidate is below every failing one's badness: the badness decides
            # (np.int64, np.bool_: bare literals would compile badness once more, for their literal types)
            badness(T, t_next, end_lo, end_hi, zr, work, c_ok, c_in, c_bounded, c_proven, c_kept, c_c1, c_zend,
                    np.int64(-1), np.bool_(True), c_bad, c_score, c_low, c_tie)
            best = np.argmin(c_score)
        # a failing candidate's next value is +inf (Lookahead.assess): none of its end states is certified
        ok[r], nxt[r] = c_ok[best], c_next[best]
        inside[r] = on_table(W, tr, xr, max(zr, 0.0), point, work)
        in_cells[r] = cover_row(C[2], tr, xr, xr, zr)
