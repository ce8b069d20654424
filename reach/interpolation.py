"""Batched multilinear interpolation on a grid, with time as one more axis."""

from __future__ import annotations

import itertools

import numpy as np

from .grid import Grid


def locate(coords: np.ndarray, lo: float, spacing: float, n: int, periodic: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell index, fraction in the cell and an inside flag for each coordinate along one axis."""
    s = (coords - lo) / spacing
    if periodic:
        s = np.mod(s, n)
        i0 = np.floor(s).astype(np.int64)
        return i0 % n, s - i0, np.ones(coords.shape, bool)
    tol = 1e-9 * max(1.0, n)
    inside = (s >= -tol) & (s <= n - 1 + tol)
    s = np.clip(s, 0.0, n - 1)
    i0 = np.minimum(np.floor(s).astype(np.int64), n - 2)
    return i0, s - i0, inside


def interpolate(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Multilinear interpolation of ``values[k, i1, .., id]`` at ``(t[j], x[j])``.

    :param values: array (or memmap) of shape ``(len(times), *grid.shape)``
    :param times: increasing snapshot times
    :param grid: the grid of the spatial axes
    :param t: query times, shape ``(N,)``
    :param x: query points, shape ``(N, d)``
    :return: ``(value, inside)``; ``value`` is float64, meaningful where ``inside``
    """
    n_t = len(times)
    if n_t > 1:
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, n_t - 2)
        wt = (t - times[k]) / (times[k + 1] - times[k])
        inside = (t >= times[0] - 1e-9) & (t <= times[-1] + 1e-9)
        wt = np.clip(wt, 0.0, 1.0)
    else:
        k = np.zeros(t.shape, np.int64)
        wt = np.zeros(t.shape)
        inside = np.isclose(t, times[0])
    idx, frac = [], []
    for a in range(grid.ndim):
        i0, f, ok = locate(x[:, a], grid.lo[a], grid.spacing[a], grid.shape[a], grid.periodic[a])
        idx.append(i0)
        frac.append(f)
        inside &= ok
    out = np.zeros(len(t))
    flat = values.reshape(values.shape[0], -1) if isinstance(values, np.ndarray) else values
    if isinstance(flat, np.memmap):
        flat = flat.view(np.ndarray)  # a memmap's own __getitem__ costs more than the gather itself
    strides = np.array([int(np.prod(grid.shape[a + 1:])) for a in range(grid.ndim)], dtype=np.int64)
    time_corners = ((0, 1 - wt), (1, wt)) if n_t > 1 else ((0, 1 - wt),)
    if n_t > 1 and not np.any(wt):  # queries on a snapshot (the sampled-data filter's): one time layer
        time_corners = ((0, 1 - wt),)
    for corner in itertools.product((0, 1), repeat=grid.ndim):
        w = np.ones(len(t))
        lin = np.zeros(len(t), np.int64)
        for a, c in enumerate(corner):
            j = idx[a] + c
            if grid.periodic[a]:
                j = j % grid.shape[a]
            w = w * (frac[a] if c else 1 - frac[a])
            lin += j * strides[a]
        for dk, wk in time_corners:
            out += (w * wk) * flat[k + dk, lin]
    return out, inside


def box_max(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, lo: np.ndarray,
            hi: np.ndarray) -> np.ndarray:
    """The exact maximum of the interpolant at time ``t[j]`` over the box ``[lo[j], hi[j]]``, per row.

    At a fixed time the interpolant is multilinear inside each grid cell, so over a box its maximum is reached at a
    corner of one of the sub-boxes that the grid lines cut the box into: the candidates along an axis are the
    box's two ends and the grid nodes strictly between them. Rows whose box holds more than one node along some
    axis take the largest node value of every cell the box touches instead (an upper bound: inside a cell the
    interpolant is a convex combination of the cell's node values). A box that leaves the grid gets ``+inf``.

    :param values: ``(len(times), *grid.shape)``
    :param t: ``(N,)`` query times, inside the table's span
    :param lo: ``(N, d)`` lower corners
    :param hi: ``(N, d)`` upper corners (``>= lo``)
    :return: ``(N,)`` float64
    """
    N, d = lo.shape
    out = np.full(N, -np.inf)
    ok = np.ones(N, bool)
    axes = []
    for a in range(d):
        h = grid.spacing[a]
        s_lo = (lo[:, a] - grid.lo[a]) / h
        s_hi = (hi[:, a] - grid.lo[a]) / h
        if grid.periodic[a]:
            inside = np.ones(N, bool)
        else:
            tol = 1e-9 * max(1.0, grid.shape[a])
            inside = (s_lo >= -tol) & (s_hi <= grid.shape[a] - 1 + tol)
        first = np.floor(s_lo).astype(np.int64) + 1  # the first node strictly above lo (or lo itself, once)
        count = np.ceil(s_hi).astype(np.int64) - first  # nodes strictly inside (lo, hi)
        ok &= inside & (count <= 1)
        mid = np.where(count == 1, grid.lo[a] + first * h, lo[:, a])
        axes.append((lo[:, a], mid, hi[:, a], inside, count))
    rows = np.nonzero(ok)[0]
    if len(rows):
        pts = np.stack(np.meshgrid(*[np.arange(3)] * d, indexing="ij"), -1).reshape(-1, d)  # (3^d, d)
        P = len(pts)
        coords = np.empty((len(rows), P, d))
        for a in range(d):
            choice = np.stack([axes[a][0][rows], axes[a][1][rows], axes[a][2][rows]], axis=1)  # (R, 3)
            coords[:, :, a] = choice[:, pts[:, a]]
        v, _ = interpolate(values, times, grid, np.repeat(t[rows], P), coords.reshape(-1, d))
        out[rows] = v.reshape(len(rows), P).max(axis=1)
    for r in np.nonzero(~ok)[0]:
        if not all(ax[3][r] for ax in axes):
            out[r] = np.inf
            continue
        # a wide box: every node of every cell it touches, at both snapshots around t
        sl = []
        for a in range(d):
            h = grid.spacing[a]
            i0 = int(np.floor((lo[r, a] - grid.lo[a]) / h))
            i1 = int(np.ceil((hi[r, a] - grid.lo[a]) / h))
            if grid.periodic[a]:
                sl.append(np.arange(i0, i1 + 1) % grid.shape[a])
            else:
                sl.append(np.arange(max(i0, 0), min(i1, grid.shape[a] - 1) + 1))
        k = int(np.clip(np.searchsorted(times, t[r], side="right") - 1, 0, max(len(times) - 2, 0)))
        ks = [k] if len(times) == 1 else [k, k + 1]
        out[r] = max(float(np.max(np.asarray(values[kk])[np.ix_(*sl)])) for kk in ks)
    return out
