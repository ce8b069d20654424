"""Compiled loops behind the safety filter's per-decision mechanisms (numba, one row at a time).

A filter decision asks a few hundred tiny questions of a table and of the cells (the interpolant's maximum over a
box, which cells a box touches); numpy answers each with a dozen calls whose fixed cost dwarfs the arithmetic, so
these loops are compiled instead, and the numpy-facing functions (:func:`softreach.reach.box_max.box_max`,
:meth:`~softreach.reach.cell_certificate.CellCertificate.covered`) call them. Compiled code is cached on disk
(numba's ``cache=True``): the first process on a machine compiles for a few seconds, later ones load it.

Grids are passed as arrays: ``shape`` (int64), ``glo`` and ``ghi`` the first and last node (float64), ``inv_h``
``1 / spacing``, ``periodic`` (bool); a field's values as ``(n_times, size)``, C-ordered.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: tolerance of the grid checks, in cell units (:data:`softreach.reach.interpolation.TOL`)
TOL = 1e-9


@nb.njit(cache=True)
def snapshot(times, t):
    """``(k, wt)``: the snapshot interval ``[times[k], times[k + 1]]`` of ``t`` and the later snapshot's weight,
    clamped to ``[0, 1]`` (:func:`softreach.reach.interpolation.snapshot_pair`)."""
    n_t = len(times)
    if n_t == 1:
        return 0, 0.0
    k = np.searchsorted(times, t, side="right") - 1
    k = min(max(k, 0), n_t - 2)
    t0 = times[k]
    wt = min(max((t - t0) / (times[k + 1] - t0), 0.0), 1.0)
    return k, wt


@nb.njit(cache=True)
def _lattice_max(flat, k, wt, shape, glo, ghi, h, inv_h, periodic, lo, hi, first, count, buf_a, buf_b, coord_cell,
                 coord_frac):
    """The interpolant's largest value on the lattice of a box (along each axis ``a`` its two ends and the
    ``count[a]`` nodes from ``first[a]`` between them), which holds every corner of every sub-box the grid cuts the
    box into. The interpolant is multilinear, so the lattice values are the block of nodes around the box (blended
    between the two snapshots) contracted axis by axis with each coordinate's two linear weights."""
    D = len(shape)
    dims = np.empty(D, np.int64)
    base = np.empty(D, np.int64)
    for a in range(D):
        L = count[a] + 2
        for p in range(L):
            x = lo[a] if p == 0 else (hi[a] if p == L - 1 else glo[a] + h[a] * (first[a] + p - 1))
            if periodic[a]:
                S = ((x - glo[a]) * inv_h[a]) % shape[a]
                low = math.floor(S)
                coord_frac[a, p] = S - low
                coord_cell[a, p] = int(low)
            else:
                S = min((min(max(x, glo[a]), ghi[a]) - glo[a]) * inv_h[a], shape[a] - 1.0)
                coord_cell[a, p] = min(int(S), shape[a] - 2)
                coord_frac[a, p] = S - coord_cell[a, p]
        if periodic[a]:
            # the cells along the lattice, unwrapped: each at least the previous (the box may cross the seam)
            for p in range(1, L):
                while coord_cell[a, p] < coord_cell[a, p - 1]:
                    coord_cell[a, p] += shape[a]
        base[a] = coord_cell[a, 0]
        dims[a] = coord_cell[a, L - 1] + 2 - base[a]
    # the block of nodes, blended in time
    size = 1
    for a in range(D):
        size *= dims[a]
    for q in range(size):
        rest = q
        off = 0
        stride = 1
        for a in range(D - 1, -1, -1):
            i = base[a] + rest % dims[a]
            rest //= dims[a]
            off += (i % shape[a]) * stride
            stride *= shape[a]
        v = flat[k, off]
        buf_a[q] = (1.0 - wt) * v + wt * flat[k + 1, off] if wt > 0.0 else v
    # contract axis by axis: each lattice coordinate reads its cell's two nodes
    src, dst = buf_a, buf_b
    for a in range(D):
        outer = 1
        for b in range(a):
            outer *= count[b] + 2
        inner = 1
        for b in range(a + 1, D):
            inner *= dims[b]
        L = count[a] + 2
        n_a = dims[a]
        for o in range(outer):
            for p in range(L):
                j = coord_cell[a, p] - base[a]
                f = coord_frac[a, p]
                s0 = (o * n_a + j) * inner
                d0 = (o * L + p) * inner
                for i in range(inner):
                    dst[d0 + i] = (1.0 - f) * src[s0 + i] + f * src[s0 + inner + i]
        src, dst = dst, src
    total = 1
    for a in range(D):
        total *= count[a] + 2
    best = -np.inf
    for q in range(total):
        v = src[q]
        if math.isnan(v):
            return v
        if v > best:
            best = v
    return best


