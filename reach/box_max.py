"""The exact maximum of a table's interpolant over boxes of states: the safety filter's one-period test
(:mod:`softreach.reach.lookahead`) bounds the certificate over where holding an action can go."""

from __future__ import annotations

import numpy as np

from .grid import Grid
from .interpolation import interpolate, snapshot_pair


def box_max(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, lo: np.ndarray,
            hi: np.ndarray, max_nodes: int = 3) -> np.ndarray:
    """The exact maximum of the interpolant at time ``t[j]`` over the box ``[lo[j], hi[j]]``, per row.

    At a fixed time the interpolant is multilinear inside each grid cell, so over a box its maximum is reached at a
    corner of one of the sub-boxes that the grid lines cut the box into: the candidates along an axis are the
    box's two ends and the grid nodes strictly between them. Rows whose box holds more than ``max_nodes`` nodes
    along some axis take the largest node value of every cell the box touches instead (an upper bound: inside a
    cell the interpolant is a convex combination of the cell's node values). A box that leaves the grid gets
    ``+inf``.

    :param values: ``(len(times), *grid.shape)``
    :param t: ``(N,)`` query times, inside the table's span
    :param lo: ``(N, d)`` lower corners
    :param hi: ``(N, d)`` upper corners (``>= lo``)
    :param max_nodes: the most grid nodes inside a box, per axis, for the exact (candidate) evaluation
    :return: ``(N,)`` float64
    """
    N, d = lo.shape
    out = np.full(N, -np.inf)
    ok = np.ones(N, bool)
    inside_all = np.ones(N, bool)
    axes = []
    for a in range(d):
        h = grid.spacing[a]
        s_lo = (lo[:, a] - grid.lo[a]) / h
        s_hi = (hi[:, a] - grid.lo[a]) / h
        if not grid.periodic[a]:
            tol = 1e-9 * max(1.0, grid.shape[a])
            inside_all &= (s_lo >= -tol) & (s_hi <= grid.shape[a] - 1 + tol)
        first = np.floor(s_lo).astype(np.int64) + 1  # the first node strictly above lo (or lo itself, once)
        count = np.maximum(np.ceil(s_hi).astype(np.int64) - first, 0)  # nodes strictly inside (lo, hi)
        ok &= count <= max_nodes
        axes.append((first, count))
    ok &= inside_all
    counts = np.stack([c for _, c in axes], axis=1)  # (N, d)
    rows = np.nonzero(ok)[0]
    if len(rows):
        # rows with the same number of inner nodes per axis share one block shape: evaluate them together
        key = counts[rows] @ (max_nodes + 1) ** np.arange(d)
        for g in np.unique(key):
            sel = rows[key == g]
            cnt = counts[sel[0]]
            out[sel] = _points_max(values, times, grid, t[sel], lo[sel], hi[sel], [f[sel] for f, _ in axes], cnt + 2)
    out[~inside_all] = np.inf
    wide = np.nonzero(~ok & inside_all)[0]
    if len(wide):
        out[wide] = _cells_max(values, times, grid, t[wide], lo[wide], hi[wide])
    return out


def _points_max(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                first: list[np.ndarray], L: np.ndarray) -> np.ndarray:
    """:func:`box_max` for boxes that hold ``L[a] - 2`` grid nodes along each axis ``a``: the interpolant at every
    corner of every sub-box (along each axis the box's ends and its inner nodes), in one call of the one
    interpolation engine, and the largest per box."""
    R, d = lo.shape
    coords = []
    for a in range(d):
        inner = grid.lo[a] + grid.spacing[a] * (first[a][:, None] + np.arange(int(L[a]) - 2)[None, :])
        coords.append(np.concatenate([lo[:, a:a + 1], inner, hi[:, a:a + 1]], axis=1))
    mesh = np.meshgrid(*[np.arange(int(n)) for n in L], indexing="ij")
    P = mesh[0].size
    pts = np.stack([coords[a][:, mesh[a].ravel()] for a in range(d)], axis=-1)
    v, _ = interpolate(values, times, grid, np.repeat(t, P), pts.reshape(R * P, d))
    return v.reshape(R, P).max(axis=1)


def _cells_max(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, lo: np.ndarray,
               hi: np.ndarray, chunk: int = 1 << 21) -> np.ndarray:
    """The largest node value of every cell each box touches, at both snapshots around ``t``: :func:`box_max`'s
    bound for wide boxes. Rows are padded to the widest box of their chunk (the padding masked out), and chunked so
    that a chunk gathers at most ``chunk`` values."""
    R, d = lo.shape
    n_t = len(times)
    flat = values.reshape(n_t, -1) if isinstance(values, np.ndarray) else values
    if isinstance(flat, np.memmap):
        flat = flat.view(np.ndarray)
    strides = [int(np.prod(grid.shape[a + 1:])) for a in range(d)]
    first, count = np.zeros((R, d), np.int64), np.zeros((R, d), np.int64)
    for a in range(d):
        h, n = grid.spacing[a], grid.shape[a]
        i0 = np.floor((lo[:, a] - grid.lo[a]) / h).astype(np.int64)
        i1 = np.ceil((hi[:, a] - grid.lo[a]) / h).astype(np.int64)
        if not grid.periodic[a]:
            i0, i1 = np.maximum(i0, 0), np.minimum(i1, n - 1)
        first[:, a], count[:, a] = i0, np.minimum(i1 - i0 + 1, n)
    k, wt, _, _ = snapshot_pair(np.asarray(times, dtype=np.float64), t)
    k_next = np.where(wt > 0, np.minimum(k + 1, n_t - 1), k)
    out = np.empty(R)
    order = np.argsort(count.prod(axis=1), kind="stable")
    start = 0
    while start < R:
        # as many rows as fit, padded to the widest of them (rows sorted by size, so padding stays small)
        widest = np.maximum.accumulate(count[order[start:]], axis=0).prod(axis=1)
        gathered = widest * np.arange(1, R - start + 1)
        stop = start + max(1, int(np.searchsorted(gathered, chunk, side="right")))
        sel = order[start:stop]
        L = count[sel].max(axis=0)
        lin = np.zeros((len(sel),) + (1,) * d, np.int64)
        valid = np.ones((len(sel),) + (1,) * d, bool)
        for a in range(d):
            offs = np.arange(L[a])
            nodes = first[sel, a][:, None] + offs[None, :]
            nodes = nodes % grid.shape[a] if grid.periodic[a] else np.minimum(nodes, grid.shape[a] - 1)
            shape = [len(sel)] + [1] * d
            shape[1 + a] = int(L[a])
            lin = lin + (nodes * strides[a]).reshape(shape)
            valid = valid & (offs[None, :] < count[sel, a][:, None]).reshape(shape)
        idx = lin.reshape(len(sel), -1)
        mask = np.broadcast_to(valid, lin.shape).reshape(len(sel), -1)
        both = np.maximum(flat[k[sel][:, None], idx], flat[k_next[sel][:, None], idx])
        out[sel] = np.where(mask, both, -np.inf).max(axis=1)
        start = stop
    return out
