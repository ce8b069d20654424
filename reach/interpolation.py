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
    strides = np.array([int(np.prod(grid.shape[a + 1:])) for a in range(grid.ndim)], dtype=np.int64)
    time_corners = ((0, 1 - wt), (1, wt)) if n_t > 1 else ((0, 1 - wt),)
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
