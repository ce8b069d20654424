"""Whether states are certified, compiled: what :meth:`~softreach.filters.ValueFilter.certify` needs of each row
(the best candidate, whether it passes and its next table value; the value at the state, whether the state lies on
the table and in a landing cell), by the decision's own parts (:mod:`softreach.filters.judge`), in the same arithmetic.
"""

from __future__ import annotations

import numpy as np

from softreach.reach.jit import njit
from softreach.reach.proof.kernels import certificate_row, cover_row
from softreach.reach.proof.period import Motion
from softreach.reach.proof.ranks import LOWEST_BAD

from .compiled_args import Cells, TableArgs, packed_space
from .judge import badness, judge_once, next_value, on_table


@njit(nogil=True, _nrt=False)
def certify_rows(enclose, m_args, c_args, t_args, cands, t, x, z, ok, nxt, value, inside, in_cells, space_args):
    """Per row: ``ok`` and ``nxt`` of the best candidate, ``value`` the certificate at the state, ``inside`` on the
    table (at the budget ``max(z, 0)``), ``in_cells`` in a landing cell; arguments as
    :func:`~softreach.filters.compiled.decide_rows` takes them."""
    M, C, T = Motion(*m_args), Cells(*c_args), TableArgs(*t_args)
    space = packed_space(space_args)
    N = x.shape[0]
    J = cands.shape[0]
    work, end_lo, end_hi, point = space.work, space.end_lo, space.end_hi, space.point
    c_ok, c_next, c_bad, c_zend, c_kept = space.c_ok, space.c_next, space.c_bad, space.c_zend, space.c_kept
    c_score, c_in, c_bounded, c_proven, c_c1 = space.c_score, space.c_in, space.c_bounded, space.c_proven, space.c_c1
    for r in range(N):
        tr, xr, zr = t[r], x[r], z[r]
        value[r] = certificate_row(T.W, T.z_top, T.z_floor, T.z_left, T.V, T.has_V, tr, xr, zr, point,
                                   work.scratch_W, work.scratch_V)
        t_next = tr
        least, best = np.inf, -1
        for j in range(J):
            v = judge_once(enclose, M, C, tr, xr, xr, zr, cands[j], end_lo[j], end_hi[j], work)
            c_bounded[j], c_in[j], c_proven[j], c_c1[j], c_zend[j], t_next = (v.bounded, v.in_c1, v.proven, v.c1,
                                                                               v.z_end, v.t_next)
            c_ok[j], c_kept[j] = v.ok or v.lands, v.kept or v.lands
            # a passing candidate's badness is its next value (-inf: it surely lands)
            c_next[j] = -np.inf if v.lands else np.inf
            if v.ok and not v.lands:
                c_next[j] = next_value(T, t_next, end_lo[j], end_hi[j], c_zend[j], zr, work)
            c_score[j] = c_next[j]
            # the first of the least, as np.argmin
            if c_ok[j] and (best < 0 or c_next[j] < least):
                least, best = c_next[j], j
        if best < 0 or not least < LOWEST_BAD:
            # the badness decides (np.int64, np.bool_: bare literals would compile badness once more)
            badness(T, t_next, end_lo, end_hi, zr, work, c_ok, c_in, c_bounded, c_proven, c_kept, c_c1, c_zend,
                    np.int64(-1), np.bool_(True), c_bad, c_score, space.c_low, space.c_tie)
            best = np.argmin(c_score)
        # a failing candidate's next value certifies nothing
        ok[r], nxt[r] = c_ok[best], c_next[best]
        inside[r] = on_table(T.inside, tr, xr, max(zr, 0.0), point, work.scratch_W)
        in_cells[r] = cover_row(C.land, tr, xr, xr, zr)
