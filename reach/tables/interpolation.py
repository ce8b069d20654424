"""Multilinear interpolation of a table's snapshots on a grid, with time as one more axis: the one engine behind
:class:`~softreach.reach.tables.query.Table` (values, gradients, slices), the safety filter's certificate and
:class:`~softreach.reach.tables.field.TableField`.

A query is located once (:meth:`Interpolant.locate`: the cell of each point, clamped to the grid or wrapped along a
periodic axis, and the snapshot interval of its time); the value and the gradient are then read with the same
weights from the ``2^D`` corners of the cell at the two snapshots around the time.

The gradient is the central difference of the interpolant over one spacing, shifted inwards at the grid's edges.
Of a multilinear interpolant that difference is the interpolant (same cell, same weights) of the node-wise
differences ``(W[m + 2] - W[m]) / 2h`` with ``m = clip(j - 1, 0, n - 3)``, the clip being the inward shift: so one
set of weights serves the value and every component, whether each corner's two partners are gathered with it
(``stencil``) or the differences are computed once and stored beside the values (``stacked``).
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right
from functools import lru_cache
from typing import Any, Iterable, NamedTuple

import numpy as np

from ..numerics.grid import Grid

#: tolerance of the time-span and grid checks (in snapshot and cell units)
TOL = 1e-9


class _Geometry:
    """What every look-up on one grid needs, computed once per grid (:func:`geometry`)."""

    def __init__(self, grid: Grid):
        D = grid.ndim
        self.dim = D
        self.shape = np.array(grid.shape, dtype=np.int64)
        self.lo = np.array(grid.lo)
        self.hi = np.array(grid.hi)
        self.h = np.array(grid.spacing)
        self.inv_h = 1.0 / self.h
        self.periodic = np.array(grid.periodic, dtype=bool)
        self.any_periodic = bool(self.periodic.any())
        self.n1 = (self.shape - 1).astype(np.float64)
        self.imax = self.shape - 2
        self.size = int(np.prod(grid.shape))
        self.strides = np.array([int(np.prod(grid.shape[a + 1:])) for a in range(D)], dtype=np.int64)
        pad = TOL * np.maximum(1.0, self.shape) * self.h
        self.ok_lo = np.where(self.periodic, -np.inf, self.lo - pad)
        self.ok_hi = np.where(self.periodic, np.inf, self.hi + pad)
        # corners in itertools.product order: axis 0 is the most significant bit
        self.bits = np.array(list(itertools.product((0, 1), repeat=D)), dtype=np.int64)  # (C, D)
        self.corner_offsets = self.bits @ self.strides
        # central-difference partners of node j along a non-periodic axis: m and m + 2 (the inward shift at the
        # edges), or the two nodes of a two-node axis
        self.m_max = np.maximum(self.shape - 3, 0)
        self.span = np.where(self.periodic, 2.0, np.minimum(2, self.shape - 1)) * self.h


@lru_cache(maxsize=64)
def geometry(grid: Grid) -> _Geometry:
    return _Geometry(grid)


class Location(NamedTuple):
    """Where ``N`` queries lie: see :meth:`Interpolant.locate`."""

    inside: np.ndarray  #: (N,) on the grid and in the time span
    after: np.ndarray  #: (N,) past the last snapshot
    I: np.ndarray  #: (D, N) lower corner of the cell (axis-major: numpy is fastest on whole rows)
    F: np.ndarray  #: (D, N) fractions in the cell
    k: np.ndarray  #: (N,) snapshot interval ``[times[k], times[k + 1]]``
    wt: np.ndarray  #: (N,) weight of ``times[k + 1]``


def snapshot_pair(times: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(k, wt, inside, after)``: the snapshot interval of each time, its weight of the later snapshot (clamped
    to ``[0, 1]``), whether the time lies in the span, whether it lies past it. One snapshot: only its own time."""
    n_t = len(times)
    if n_t == 1:
        return (np.zeros(t.shape, np.int64), np.zeros(t.shape), np.isclose(t, times[0]), t > times[0] + TOL)
    if len(t) > 1 and t[0] == t[-1] and (t == t[0]).all():  # one time for the batch (the filter's): once
        k, wt, inside, after = snapshot_pair(times, t[:1])
        return (np.full(t.shape, k[0]), np.full(t.shape, wt[0]), np.full(t.shape, inside[0]),
                np.full(t.shape, after[0]))
    k = np.searchsorted(times, t, side="right") - 1
    k = np.minimum(np.maximum(k, 0), n_t - 2)
    t0 = times[k]
    wt = np.minimum(np.maximum((t - t0) / (times[k + 1] - t0), 0.0), 1.0)
    after = t > times[-1] + TOL
    return k, wt, (t >= times[0] - TOL) & ~after, after