@nb.njit(cache=True)
def box_max_rows(flat, times, shape, glo, ghi, h, inv_h, periodic, t, lo, hi, max_nodes, out):
    """:func:`softreach.reach.box_max.box_max` for every row: ``out[j]`` the interpolant's maximum over
    ``[lo[j], hi[j]]`` at ``t[j]`` (exact where the box holds at most ``max_nodes`` nodes along every axis, else the
    largest node value of the cells it touches at both snapshots), ``+inf`` for a box off the grid."""
    N, D = lo.shape
    first = np.empty(D, np.int64)
    count = np.empty(D, np.int64)
    n_t = len(times)
    # scratch: a block of at most max_nodes + 3 nodes per axis, and each axis' lattice coordinates located
    buf_a = np.empty((max_nodes + 3) ** D)
    buf_b = np.empty((max_nodes + 3) ** D)
    coord_cell = np.empty((D, max_nodes + 2), np.int64)
    coord_frac = np.empty((D, max_nodes + 2))
    for r in range(N):
        inside, exact = True, True
        for a in range(D):
            s_lo = (lo[r, a] - glo[a]) / h[a]
            s_hi = (hi[r, a] - glo[a]) / h[a]
            if not periodic[a]:
                tol = TOL * max(1.0, shape[a])
                if not (s_lo >= -tol and s_hi <= shape[a] - 1 + tol):
                    inside = False
            first[a] = math.floor(s_lo) + 1  # the first node strictly above lo (or lo itself, once)
            count[a] = max(math.ceil(s_hi) - first[a], 0)  # nodes strictly inside (lo, hi)
            if count[a] > max_nodes:
                exact = False
        if not inside:
            out[r] = np.inf
            continue
        k, wt = snapshot(times, t[r])
        if exact:
            out[r] = _lattice_max(flat, k, wt, shape, glo, ghi, h, inv_h, periodic, lo[r], hi[r], first, count, buf_a,
                                  buf_b, coord_cell, coord_frac)
            continue
        # wide: the largest node of every cell the box touches, at both snapshots around t
        k2 = min(k + 1, n_t - 1) if wt > 0.0 else k
        P = 1
        for a in range(D):
            i0 = math.floor((lo[r, a] - glo[a]) / h[a])
            i1 = math.ceil((hi[r, a] - glo[a]) / h[a])
            if not periodic[a]:
                i0, i1 = max(i0, 0), min(i1, shape[a] - 1)
            first[a] = i0
            count[a] = min(i1 - i0 + 1, shape[a])
            P *= count[a]
        best = -np.inf
        for p in range(P):
            rest = p
            off = 0
            stride = 1
            for a in range(D - 1, -1, -1):
                node = first[a] + rest % count[a]
                rest //= count[a]
                node = node % shape[a] if periodic[a] else min(node, shape[a] - 1)
                off += node * stride
                stride *= shape[a]
            v = max(flat[k, off], flat[k2, off])
            if math.isnan(flat[k, off]) or math.isnan(flat[k2, off]):
                v = np.nan
            if v > best or math.isnan(v):
                best = v
            if math.isnan(best):
                break
        out[r] = best


@nb.njit(cache=True)
def cells_need(m, shape, clo, chi, width, end_lo, end_hi, k, out_need, out_on):
    """For :meth:`~softreach.reach.cell_certificate.CellCertificate.covered`: per row, the largest lowest-good
    budget index ``m[k[j], c]`` over the cells ``c`` the box ``[end_lo[j], end_hi[j]]`` touches (closed cells; a box
    reaching the grid's upper end exactly touches the last cell only), and whether the box lies on the grid."""
    N, D = end_lo.shape
    first = np.empty(D, np.int64)
    span = np.empty(D, np.int64)
    for r in range(N):
        on = True
        P = 1
        for a in range(D):
            f = math.floor((end_lo[r, a] - clo[a]) / width[a])
            g = math.floor((end_hi[r, a] - clo[a]) / width[a])
            if end_hi[r, a] == chi[a]:
                g = shape[a] - 1.0
            if not (math.isfinite(f) and math.isfinite(g) and f >= 0 and g <= shape[a] - 1):
                on = False
            fi = int(min(max(f, 0.0), shape[a] - 1.0)) if math.isfinite(f) else 0
            gi = int(min(max(g, 0.0), shape[a] - 1.0)) if math.isfinite(g) else 0
            first[a] = fi
            span[a] = max(fi, gi) - fi + 1
            P *= span[a]
        need = -1
        for p in range(P):
            rest = p
            off = 0
            stride = 1
            for a in range(D - 1, -1, -1):
                off += (first[a] + rest % span[a]) * stride
                rest //= span[a]
                stride *= shape[a]
            need = max(need, int(m[k[r], off]))
        out_need[r] = need
        out_on[r] = on
