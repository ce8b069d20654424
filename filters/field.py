"""``TableField``: batched ``W~`` and its spatial gradient from a table's ``W_eps`` block (the table-optimal
``a*`` feedback of :mod:`softreach.agents` reads it)."""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right


import numpy as np

from softreach.reach import Table, TableError

#: tolerance of the table's own time-span and grid checks (``softreach.reach.interpolation``)
_TIME_TOL = 1e-9


class TableField:
    """Batched ``W~`` and its spatial gradient from a table's ``W_eps`` block.

    Numerically the same as :meth:`Table.value` and :meth:`Table.gradient` (up to rounding), including their
    conventions: ``+inf`` outside the grid or the time span or below the budget grid; a budget above the grid
    is taken at its top; the gradient is the central difference of the interpolant over one spacing, shifted
    inwards at the grid's edges, at the query clipped to the grid and time span.

    It is faster because the central difference of a multilinear interpolant over exactly one spacing is the
    interpolant (same cell, same weights) of the node-wise central differences ``(W[m+2] - W[m]) / 2h`` with
    ``m = clip(j - 1, 0, n - 3)`` (which reproduces the inward shift at the edges): one set of weights serves the
    value and every gradient component. Two layouts:

    * ``"stacked"`` (default when it fits ``max_bytes``): the node-wise differences are computed once, stored
      next to the values (float64, ``1 + n`` numbers per node), and a query gathers ``2^D`` rows per snapshot;
    * ``"stencil"``: nothing is precomputed; a query gathers each corner's value and its ``2n`` difference
      partners straight from the (memory-mapped) table. For tables too big to copy.

    :param table: a table with a ``W_eps`` field
    :param layout: ``"stacked"``, ``"stencil"`` or ``None`` (stacked if it fits ``max_bytes``)
    :param max_bytes: memory budget of the stacked copy
    """

    def __init__(self, table: Table, layout: str | None = None, max_bytes: int = 1024 * 2**20):
        if not table.has_budget:
            raise TableError(f"table {table.path} holds only the classical V; the filter needs W_eps (solve it "
                             f"without classical_only)")
        if layout not in (None, "stacked", "stencil"):
            raise ValueError(f"layout must be 'stacked', 'stencil' or None, got {layout!r}")
        grid = table.grid("W_eps")
        self.table = table
        self.grid = grid
        self.n = n = len(table.model_metadata["state_names"])  # state axes; the last grid axis is the budget z
        self.dim = D = grid.ndim
        self.times = table.times("W_eps")
        if len(self.times) < 2:
            raise TableError(f"table {table.path} has a single snapshot; the filter needs W_eps over time")
        self.horizon = float(self.times[-1])
        self.lo = np.array(grid.lo)
        self.hi = np.array(grid.hi)
        self.h = np.array(grid.spacing)
        self.inv_h = 1.0 / self.h
        self.shape = np.array(grid.shape, dtype=np.int64)
        self.n1 = (self.shape - 1).astype(np.float64)
        self.periodic = np.array(grid.periodic, dtype=bool)
        self.any_periodic = bool(self.periodic.any())
        self._tol = 1e-9 * np.maximum(1.0, self.shape)
        # a plain ndarray view of the memory map: fancy indexing on it skips np.memmap's Python-level wrapping
        self.values = np.asarray(table.values("W_eps"))
        self.size = int(np.prod(grid.shape))
        self.flat = self.values.reshape(-1)
        self.strides = np.array([int(np.prod(grid.shape[a + 1:])) for a in range(D)], dtype=np.int64)
        # corners in itertools.product order: axis 0 is the most significant bit
        self.bits = np.array(list(itertools.product((0, 1), repeat=D)), dtype=np.int64)  # (C, D)
        self.corner_offsets = self.bits @ self.strides  # (C,)
        C, K = len(self.bits), 1 + 2 * n
        self._value_offsets = np.stack([self.corner_offsets, self.corner_offsets + self.size])  # (2, C)
        # for each axis (time first), which end's weight every one of the 2C (snapshot, corner) pairs takes
        time_bits = np.array(list(itertools.product((0, 1), repeat=D + 1)), dtype=np.int64)
        self._weight_select = [time_bits[:, a] for a in range(D + 1)]

        if layout is None:
            layout = "stacked" if self.values.shape[0] * self.size * (1 + n) * 8 <= max_bytes else "stencil"
        self.layout = layout
        self.stacked = None
        if layout == "stacked":
            self.stacked = self._stack()
        else:
            # offsets of [value, (minus, plus) per state axis] at every corner and both snapshots of the pair,
            # for a cell away from the edges; edge cells get a correction (see _stencil)
            offs = np.empty((2, C, K), dtype=np.int64)
            for s in range(2):
                offs[s, :, 0] = self.corner_offsets + s * self.size
                for a in range(n):
                    offs[s, :, 1 + 2 * a] = offs[s, :, 0] - self.strides[a]
                    offs[s, :, 2 + 2 * a] = offs[s, :, 0] + self.strides[a]
            self._stencil_offsets = offs
        self._single_offsets = self._value_offsets.reshape(-1) if layout == "stacked" else \
            self._stencil_offsets.reshape(-1)
        # scalar fast path constants (Python floats and ints)
        self._py = {
            "lo": self.lo.tolist(), "inv_h": self.inv_h.tolist(), "n1": self.n1.tolist(), "tol": self._tol.tolist(),
            "imax": (self.shape - 2).tolist(), "strides": self.strides.tolist(), "times": self.times.tolist(),
            "two_h": (2.0 * self.h[:n]).tolist(),
        }

    def _stack(self) -> np.ndarray:
        """``(n_times * size, 1 + n)`` float64: each node's value and its central differences along the states.

        float64, because float32 differences would round the gradient by ~1e-7 relative and flip the sign of
        bang-bang inputs where the table's own gradient is nearly zero."""
        n, nt = self.n, self.values.shape[0]
        out = np.empty((nt,) + tuple(self.shape) + (1 + n,), dtype=np.float64)
        for k in range(nt):
            W = np.asarray(self.values[k], dtype=np.float64)
            out[k, ..., 0] = W
            for a in range(n):
                if self.periodic[a]:
                    d = (np.roll(W, -1, axis=a) - np.roll(W, 1, axis=a)) / (2.0 * self.h[a])
                else:
                    j = np.arange(self.shape[a])
                    m = np.clip(j - 1, 0, self.shape[a] - 3)
                    d = (np.take(W, m + 2, axis=a) - np.take(W, m, axis=a)) / (2.0 * self.h[a])
                out[k, ..., 1 + a] = d
        return out.reshape(nt * self.size, 1 + n)

    # ---------------------------------------------------------------- location
    def locate(self, t: np.ndarray, X: np.ndarray) -> dict[str, np.ndarray]:
        """Cell, weights and flags of ``N`` augmented points ``X = (x, z)`` at times ``t``.

        :param t: ``(N,)`` times
        :param X: ``(N, n + 1)`` states with the budget as the last column
        :return: ``inside`` (grid and time span, budget not below the grid), ``after`` (past the horizon),
            ``I`` (lower cell corner indices, ``(N, D)``), ``F`` (fractions), ``k`` / ``wt`` (snapshot interval
            and its time weight), ``base`` (flat index of the lower corner in snapshot ``k``)
        """
        S = (X - self.lo) * self.inv_h
        n1 = self.n1
        ok = (S >= -self._tol) & (S <= n1 + self._tol)
        ok[:, -1] = (X[:, -1] >= self.lo[-1])  # budget: below the grid is unsafe, above it is clamped
        if self.any_periodic:
            per = self.periodic
            ok[:, per] = True
            S = np.where(per, np.mod(S, self.shape), np.minimum(np.maximum(S, 0.0), n1))
            I = np.floor(S).astype(np.int64)
            I = np.where(per, I % self.shape, np.minimum(I, self.shape - 2))
        else:
            S = np.minimum(np.maximum(S, 0.0), n1)
            I = np.minimum(S.astype(np.int64), self.shape - 2)  # S >= 0, so truncation is floor
        F = S - I
        times = self.times
        k = np.searchsorted(times, t, side="right") - 1
        k = np.minimum(np.maximum(k, 0), len(times) - 2)
        t0 = times[k]
        wt = np.minimum(np.maximum((t - t0) / (times[k + 1] - t0), 0.0), 1.0)
        after = t > times[-1] + _TIME_TOL
        inside = ok.all(axis=1) & (t >= times[0] - _TIME_TOL) & ~after
        base = k * self.size
        for a in range(self.dim):
            base = base + I[:, a] * self.strides[a]
        return {"inside": inside, "after": after, "I": I, "F": F, "k": k, "wt": wt, "base": base}

    def _weights(self, F: np.ndarray, wt: np.ndarray) -> np.ndarray:
        """Multilinear weights ``(N, 2C)`` of the ``C = 2^D`` cell corners at both snapshots of the pair
        (time-major, then the corners in :attr:`bits` order: axis 0 the most significant)."""
        # built corner-major, (2C, N), where each factor is one fancy-indexed row gather: fastest in numpy
        G = np.empty((self.dim + 1, 2, len(F)))
        G[0, 1] = wt
        G[1:, 1] = F.T
        G[:, 0] = 1.0 - G[:, 1]
        sel = self._weight_select
        w = G[0, sel[0]]
        for a in range(1, self.dim + 1):
            w *= G[a, sel[a]]
        return np.ascontiguousarray(w.T)

    def _corner_index(self, loc: dict[str, np.ndarray]) -> np.ndarray:
        """Flat node indices ``(N, 2, C)`` of the cell corners at both snapshots of the pair."""
        if not self.any_periodic:
            return loc["base"][:, None, None] + self._value_offsets[None]
        J = loc["I"][:, None, :] + self.bits[None, :, :]
        J = np.where(self.periodic, J % self.shape, J)
        lin = J @ self.strides + (loc["k"] * self.size)[:, None]
        return lin[:, None, :] + np.array([0, self.size])[None, :, None]

    def _stencil(self, loc: dict[str, np.ndarray]) -> np.ndarray:
        """Flat indices ``(N, 2, C, 1 + 2n)``: each corner's node and its two central-difference partners."""
        I = loc["I"]
        if self.any_periodic:
            J = I[:, None, :] + self.bits[None, :, :]
            J = np.where(self.periodic, J % self.shape, J)
            lin = J @ self.strides + (loc["k"] * self.size)[:, None]  # (N, C)
            cols = [lin]
            for a in range(self.n):
                j = J[:, :, a]
                if self.periodic[a]:
                    jm, jp = (j - 1) % self.shape[a], (j + 1) % self.shape[a]
                else:
                    jm = np.clip(j - 1, 0, self.shape[a] - 3)
                    jp = jm + 2
                cols += [lin + (jm - j) * self.strides[a], lin + (jp - j) * self.strides[a]]
            idx = np.stack(cols, axis=-1)
            return idx[:, None] + np.array([0, self.size])[None, :, None, None]
        idx = loc["base"][:, None, None, None] + self._stencil_offsets[None]
        for a in range(self.n):
            # at the grid's edges the difference is shifted inwards: nodes (0, 2) for node 0, (n-3, n-1) for n-1
            low = I[:, a] == 0
            high = I[:, a] == self.shape[a] - 2
            if low.any() or high.any():
                corr = self.strides[a] * (low[:, None] & (self.bits[None, :, a] == 0)).astype(np.int64) \
                    - self.strides[a] * (high[:, None] & (self.bits[None, :, a] == 1)).astype(np.int64)
                idx[:, :, :, 1 + 2 * a:3 + 2 * a] += corr[:, None, :, None]
        return idx

    # ---------------------------------------------------------------- queries
    def value_at(self, loc: dict[str, np.ndarray]) -> np.ndarray:
        """``W~`` at located points; ``+inf`` where not ``inside`` (NaN stays NaN where inside)."""
        N = len(loc["k"])
        # np.take, not fancy indexing: several times faster for row gathers of this size
        v = np.take(self.flat, self._corner_index(loc)).reshape(N, -1).astype(np.float64)  # (N, 2C)
        w = self._weights(loc["F"], loc["wt"])
        val = np.matmul(w[:, None, :], v[:, :, None])[:, 0, 0]
        return np.where(loc["inside"], val, np.inf)

    def value(self, t: np.ndarray, X: np.ndarray) -> np.ndarray:
        """``W~(t, x, z)`` for ``(N,)`` times and ``(N, n + 1)`` points (validated by the caller)."""
        return self.value_at(self.locate(t, X))

    def value_and_gradient(self, t: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """``W~``, its gradient along the ``n`` state axes ``(N, n)`` and the location of the points.

        The gradient is :meth:`Table.gradient`'s (state part): the value and its flags are taken at the query
        itself, the gradient at the query clipped to the grid, which is where :meth:`locate` puts its weights.
        """
        loc = self.locate(t, X)
        N = len(t)
        w = self._weights(loc["F"], loc["wt"])
        if self.stacked is not None:
            # np.take, not fancy indexing: several times faster for row gathers of this size
            v = np.take(self.stacked, self._corner_index(loc).reshape(-1), axis=0).reshape(N, -1, 1 + self.n)
            s = np.matmul(w[:, None, :], v)[:, 0, :]  # (N, 1 + n); matmul beats einsum here by ~3x
            grad = s[:, 1:]
        else:
            v = np.take(self.flat, self._stencil(loc)).reshape(N, -1, 1 + 2 * self.n).astype(np.float64)
            s = np.matmul(w[:, None, :], v)[:, 0, :]
            grad = (s[:, 2::2] - s[:, 1::2]) / (2.0 * self.h[: self.n])
        val = np.where(loc["inside"], s[:, 0], np.inf)
        return val, grad, loc

    def single(self, t: float, c: list[float]) -> tuple[float, list[float], int, list[int], bool, bool] | None:
        """The scalar fast path of :meth:`value_and_gradient` for one query in Python floats.

        :return: ``(value, gradient, k, I, inside, after)``, or ``None`` where the batch path must answer
            (periodic grids; with the stencil layout, cells at a grid edge along a state axis)
        """
        if self.any_periodic:
            return None
        py = self._py
        lo, inv_h, n1, tol, imax = py["lo"], py["inv_h"], py["n1"], py["tol"], py["imax"]
        stencil = self.stacked is None
        inside = True
        I: list[int] = []
        F: list[float] = []
        last = self.dim - 1
        for a in range(self.dim):
            s = (c[a] - lo[a]) * inv_h[a]
            if a == last:
                if c[a] < lo[a]:
                    inside = False
            elif s < -tol[a] or s > n1[a] + tol[a]:
                inside = False
            s = 0.0 if s < 0.0 else (n1[a] if s > n1[a] else s)
            i = int(s)
            if i > imax[a]:
                i = imax[a]
            if stencil and a < self.n and (i == 0 or i == imax[a]):
                return None
            I.append(i)
            F.append(s - i)
        times = py["times"]
        k = bisect_right(times, t) - 1
        k = 0 if k < 0 else (len(times) - 2 if k > len(times) - 2 else k)
        wt = (t - times[k]) / (times[k + 1] - times[k])
        wt = 0.0 if wt < 0.0 else (1.0 if wt > 1.0 else wt)
        after = t > times[-1] + _TIME_TOL
        if after or t < times[0] - _TIME_TOL:
            inside = False
        base = k * self.size
        for a, st in enumerate(py["strides"]):
            base += I[a] * st
        w = [1.0]
        for f in F:
            g = 1.0 - f
            w = [x for wi in w for x in (wi * g, wi * f)]
        u = 1.0 - wt
        w = np.array([wi * u for wi in w] + [wi * wt for wi in w])
        if stencil:
            s = (w @ np.take(self.flat, self._single_offsets + base).reshape(len(w), -1)).tolist()
            two_h = py["two_h"]
            grad = [(s[2 + 2 * a] - s[1 + 2 * a]) / two_h[a] for a in range(self.n)]
        else:
            s = (w @ np.take(self.stacked, self._single_offsets + base, axis=0)).tolist()
            grad = s[1:]
        value = s[0] if inside else math.inf
        return value, grad, k, I, inside, after


# --------------------------------------------------------------------------------------------- margin