class Interpolant:
    """Values (and gradients along ``gradient_axes``) of a field ``values[k, i1, .., iD]`` at ``(t, x)``.

    Conventions: outside the grid or the time span ``inside`` is false (and :meth:`value` is ``+inf``); a
    periodic axis wraps and is never outside; a point off the grid is clamped to it, and the gradient is that of
    the clamped point. ``budget_last``: the last axis is a budget, below its grid is outside and above it is
    clamped to its top.

    :param values: array or memory map of shape ``(len(times), *grid.shape)``
    :param times: increasing snapshot times
    :param grid: the grid of the other axes
    :param budget_last: the last axis is a budget (see above)
    :param gradient_axes: the axes along which :meth:`value_and_gradient` differentiates
    :param stacked: compute the node-wise differences once and store them beside the values (float64,
        ``1 + len(gradient_axes)`` numbers per node); else gather each corner's partners per query
    """

    def __init__(self, values: Any, times: Any, grid: Grid, *, budget_last: bool = False,
                 gradient_axes: Iterable[int] = (), stacked: bool = False):
        self.grid = grid
        self.g = g = geometry(grid)
        self.times = np.asarray(times, dtype=np.float64)
        self.n_t = len(self.times)
        # a plain ndarray view of a memory map: fancy indexing on it skips np.memmap's Python-level wrapping
        self.values = np.asarray(values)
        self.flat = self.values.reshape(-1)
        self.axes = tuple(int(a) for a in gradient_axes)
        self.budget_last = budget_last
        self.ok_lo, self.ok_hi = g.ok_lo, g.ok_hi
        if budget_last:
            self.ok_lo, self.ok_hi = g.ok_lo.copy(), g.ok_hi.copy()
            self.ok_lo[-1], self.ok_hi[-1] = g.lo[-1], np.inf
        self.stacked = self._stack() if stacked else None
        self._py = None

    # ---------------------------------------------------------------- location and weights
    def locate(self, t: np.ndarray, X: np.ndarray) -> Location:
        """Cell, fractions, snapshot interval and flags of ``N`` queries.

        :param t: ``(N,)`` times
        :param X: ``(N, D)`` points
        """
        g = self.g
        N = len(X)
        ok = np.ones(N, bool)
        I = np.empty((g.dim, N), np.int64)
        F = np.empty((g.dim, N))
        for a in range(g.dim):  # axis by axis: numpy broadcasts over a short last axis slowly
            x = X[:, a]
            ok &= (x >= self.ok_lo[a]) & (x <= self.ok_hi[a])
            if g.periodic[a]:
                S = np.mod((x - g.lo[a]) * g.inv_h[a], g.shape[a])
                low = np.floor(S)
                F[a] = S - low
                I[a] = low.astype(np.int64) % g.shape[a]  # S may round up to n: that is node 0 again
            else:
                S = np.minimum((np.minimum(np.maximum(x, g.lo[a]), g.hi[a]) - g.lo[a]) * g.inv_h[a], g.n1[a])
                I[a] = np.minimum(S.astype(np.int64), g.imax[a])  # S >= 0, so truncation is floor
                F[a] = S - I[a]
        k, wt, t_ok, after = snapshot_pair(self.times, np.asarray(t, dtype=np.float64))
        return Location(ok & t_ok, after, I, F, k, wt)

    def weights(self, F: np.ndarray, wt: np.ndarray | None = None) -> np.ndarray:
        """Multilinear weights of the ``C = 2^D`` cell corners, ``(C, N)``; with ``wt``, of the corners at both
        snapshots, ``(2C, N)``, time-major (the corners in :attr:`_Geometry.bits` order: axis 0 the most
        significant)."""
        N = F.shape[1]
        if wt is None:
            w = np.ones((1, N))
        else:
            w = np.empty((2, N))
            np.subtract(1.0, wt, out=w[0])
            w[1] = wt
        for f in F:  # each axis doubles the corners, its bit the least significant so far
            nxt = np.empty((2 * len(w), N))
            np.multiply(w, 1.0 - f, out=nxt[0::2])
            np.multiply(w, f, out=nxt[1::2])
            w = nxt
        return w

    def _both(self, loc: Location) -> bool:
        """Whether the later snapshot enters: not for queries that all lie on snapshots (the sampled-data
        filter's), which then read one time layer."""
        return self.n_t > 1 and bool(loc.wt.any())

    def _corners(self, loc: Location) -> np.ndarray:
        """Flat indices of the cell corners in snapshot ``k``, ``(C, N)``."""
        g = self.g
        if not g.any_periodic:
            base = loc.k * g.size
            for a in range(g.dim):
                base = base + loc.I[a] * g.strides[a]
            return g.corner_offsets[:, None] + base[None, :]
        lin = (loc.k * g.size)[None, :]
        for a in range(g.dim):
            j = loc.I[a][None, :] + g.bits[:, a, None]
            lin = lin + (j % g.shape[a] if g.periodic[a] else j) * g.strides[a]
        return lin

    def corner_index(self, loc: Location, both: bool) -> np.ndarray:
        """Flat indices of the cell corners, ``(C, N)``, or ``(2C, N)`` at both snapshots (time-major)."""
        idx = self._corners(loc)
        return np.concatenate([idx, idx + self.g.size]) if both else idx

    def stencil_index(self, loc: Location, both: bool) -> np.ndarray:
        """Flat indices ``(C', N, 1 + 2m)`` of each corner and its two difference partners along each gradient
        axis."""
        g = self.g
        lin = self._corners(loc)
        cols = [lin]
        for a in self.axes:
            j = loc.I[a][None, :] + g.bits[:, a, None]
            n = g.shape[a]
            if g.periodic[a]:
                j = j % n
                jm, jp = (j - 1) % n, (j + 1) % n
            else:
                jm = np.minimum(np.maximum(j - 1, 0), g.m_max[a])
                jp = np.minimum(jm + 2, n - 1)
            cols += [lin + (jm - j) * g.strides[a], lin + (jp - j) * g.strides[a]]
        idx = np.stack(cols, axis=-1)
        return np.concatenate([idx, idx + g.size]) if both else idx

    def _stack(self) -> np.ndarray:
        """``(n_times * size, 1 + m)`` float64: each node's value and its differences along the gradient axes.

        float64, because float32 differences would round the gradient by ~1e-7 relative and flip the sign of
        bang-bang inputs where the table's own gradient is nearly zero."""
        g, nt = self.g, self.n_t
        out = np.empty((nt,) + tuple(self.values.shape[1:]) + (1 + len(self.axes),), dtype=np.float64)
        for k in range(nt):
            W = np.asarray(self.values[k], dtype=np.float64)
            out[k, ..., 0] = W
            for c, a in enumerate(self.axes, start=1):
                if g.periodic[a]:
                    out[k, ..., c] = (np.roll(W, -1, axis=a) - np.roll(W, 1, axis=a)) / g.span[a]
                else:
                    m = np.minimum(np.maximum(np.arange(g.shape[a]) - 1, 0), g.m_max[a])
                    p = np.minimum(m + 2, g.shape[a] - 1)
                    out[k, ..., c] = (np.take(W, p, axis=a) - np.take(W, m, axis=a)) / g.span[a]
        return out.reshape(nt * g.size, 1 + len(self.axes))

    # ---------------------------------------------------------------- queries
    def raw(self, loc: Location) -> np.ndarray:
        """The interpolant at located queries, float64, meaningful where ``loc.inside``."""
        both = self._both(loc)
        # np.take, not fancy indexing: several times faster for gathers of this size
        v = np.take(self.flat, self.corner_index(loc, both))
        return _corner_sum(self.weights(loc.F, loc.wt if both else None) * v)

    def value_at(self, loc: Location) -> np.ndarray:
        """The value at located queries; ``+inf`` where not ``inside`` (NaN stays NaN where inside)."""
        return np.where(loc.inside, self.raw(loc), np.inf)

    def value(self, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """The value at ``(N,)`` times and ``(N, D)`` points; ``+inf`` outside."""
        return self.value_at(self.locate(t, X))

    def value_and_gradient(self, t: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, Location]:
        """The value (``+inf`` outside), the gradient ``(N, m)`` along the gradient axes and the location.

        The value and its flags are those of the query itself, the gradient that of the query clamped to the grid
        and the time span, which is where :meth:`locate` puts its weights.
        """
        loc = self.locate(t, X)
        m = len(self.axes)
        both = self._both(loc)
        w = self.weights(loc.F, loc.wt if both else None)
        if self.stacked is not None:
            idx = self.corner_index(loc, both)
            v = np.take(self.stacked, idx.reshape(-1), axis=0).reshape(idx.shape + (1 + m,))
            s = _corner_sum(w[:, :, None] * v)
            grad = s[:, 1:]
        else:
            v = np.take(self.flat, self.stencil_index(loc, both))
            s = _corner_sum(w[:, :, None] * v)
            grad = (s[:, 2::2] - s[:, 1::2]) / self.g.span[list(self.axes)]
        return np.where(loc.inside, s[:, 0], np.inf), grad, loc

    def single(self, t: float, c: list[float]) -> tuple[float, list[float], int, list[int], bool, bool] | None:
        """:meth:`value_and_gradient` of one query in Python floats: the same location, weights and gathers
        without numpy's cost per call, several times faster for one query.

        :return: ``(value, gradient, k, I, inside, after)``, or ``None`` where the batch path must answer: a cell
            whose corners (or, without the stacked differences, difference partners) would wrap around a periodic
            axis or be shifted at a grid edge, and tables of one snapshot
        """
        py = self._py if self._py is not None else self._scalar_constants()
        if py is None:
            return None
        lo, hi, inv_h, n1, ok_lo, ok_hi, first, last = (py[k] for k in ("lo", "hi", "inv_h", "n1", "ok_lo", "ok_hi",
                                                                         "first", "last"))
        inside = True
        base = 0
        F: list[float] = []
        I: list[int] = []
        for a, per in enumerate(py["periodic"]):
            x = c[a]
            if x < ok_lo[a] or x > ok_hi[a]:
                inside = False
            if per:
                s = ((x - lo[a]) * inv_h[a]) % py["n"][a]
                i = math.floor(s)
            else:
                s = (min(max(x, lo[a]), hi[a]) - lo[a]) * inv_h[a]
                s = s if s < n1[a] else n1[a]
                i = int(s)
                i = i if i < n1[a] else int(n1[a]) - 1
            if i < first[a] or i > last[a]:
                return None
            I.append(i)
            F.append(s - i)
            base += i * py["strides"][a]
        times = py["times"]
        k = min(max(bisect_right(times, t) - 1, 0), len(times) - 2)
        wt = min(max((t - times[k]) / (times[k + 1] - times[k]), 0.0), 1.0)
        after = t > times[-1] + TOL
        if after or t < times[0] - TOL:
            inside = False
        w = [1.0 - wt, wt]
        for f in F:
            g = 1.0 - f
            w = [x for wi in w for x in (wi * g, wi * f)]
        base += k * self.g.size
        if self.stacked is not None:
            s = (np.array(w) @ np.take(self.stacked, py["offsets"] + base, axis=0)).tolist()
            grad = s[1:]
        else:
            s = (np.array(w) @ np.take(self.flat, py["offsets"] + base).reshape(len(w), -1)).tolist()
            span = py["span"]
            grad = [(s[2 + 2 * j] - s[1 + 2 * j]) / span[j] for j in range(len(self.axes))]
        return (s[0] if inside else math.inf), grad, k, I, inside, after

    def _scalar_constants(self) -> dict[str, Any] | None:
        """The constants of :meth:`single` as Python numbers, and the flat offsets of what one query gathers from
        a cell's lower corner in snapshot ``k``: the corners at both snapshots, time-major, each with its
        difference partners (those of an interior cell) unless the differences are stacked."""
        g = self.g
        if self.n_t < 2:
            return None
        interior = set() if self.stacked is not None else set(self.axes)
        corners = np.concatenate([g.corner_offsets, g.corner_offsets + g.size])
        if self.stacked is not None:
            offsets = corners
        else:
            cols = [corners]
            for a in self.axes:
                cols += [corners - g.strides[a], corners + g.strides[a]]
            offsets = np.stack(cols, axis=-1).reshape(-1)
        self._py = {
            "lo": g.lo.tolist(), "hi": g.hi.tolist(), "inv_h": g.inv_h.tolist(), "n1": g.n1.tolist(),
            "n": g.shape.tolist(), "ok_lo": self.ok_lo.tolist(), "ok_hi": self.ok_hi.tolist(),
            "periodic": g.periodic.tolist(), "strides": g.strides.tolist(), "times": self.times.tolist(),
            "first": [1 if a in interior else 0 for a in range(g.dim)],
            "last": [int(g.shape[a]) - (3 if a in interior else 2) for a in range(g.dim)],
            "span": g.span[list(self.axes)].tolist(), "offsets": offsets,
        }
        return self._py

    def slice(self, t: float, z: float | None = None) -> np.ndarray:
        """The field at time ``t`` on the grid's nodes; with ``z``, at that coordinate of the last axis (clamped
        to the grid) on the nodes of the other axes. The weights are a point query's.

        :raises ValueError: ``t`` outside the time span
        """
        k, wt, ok, _ = snapshot_pair(self.times, np.array([float(t)]))
        if not (math.isfinite(t) and ok[0]):
            raise ValueError(f"t={t!r} is outside the table's time span [{self.times[0]}, {self.times[-1]}]")
        k, wt = int(k[0]), float(wt[0])
        layers = [(k, 1.0 - wt)] + ([(k + 1, wt)] if wt > 0 else [])
        if z is None:
            return sum(w * np.asarray(self.values[j], dtype=np.float64) for j, w in layers)
        g = self.g
        s = min((min(max(float(z), g.lo[-1]), g.hi[-1]) - g.lo[-1]) * g.inv_h[-1], g.n1[-1])
        i = min(int(s), int(g.imax[-1]))
        f = s - i
        out = 0.0
        for j, w in layers:
            lower = np.asarray(self.values[j, ..., i], dtype=np.float64)
            upper = np.asarray(self.values[j, ..., i + 1], dtype=np.float64)
            out = out + w * ((1.0 - f) * lower + f * upper)
        return out


def _corner_sum(p: np.ndarray) -> np.ndarray:
    """The sum over the corners (axis 0, a power of two long) as a tree of row additions: every query's sum is
    taken in the same order whatever the batch, so a decision is the same number alone or in a batch (a BLAS or
    pairwise reduction would reorder it with the batch's size)."""
    while len(p) > 1:
        p = p[0::2] + p[1::2]
    return p[0]


def interpolate(values: Any, times: np.ndarray, grid: Grid, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Multilinear interpolation of ``values[k, i1, .., id]`` at ``(t[j], x[j])`` (:class:`Interpolant`).

    :param values: array (or memmap) of shape ``(len(times), *grid.shape)``
    :param times: increasing snapshot times
    :param grid: the grid of the spatial axes
    :param t: query times, shape ``(N,)``
    :param x: query points, shape ``(N, d)``
    :return: ``(value, inside)``; ``value`` is float64, that of the query clamped to the grid where not ``inside``
    """
    engine = Interpolant(values, times, grid)
    loc = engine.locate(np.asarray(t, dtype=np.float64), np.asarray(x, dtype=np.float64))
    return engine.raw(loc), loc.inside


__all__ = ["Interpolant", "Location", "TOL", "geometry", "interpolate", "snapshot_pair"]
