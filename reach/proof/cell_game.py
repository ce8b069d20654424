"""The cell game of :mod:`softreach.reach.proof.cell_certificate` solved backwards from ``T`` (:func:`solve`) by
:func:`backward_step` over plan steps (:func:`plan_steps`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from ..jit import njit
from .blocks import default_threads, run_in_blocks
from .kernels import cell_span
from .model_kernels import ENCLOSE_MIN_ROWS
from .period import motion, period_rows


def cell_boxes(cells: Any, flat: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The lower and upper corners of the cells ``flat`` (flat indices, the last axis fastest; all by default)."""
    if flat is None:
        flat = np.arange(int(np.prod(cells.shape)))
    idx = np.stack(np.unravel_index(np.asarray(flat, dtype=np.int64), cells.shape), axis=-1)
    return cells.lo + idx * cells.width, cells.lo + (idx + 1) * cells.width


def solve(cls: type, lookahead: Any, key: dict[str, Any]) -> Any:
    """The certificate (a ``cls``) of the game ``key`` (:func:`~softreach.reach.proof.cell_certificate.cell_key`)."""
    la, model = lookahead, lookahead.model
    shape, holds, dz, span_cap = tuple(key["shape"]), tuple(key["holds"]), key["dz"], key["span_cap"]
    dt, T, N = la.dt, la.horizon, int(round(la.horizon / la.dt))
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
    blank = np.zeros((1,) + shape, np.int8)
    cells = cls(lo, hi, blank.astype(np.int16), blank, blank, la.candidates, dt, dz, T, key)
    cell_lo, cell_hi = cell_boxes(cells)
    C = len(cell_lo)
    m, action, hold = np.empty((N + 1, C), np.int16), np.full((N + 1, C), -1, np.int8), np.zeros((N + 1, C), np.int8)
    m[N] = cells.never  # no cell is good at T
    plans = None
    K_max = max(holds)
    # a bar on a terminal, nothing in logs (disable=None)
    bar = tqdm(total=N + len(la.candidates), desc=f"{model.name} cells", unit="step", disable=None, leave=False)
    for k in range(N - 1, -1, -1):
        if k + K_max + 1 <= N and all(np.array_equal(m[k + 1], m[k + 1 + d]) for d in range(1, K_max + 1)):
            # the recursion reads the next K_max columns; they agree, so every earlier one is the same
            m[:k + 1], action[:k + 1], hold[:k + 1] = m[k + 1], action[k + 1], hold[k + 1]
            break
        if plans is None:
            plans = all_plan_steps(cells, la, cell_lo, cell_hi, holds, span_cap, bar)
        bar.update(1)
        m[k], action[k], hold[k] = backward_step(cells, plans, m, k, N, C)
    bar.close()
    return cls(lo, hi, *(v.reshape((N + 1,) + shape) for v in (m, action, hold)), la.candidates, dt, dz, T, key)


def all_plan_steps(cells: Any, la: Any, lo: np.ndarray, hi: np.ndarray, holds: tuple, span_cap: int,
                   bar: Any = None) -> list:
    """:func:`plan_steps` of every candidate: ``(j, K, step)`` in the candidates' order."""
    out, bounds = [], motion(la)
    for j, a in enumerate(la.candidates):
        out += [(j, K, g) for K, g in plan_steps(cells, bounds, lo, hi, a, holds, span_cap)]
        if bar is not None:
            bar.update(1)
    return out


