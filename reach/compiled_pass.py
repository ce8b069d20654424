"""The filter's first question, compiled: does holding the policy's action for one period end in the cells?

Most of a filter's decisions are the policy's action passing (:class:`~softreach.filters.ValueFilter`), and for a
filter with landing cells (:mod:`softreach.reach.cell_certificate`) an action passes the one-period test
(:meth:`~softreach.reach.lookahead.Lookahead.assess`) when

* the period's motion stays in ``C1``: ``max c1 <= 0`` over the tube box, which is bounded;
* the budget bound ``z' = z - sum_j (dt / P) max h_eps`` over the ``P`` pieces of the period is ``>= 0``;
* ``t + dt <= T``, and the end box lies in safe and landing cells at budget ``z'``,

or when its period surely lands (which only rows failing the above are asked). This module answers the first
test for every row in one compiled loop, with the worst next certificate of the passing rows and the certificate
at every state; :meth:`ValueFilter.filter` sends the rows it does not pass to the numpy test, which asks the rest.
It is the same test on the same numbers: the enclosure is the model's own compiled one (its numpy enclosure is
built on it), the set functions are box distances whose maximum over a box is taken at its corners, and the
cells and the table are read by the same kernels (:mod:`softreach.reach.kernels`); ``tests/test_compiled_pass.py``
checks that the answers are equal.

It applies where the model provides :attr:`~softreach.reach.dynamics.Dynamics.held_box_kernel` and declares
:attr:`~softreach.reach.problem.Model.set_boxes`, the table holds ``W_eps`` and the filter has landing cells.
"""

from __future__ import annotations

import math
from typing import Any

import numba as nb
import numpy as np

from .kernels import MAX_NODES, box_max_row, box_scratch, certificate_row, cover_row


@nb.njit(cache=True)
def box_excess(box_lo, box_hi, lo, hi):
    """The largest value of the box distance :func:`~softreach.reach.sets.box` of ``[box_lo, box_hi]`` over the
    box ``[lo, hi]``: per axis the larger of ``box_lo - lo`` and ``hi - box_hi`` (the corners' terms), the largest
    over the axes; an infinite bound has no term."""
    out = -np.inf
    for a in range(len(lo)):
        if box_lo[a] != -np.inf:
            term = max(box_lo[a] - lo[a], hi[a] - box_hi[a]) if box_hi[a] != np.inf else box_lo[a] - lo[a]
        elif box_hi[a] != np.inf:
            term = hi[a] - box_hi[a]
        else:
            continue
        out = max(out, term)
    return out


@nb.njit(cache=True)
def pass_rows(enclose, params, edges, eps, horizon, hard, soft, safe, has_safe, land, W, z_top, z_floor, V, has_V,
              t, x, z, a, ok, nxt, value):
    """Per row: whether holding ``a`` one period passes by its end box (the module docstring), its worst next
    certificate (``+inf`` where it does not pass) and the certificate at the state."""
    N, n = x.shape
    P = len(edges) - 1
    dt = edges[P]
    tube_lo, tube_hi, lo, hi = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    box_lo, box_hi, point = np.empty(n + 1), np.empty(n + 1), np.empty(n + 1)
    scratch_W, scratch_V = box_scratch(n + 1, MAX_NODES), box_scratch(n, MAX_NODES)
    for r in range(N):
        xr = x[r]
        value[r] = certificate_row(W, z_top, z_floor, V, has_V, t[r], xr, z[r], point, scratch_W, scratch_V)
        nxt[r] = np.inf
        ok[r] = False
        enclose(params, xr, xr, a[r], edges[0], dt, tube_lo, tube_hi)
        bounded = True
        for i in range(n):
            bounded = bounded and math.isfinite(tube_lo[i]) and math.isfinite(tube_hi[i])
        t_next = t[r] + dt
        if not (bounded and box_excess(hard[0], hard[1], tube_lo, tube_hi) <= 0
                and t_next <= horizon + 1e-9 * max(1.0, horizon)):
            continue
        spent = 0.0
        for j in range(P):
            enclose(params, xr, xr, a[r], edges[j], edges[j + 1], lo, hi)
            spent += (dt / P) * min(max(box_excess(soft[0], soft[1], lo, hi) / eps, 0.0), 1.0)
        z_end = z[r] - spent
        t_next = min(t_next, horizon)
        enclose(params, xr, xr, a[r], dt, dt, lo, hi)
        if not (z_end >= 0 and (not has_safe or cover_row(safe, t_next, lo, hi, z_end))
                and cover_row(land, t_next, lo, hi, z_end)):
            continue
        ok[r] = True
        # the worst certificate over the end box and the budgets [z', z] it may hold
        z_lo = max(z_end, z_floor)
        for i in range(n):
            box_lo[i], box_hi[i] = lo[i], hi[i]
        box_lo[n], box_hi[n] = z_lo, max(min(z[r], z_top), z_lo)
        best = box_max_row(W, t_next, box_lo, box_hi, MAX_NODES, scratch_W)
        if has_V:
            v = box_max_row(V, t_next, lo, hi, MAX_NODES, scratch_V)
            best = np.nan if math.isnan(v) else min(best, v)
        nxt[r] = np.inf if math.isnan(best) else best


class CompiledPass:
    """:func:`pass_rows` bound to one filter's model, table and cells (build it with :meth:`for_lookahead`)."""

    def __init__(self, lookahead: Any):
        la, model = lookahead, lookahead.model
        self.lookahead = la
        boxes = model.set_boxes

        def box(name: str) -> tuple[np.ndarray, np.ndarray]:
            return tuple(np.asarray(b, dtype=np.float64) for b in boxes[name])

        self.hard, self.soft = box("hard_constraint"), box("soft_constraint")
        self.edges = np.linspace(0.0, la.dt, la.pieces + 1)

    @staticmethod
    def for_lookahead(lookahead: Any) -> "CompiledPass | None":
        """The compiled test for this look-ahead, or ``None`` where it does not apply (the module docstring)."""
        la, model = lookahead, lookahead.model
        boxes = model.set_boxes or {}
        if (model.held_box_kernel is None or not {"hard_constraint", "soft_constraint"} <= set(boxes)
                or la.budget_field != "W_eps" or la.landing_cells is None):
            return None
        return CompiledPass(la)

    def __call__(self, t: np.ndarray, x: np.ndarray, z: np.ndarray, a: np.ndarray):
        """``(passes, next_value, value)`` per row: ``(N,)`` times, ``(N, n)`` states, budgets, ``(N, m)`` physical
        held actions."""
        la, N = self.lookahead, len(x)
        ok, nxt, value = np.empty(N, bool), np.empty(N), np.empty(N)
        safe = la.safe_cells
        pass_rows(la.model.held_box_kernel, la.model.held_box_params, self.edges, la.eps, la.horizon, self.hard,
                  self.soft, (safe or la.landing_cells).kernel_args, safe is not None, la.landing_cells.kernel_args,
                  *la.table_args, t, x, z, a, ok, nxt, value)
        return ok, nxt, value