def backward_step(cells: Any, plans: list, m: np.ndarray, k: int, N: int, C: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of the recursion: at sample ``k``, from ``m``'s later ones, each cell's least good index and plan."""
    never = cells.never
    best, action, hold = np.full(C, never, np.int64), np.full(C, -1, np.int8), np.zeros(C, np.int8)
    shape = np.asarray(cells.shape, dtype=np.int64)
    for j, K, (rows, spend, first, last, land_rows, land_need) in plans:
        if k + K > N:
            continue
        need = np.empty(len(rows), np.int64)
        m_next = np.ascontiguousarray(m[k + K])
        # the rows are independent and the loop releases the GIL: one block a thread
        run_in_blocks(lambda i, j: plan_needs(m_next, shape, first[i:j], last[i:j], spend[i:j], cells.dz, never,
                                              need[i:j]), len(rows), default_threads(), ENCLOSE_MIN_ROWS)
        # landing inside the plan needs no later cell: its budget index does not change with k
        for r, nd in ((land_rows, land_need), (rows, need)):
            better = nd < best[r]
            r = r[better]
            best[r], action[r], hold[r] = nd[better], j, K
    out = np.minimum(best, never)
    return out, np.where(out < never, action, -1), hold


@njit(nogil=True)
def cell_ranges(shape, clo, width, periodic, wrap, lo, hi, first, last, on):
    """Per row and axis the first and last cell the box ``[lo, hi]`` touches (closed cells, widened by ``wrap`` and
    read modulo the cells along a periodic axis, as the filter's :func:`~softreach.reach.proof.kernels.cell_span`),
    and whether it lies on the grid."""
    for i in range(lo.shape[0]):
        on[i] = True
        for a in range(len(shape)):
            f, g, on_a = cell_span(lo[i, a], hi[i, a], clo[a], width[a], shape[a], periodic[a], wrap[a])
            first[i, a], last[i, a] = f, g
            on[i] = on[i] and on_a


@njit(forceinline=True)
def budget_index(spend, needed, dz, never):
    """The lowest budget index ``j`` with ``j dz - spend >= needed dz``, else (or for a spend not finite) ``never``."""
    if not math.isfinite(spend):
        return never
    j = np.int64(math.ceil(min(spend / dz + needed - 1e-12, float(never))))
    # float guard: the condition itself, not its rearrangement, decides
    if not j * dz - spend >= needed * dz:
        j += 1
    return min(max(j, 0), never)


@njit(nogil=True)
def budget_indices(spend, needed, dz, never, out):
    """:func:`budget_index` of every row."""
    for i in range(len(spend)):
        out[i] = budget_index(spend[i], needed, dz, never)


@njit(nogil=True)
def plan_needs(m_next, shape, first, last, spend, dz, never, out):
    """Per row: the start budget index (:func:`budget_index`) that, after ``spend[i]``, reaches the cells
    ``first[i] .. last[i]`` (inclusive, read modulo ``shape``: :func:`cell_ranges`) at the largest of their indices in
    ``m_next`` (flat, the last axis fastest)."""
    d = len(shape)
    idx = np.empty(d, np.int64)
    for i in range(first.shape[0]):
        for a in range(d):
            idx[a] = first[i, a]
        worst = np.int64(0)
        while True:
            flat = np.int64(0)
            for a in range(d):
                flat = flat * shape[a] + idx[a] % shape[a]
            worst = max(worst, np.int64(m_next[flat]))
            a = d - 1
            while a >= 0 and idx[a] == last[i, a]:
                idx[a] = first[i, a]
                a -= 1
            if a < 0:
                break
            idx[a] += 1
        out[i] = budget_index(spend[i], worst, dz, never)


def plan_steps(cells: Any, bounds: tuple, lo: np.ndarray, hi: np.ndarray, a: np.ndarray, holds: tuple,
               span_cap: int) -> list:
    """Candidate ``a`` held from every cell, each period bounded by :func:`~softreach.reach.proof.period.period_rows`:
    per ``K`` in ``holds``, the rows that keep ``C1`` and end in at most ``span_cap`` grid cells, their spend and end
    cells, and the rows that surely land; the same at every sample, as the compiled bounds take no time."""
    enclose, M = bounds
    C, n = lo.shape
    acts = np.ascontiguousarray(np.broadcast_to(np.asarray(a, dtype=np.float64), (C, len(a))))
    ok, spend, lands = np.ones(C, bool), np.zeros(C), np.zeros(C, bool)
    kept, charge, landed = np.empty(C, bool), np.empty(C), np.empty(C, bool)
    end_lo, end_hi = np.empty((C, n)), np.empty((C, n))
    shape = np.asarray(cells.shape, dtype=np.int64)
    out = []
    for p in range(1, max(holds) + 1):
        # landing needs only the budget spent until the landing instant, at most the plan's bound so far
        ask = ok & ~lands
        args = (np.ascontiguousarray(lo), np.ascontiguousarray(hi), acts, ask, kept, charge, end_lo, end_hi, landed)
        # the rows are independent and the loop releases the GIL: one block a thread
        run_in_blocks(lambda i, j: period_rows(enclose, M, *(v[i:j] for v in args)), C, default_threads(),
                      ENCLOSE_MIN_ROWS)
        ok &= kept
        spend = spend + charge
        lands |= landed
        lo, hi = np.where(ok[:, None], end_lo, lo), np.where(ok[:, None], end_hi, hi)
        if p in holds:
            first, last, on = np.empty((C, n), np.int64), np.empty((C, n), np.int64), np.empty(C, bool)
            cell_ranges(shape, cells.lo, cells.width, cells.periodic, cells.wrap, np.ascontiguousarray(lo),
                        np.ascontiguousarray(hi), first, last, on)
            rows = np.nonzero(ok & on & ((last - first + 1).prod(axis=1) <= span_cap))[0]
            land_rows = np.nonzero(ok & lands)[0]
            land_need = np.empty(len(land_rows), np.int64)
            budget_indices(spend[land_rows], 0, cells.dz, cells.never, land_need)
            out.append((p, (rows, spend[rows], first[rows], last[rows], land_rows, land_need)))
    return out
