"""The batched core of the least-restrictive safety filter: fast table look-ups, the computed margin, two rules.

Everything here works on batches: ``t`` and ``z`` are scalars or ``(N,)``, ``x`` is ``(N, n)`` (or ``(n,)`` for
one query), actions are ``(N, m)`` (or ``(m,)``) in the model's **physical** units unless ``normalized=True``.
numpy in gives numpy out; torch tensors in give torch tensors out, on the action's device and in its dtype (the
table is numpy, so the tensors are converted once at the boundary).

The guarantee (paper, Thm. 3 and §V): from a state with ``W_eps(t, x, z) <= 0`` the table's feedback
``a*(t, x, z)`` lands, never leaves ``C1`` and spends at most ``z`` of budget, whatever the wind in its box. A
filter keeps that guarantee while letting any other policy act where one control period of *any* action
cannot leave ``{W_eps <= 0}``:

* **switch** rule (least restrictive): apply the policy's action while ``W(t, x, z) <= -margin(t, x, z)``,
  otherwise apply ``a*``;
* **smooth** rule: where the switch rule would apply ``a*``, apply instead the action closest to the policy's,
  on the segment from ``a*`` to it, whose predicted value after one control period under the worst wind does
  not exceed the current value (``a*`` if no point of the segment but ``a*`` qualifies).

``W`` here is the table's multilinear interpolant ``W~`` in ``(x, z)`` and linear in ``t`` (what
:meth:`softreach.reach.Table.value` returns) and ``a*`` is :meth:`softreach.reach.Table.optimal_control` (read at
the budget ``max(z, Table.budget_resolution)``, the Table API's convention: at ``z = 0`` the exact ``W_eps`` is
flat); :class:`TableField` evaluates the same numbers faster (a single query takes tens of microseconds).

The margin (:class:`MarginField`) is computed from the table, not guessed. For a query in grid cell ``c`` and
snapshot interval ``k`` (``t`` in ``[t_k, t_k+1]``)::

    margin = dt * ( sum_i L_i * S_i  +  L_t )  +  E_x  +  E_t

* ``S_i`` bounds ``|f_i|`` over every control and wind (the model's ``dissipation(t, x, None, None)``, taken at
  the cell corners; ``S_z = 1`` since ``z' = -h_eps`` is in ``[-1, 0]``);
* ``L_i`` bounds the slope ``|dW~/dx_i|`` of the interpolant: within a cell it is a convex combination of the
  cell's edge slopes ``|W[j+1] - W[j]| / h_i``, so the largest of those is exact, not an estimate;
* ``L_t`` bounds ``|dW~/dt|``: the largest ``|W[k+1] - W[k]| / (t_k+1 - t_k)`` at the cell's nodes;
* ``E_x = sum_i max |W[j+1] - 2 W[j] + W[j-1]| / 8`` and ``E_t`` (the same along time) bound how far the true
  value may lie above the piecewise-linear interpolant between nodes (``h^2 / 8`` times the second derivative,
  which the second difference estimates as ``|D^2 W| / h^2``);
* every maximum is taken over all cells one control period of motion can reach from ``c`` (``ceil(dt S_i / h_i)``
  cells along each state axis, ``ceil(dt / h_z)`` cells down the budget axis) and over the snapshots that
  ``[t, t + dt]`` touches. Where that neighbourhood leaves the grid along a state axis the margin is ``+inf``:
  the next state could lie outside the table, where nothing is known.

So ``W~(t, x, z) <= -margin`` implies ``W~ <= -E`` (hence the true value ``<= 0``) after one period of any
action and any wind. The bound is local: deep in the safe set, where the value is flat, it is small and the
policy keeps full authority; near the set's boundary it is large and the filter steps in early. A global
constant (one Lipschitz bound for the whole table) would be ``dt * max_i L_i S_i``, far larger than the depth
of the safe set (``W >= min l``, a fraction of a unit), so the filter would never let the policy act; the
global terms are reported by :meth:`MarginField.summary` for reference. Pass ``margin=<float>`` to use a
constant of your own instead (e.g. ``0`` to trust the table at face value).

What the margin does not cover: the solver's own error in the node values (the table is taken as the truth at
its nodes), and the error of the zero-order-hold ``a*`` feedback between nodes and control periods, which the
tests measure on closed loops instead.

Special cases, each reported in ``reason`` and never an exception mid-episode: a query outside the grid (or
with a budget below the grid's lowest), after the table's horizon, or where the table holds a non-finite value
is treated as unsafe: ``a*`` is applied, evaluated at the nearest point of the table (state and budget clipped
to the grid, time to the table's span), and where even that is not defined (a non-finite gradient) the
documented fallback action (``fallback_action``, default: the centre of the control box). Non-finite or wrongly
shaped *inputs* (``t``, ``x``, ``z``, the policy's action) are programming errors and raise :class:`ValueError`
naming the offending value.
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_right
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable

import numpy as np

from softreach.reach import Table, TableError

try:  # torch is a base dependency, but keep numpy-only use possible
    import torch
except ImportError:  # pragma: no cover - exercised only without torch
    torch = None  # type: ignore[assignment]

__all__ = [
    "PASS", "BLEND", "OPTIMAL", "OUTSIDE", "AFTER_HORIZON", "NONFINITE", "FALLBACK", "REASONS", "RULES",
    "MarginField", "TableField", "ValueFilter", "smooth_rule", "switch_rule",
]

# --------------------------------------------------------------------------------------------- reasons
#: the policy's action was applied unchanged
PASS = 0
#: smooth rule: a point between the policy's action and ``a*`` was applied
BLEND = 1
#: ``W > -margin``: the table's optimal action ``a*`` was applied
OPTIMAL = 2
#: the query lies outside the table's grid (or its budget below the grid): ``a*`` at the nearest table point
OUTSIDE = 3
#: the query time is after the table's horizon: ``a*`` at the horizon
AFTER_HORIZON = 4
#: the table's value at the query is not finite (NaN in the table): ``a*`` where defined
NONFINITE = 5
#: ``a*`` itself was not finite there: the fallback action was applied
FALLBACK = 6
#: reason code -> name, as reported by the wrapper's ``info["filter_reason"]``
REASONS = {PASS: "pass", BLEND: "blend", OPTIMAL: "optimal", OUTSIDE: "outside_domain",
           AFTER_HORIZON: "after_horizon", NONFINITE: "nonfinite_value", FALLBACK: "fallback"}
RULES = ("switch", "smooth")

#: tolerance of the table's own time-span and grid checks (``softreach.reach.interpolation``)
_TIME_TOL = 1e-9


# --------------------------------------------------------------------------------------------- fast field
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
def _pair_max(arr: np.ndarray, axis: int) -> np.ndarray:
    """Max of neighbouring entries along ``axis``: nodes -> cells (length ``n - 1``)."""
    lo = [slice(None)] * arr.ndim
    hi = [slice(None)] * arr.ndim
    lo[axis] = slice(None, -1)
    hi[axis] = slice(1, None)
    return np.maximum(arr[tuple(lo)], arr[tuple(hi)])


def _cell_max(arr: np.ndarray, skip: int | None = None) -> np.ndarray:
    """Node field -> cell field: the max over each cell's corners (along every axis but ``skip``)."""
    for ax in range(arr.ndim):
        if ax != skip:
            arr = _pair_max(arr, ax)
    return arr


def _dilate(arr: np.ndarray, axis: int, below: int, above: int, periodic: bool, outside: float) -> np.ndarray:
    """``out[i] = max(arr[i - below], ..., arr[i + above])`` along ``axis``; entries beyond the array count as
    ``outside`` (``+inf``: the reachable cells leave the grid) unless the axis is periodic."""
    if below == 0 and above == 0:
        return arr
    out = arr.copy()
    n = arr.shape[axis]
    for s in list(range(1, below + 1)) + [-s for s in range(1, above + 1)]:
        # s > 0: out[i] sees arr[i - s]; s < 0: out[i] sees arr[i + |s|]
        if periodic:
            out = np.maximum(out, np.roll(arr, s, axis=axis))
            continue
        shifted = np.full_like(arr, outside)
        src = [slice(None)] * arr.ndim
        dst = [slice(None)] * arr.ndim
        if abs(s) >= n:
            out = np.maximum(out, shifted)
            continue
        if s > 0:
            src[axis], dst[axis] = slice(0, n - s), slice(s, n)
        else:
            src[axis], dst[axis] = slice(-s, n), slice(0, n + s)
        shifted[tuple(dst)] = arr[tuple(src)]
        out = np.maximum(out, shifted)
    return out


def _second_difference(arr: np.ndarray, axis: int) -> np.ndarray:
    """``|W[j+1] - 2 W[j] + W[j-1]|`` at the nodes along ``axis`` (the end nodes take their neighbour's)."""
    d = np.abs(np.diff(arr, n=2, axis=axis))
    first = [slice(None)] * arr.ndim
    last = [slice(None)] * arr.ndim
    first[axis] = slice(0, 1)
    last[axis] = slice(-1, None)
    return np.concatenate([d[tuple(first)], d, d[tuple(last)]], axis=axis)


@dataclass
class MarginField:
    """The computed margin on the table's cells, per snapshot interval (see the module docstring).

    :param field: ``(n_intervals, *pooled cell shape)`` float32 margins (``+inf`` where the reachable
        neighbourhood leaves the grid)
    :param pool: cells per stored entry along each axis (``1``: every cell has its own margin; larger values
        keep memory bounded on big tables, taking the max over each block, which is conservative)
    :param dt: the control period it was computed for [s]
    :param reach_cells: cells one period can cross, per axis (below, above)
    :param terms: the largest finite value of each term over the table (motion per axis, time, interpolation),
        for documentation and reports
    """

    field: np.ndarray
    pool: tuple[int, ...]
    dt: float
    reach_cells: tuple[tuple[int, int], ...]
    terms: dict[str, float]

    def lookup(self, loc: dict[str, np.ndarray]) -> np.ndarray:
        """The margin of each located point (its cell and snapshot interval)."""
        I = loc["I"]
        if any(p != 1 for p in self.pool):
            I = I // np.array(self.pool, dtype=np.int64)
        k = np.minimum(loc["k"], self.field.shape[0] - 1)
        return self.field[(k, *I.T)].astype(np.float64)

    def summary(self) -> dict[str, Any]:
        """Sizes of the terms and of the field (finite part), for reports."""
        finite = self.field[np.isfinite(self.field)]
        return {
            "dt": self.dt,
            "pool": list(self.pool),
            "reach_cells": [list(r) for r in self.reach_cells],
            "terms_max": dict(self.terms),
            "margin_min": float(finite.min()) if finite.size else math.inf,
            "margin_median": float(np.median(finite)) if finite.size else math.inf,
            "margin_max": float(finite.max()) if finite.size else math.inf,
            "fraction_infinite": float(1.0 - finite.size / max(1, self.field.size)),
        }

    @classmethod
    def compute(cls, table: Table, dt: float, *, interpolation_error: bool = True,
                max_bytes: int = 256 * 2**20) -> "MarginField":
        """Compute the margin field of ``table`` for control period ``dt``.

        Streams the table one snapshot at a time (peak memory a few snapshots) and stores float32 margins per
        snapshot interval and cell, max-pooled by the smallest integer factor that fits ``max_bytes``.

        :param table: a table with ``W_eps``
        :param dt: control period [s] (one period of any action is what the margin must absorb)
        :param interpolation_error: include ``E_x`` and ``E_t`` (on by default)
        :param max_bytes: memory budget of the stored field
        """
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite positive number of seconds, got {dt!r}")
        model = table.model
        grid = table.grid("W_eps")
        n, D = model.state_dim, grid.ndim
        h = np.array(grid.spacing)
        times = table.times("W_eps")
        nt = len(times)
        if nt < 2:
            raise TableError(f"table {table.path} has a single snapshot; the filter needs W_eps over time")
        vals = table.values("W_eps")

        # speed bounds |f_i| over all inputs at the state nodes, as cell maxima (S_z = 1: z' in [-1, 0])
        coords = [grid.axis(i).reshape([-1 if j == i else 1 for j in range(n)]) for i in range(n)]
        state_shape = tuple(grid.shape[:n])
        # a time-varying model is bounded over every snapshot time at once (conservative; the paper's are autonomous)
        when = times[:1] if getattr(model, "time_invariant", True) else times
        speed_nodes = None
        for tk in when:
            diss = model.dissipation(float(tk), coords, None, None)
            now = [np.broadcast_to(np.abs(np.asarray(s, dtype=np.float64)), state_shape) for s in diss]
            speed_nodes = now if speed_nodes is None else [np.maximum(a, b) for a, b in zip(speed_nodes, now)]
        speed_cells = [_cell_max(s) for s in speed_nodes]
        glob = [float(np.max(s)) for s in speed_nodes]
        if not all(math.isfinite(g) for g in glob):
            raise ValueError(f"model {model.name!r} returned non-finite speed bounds over the grid: {glob}")

        # cells one period can cross: symmetric along the state axes, downwards only along the budget
        reach = [(int(math.ceil(dt * g / hi - 1e-12)),) * 2 for g, hi in zip(glob, h[:n])]
        reach.append((int(math.ceil(dt / h[-1] - 1e-12)), 0))
        dsnap = np.diff(times)
        c_t = int(math.ceil(dt / float(dsnap.min()) - 1e-12))

        def dilate_space(arr: np.ndarray) -> np.ndarray:
            for ax in range(D):
                lo_, hi_ = reach[ax]
                arr = _dilate(arr, ax, lo_, hi_, bool(grid.periodic[ax]), math.inf)
            return arr

        # the speed bound must hold over the reachable cells too (e.g. |y'| = |v| grows with v)
        speed_reach = []
        for s in speed_cells:
            for ax in range(n):
                lo_, hi_ = reach[ax]
                s = _dilate(s, ax, lo_, hi_, bool(grid.periodic[ax]), math.inf)
            speed_reach.append(s[..., None])  # broadcast along the budget axis

        names = tuple(model.state_names) + ("z",)
        terms = {f"motion_{name}": 0.0 for name in names}
        terms.update({"time": 0.0, "interpolation_space": 0.0, "interpolation_time": 0.0})

        def finite_max(arr: np.ndarray) -> float:
            f = arr[np.isfinite(arr)]
            return float(f.max()) if f.size else 0.0

        @lru_cache(maxsize=c_t + 4)  # the loops below walk the snapshots in order; a few in memory suffice
        def snap(s: int) -> np.ndarray:
            return np.asarray(vals[s], dtype=np.float64)

        @lru_cache(maxsize=c_t + 3)
        def space_terms(s: int) -> tuple[np.ndarray, np.ndarray | None]:
            """Snapshot ``s``: motion ``dt sum_i L_i S_i`` and spatial interpolation error, per cell."""
            Ws = snap(s)
            motion = interp = None
            for ax in range(D):
                edge = np.abs(np.diff(Ws, axis=ax)) / h[ax]
                term = dt * dilate_space(_cell_max(edge, skip=ax)) * (speed_reach[ax] if ax < n else 1.0)
                terms[f"motion_{names[ax]}"] = max(terms[f"motion_{names[ax]}"], finite_max(term))
                motion = term if motion is None else motion + term
                if interpolation_error:
                    e = dilate_space(_cell_max(_second_difference(Ws, ax))) / 8.0
                    interp = e if interp is None else interp + e
            if interp is not None:
                terms["interpolation_space"] = max(terms["interpolation_space"], finite_max(interp))
            return motion, interp

        @lru_cache(maxsize=c_t + 3)
        def time_terms(j: int) -> tuple[np.ndarray, np.ndarray | None]:
            """Interval ``j``: ``dt |dW/dt|`` and the time-interpolation error, per cell."""
            slope = dt * dilate_space(_cell_max(np.abs(snap(j + 1) - snap(j)) / dsnap[j]))
            terms["time"] = max(terms["time"], finite_max(slope))
            err = None
            if interpolation_error:
                # second divided difference in time at the interval's end snapshots (any spacing)
                err = np.zeros(slope.shape)
                for s in (j, j + 1):
                    if 0 < s < nt - 1:
                        d2 = np.abs((snap(s + 1) - snap(s)) / dsnap[s] - (snap(s) - snap(s - 1)) / dsnap[s - 1])
                        d2 *= 2.0 / (dsnap[s] + dsnap[s - 1]) * dsnap[j] ** 2 / 8.0
                        err = np.maximum(err, dilate_space(_cell_max(d2)))
                terms["interpolation_time"] = max(terms["interpolation_time"], finite_max(err))
            return slope, err

        # pooling factor: the smallest integer (same on every axis) that fits the memory budget
        cells = np.array([g - 1 for g in grid.shape])
        pool = 1
        while (nt - 1) * int(np.prod(np.ceil(cells / pool))) * 4 > max_bytes and pool < int(cells.max()):
            pool += 1
        pooled_shape = tuple(int(math.ceil(c / pool)) for c in cells)
        field = np.empty((nt - 1, *pooled_shape), dtype=np.float32)
        for k in range(nt - 1):
            # [t, t + dt] with t in [t_k, t_k+1] touches snapshots k .. k + 1 + c_t and intervals k .. k + c_t
            snaps = range(k, min(k + 1 + c_t, nt - 1) + 1)
            intervals = range(k, min(k + c_t, nt - 2) + 1)
            m = _max_of(space_terms(s)[0] for s in snaps) + _max_of(time_terms(j)[0] for j in intervals)
            if interpolation_error:
                m = m + _max_of(space_terms(s)[1] for s in snaps) + _max_of(time_terms(j)[1] for j in intervals)
            # NaN in the table makes a margin unknown: treat it as infinite (never pass there)
            m = np.where(np.isnan(m), np.inf, m)
            if pool > 1:
                m = _pool_max(m, pool)
            # round up so that float32 storage never shrinks a margin
            m32 = m.astype(np.float32)
            field[k] = np.where(m32 < m, np.nextafter(m32, np.float32(np.inf)), m32)
        return cls(field=field, pool=(pool,) * D, dt=float(dt), reach_cells=tuple(reach), terms=terms)


def _max_of(arrays) -> np.ndarray:
    """Elementwise max of an iterable of equally shaped arrays."""
    out = None
    for a in arrays:
        out = a if out is None else np.maximum(out, a)
    return out


def _pool_max(arr: np.ndarray, p: int) -> np.ndarray:
    """Max over blocks of ``p`` cells along every axis (the last block may be shorter)."""
    for ax in range(arr.ndim):
        n = arr.shape[ax]
        pad = (-n) % p
        if pad:
            widths = [(0, 0)] * arr.ndim
            widths[ax] = (0, pad)
            arr = np.pad(arr, widths, mode="edge")
        shape = arr.shape[:ax] + (arr.shape[ax] // p, p) + arr.shape[ax + 1:]
        arr = arr.reshape(shape).max(axis=ax + 1)
    return arr


# --------------------------------------------------------------------------------------------- rules
def switch_rule(value: np.ndarray, margin: np.ndarray, policy_action: np.ndarray,
                optimal_action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The least-restrictive switch: the policy's action where ``value <= -margin``, ``a*`` elsewhere.

    A NaN value or margin compares false, so it selects ``a*``.

    :param value: ``(N,)`` ``W~(t, x, z)``
    :param margin: ``(N,)`` margins
    :param policy_action: ``(N, m)``
    :param optimal_action: ``(N, m)``
    :return: ``(applied (N, m), active (N,))``; ``active`` where ``a*`` replaced the policy's action
    """
    passes = value <= -margin
    return np.where(passes[:, None], policy_action, optimal_action), ~passes


def smooth_rule(value: np.ndarray, margin: np.ndarray, policy_action: np.ndarray, optimal_action: np.ndarray,
                predict: Callable[[np.ndarray, np.ndarray], np.ndarray], iterations: int = 10,
                tolerance: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The closest action to the policy's that keeps the value from increasing over the next period.

    Where ``value <= -margin`` the policy's action passes (as with :func:`switch_rule`). Elsewhere, with
    ``a(lam) = a* + lam (a_pol - a*)``, it returns ``a(lam)`` for the largest ``lam in [0, 1]`` found by
    bisection with ``predict(a(lam)) <= value + tolerance``; ``a*`` itself when ``lam = 0`` is the only point
    found (including when ``a*`` fails the test, or the value is not finite). For a scalar action the segment
    is the whole side of the action interval that faces the policy, so this is the closest admissible action
    whenever the predicted value is monotone along it (it is affine in the action for the point mass).

    :param value: ``(N,)`` current values
    :param margin: ``(N,)`` margins
    :param policy_action: ``(N, m)``
    :param optimal_action: ``(N, m)``
    :param predict: ``(rows (K,), actions (K, m)) -> (K,)`` the worst-case value after one period from the
        states ``rows`` (indices into the batch) under ``actions``
    :param iterations: bisection steps (the blend is resolved to ``2^-iterations`` of the segment)
    :param tolerance: allowed increase of the value per period (default 0)
    :return: ``(applied (N, m), lam (N,))``; ``lam = 1`` where the policy's action passes unchanged
    """
    N = len(value)
    lam = np.ones(N)
    passes = value <= -margin
    todo = np.nonzero(~passes)[0]
    if len(todo) == 0:
        return policy_action.copy(), lam
    lam[todo] = 0.0
    finite = np.isfinite(value[todo])
    todo = todo[finite]
    if len(todo):
        a_pol, a_opt = policy_action[todo], optimal_action[todo]
        bound = value[todo] + tolerance
        # both ends at once: the policy's action (lam = 1) and a* (lam = 0)
        both = predict(np.concatenate([todo, todo]), np.concatenate([a_pol, a_opt]))
        ok_pol, ok_opt = both[: len(todo)] <= bound, both[len(todo):] <= bound
        lam[todo[ok_pol]] = 1.0
        search = ~ok_pol & ok_opt
        rows = todo[search]
        lo = np.zeros(len(rows))
        hi = np.ones(len(rows))
        a_pol, a_opt, bound = a_pol[search], a_opt[search], bound[search]
        for _ in range(iterations if len(rows) else 0):
            mid = 0.5 * (lo + hi)
            cand = a_opt + mid[:, None] * (a_pol - a_opt)
            ok = predict(rows, cand) <= bound
            lo = np.where(ok, mid, lo)
            hi = np.where(ok, hi, mid)
        lam[rows] = lo
    applied = optimal_action + lam[:, None] * (policy_action - optimal_action)
    # exact copies at the ends (no rounding of a* or of the policy's action)
    applied = np.where((lam == 1.0)[:, None], policy_action, applied)
    applied = np.where((lam == 0.0)[:, None], optimal_action, applied)
    return applied, lam


# --------------------------------------------------------------------------------------------- the filter
def _to_numpy(v: Any) -> tuple[np.ndarray, Any]:
    """A float64 numpy copy of ``v`` and the tensor it came from (``None`` for non-tensors)."""
    if torch is not None and isinstance(v, torch.Tensor):
        return v.detach().to("cpu", torch.float64).numpy(), v
    return np.asarray(v, dtype=np.float64), None


def _first_bad(arr: np.ndarray) -> str:
    bad = ~np.isfinite(arr)
    if arr.ndim == 2:
        row = int(np.nonzero(bad.any(axis=1))[0][0])
        return f"{arr[row].tolist()} at row {row}"
    if arr.ndim == 1:
        i = int(np.nonzero(bad)[0][0])
        return f"{arr[i]!r} at index {i}"
    return repr(float(arr))


class ValueFilter:
    """The safety filter's core: one ``W_eps`` table, one control period, one rule.

    :param table: a table with ``W_eps`` (see :func:`softreach.reach.load_table`)
    :param dt: the control period [s] over which an action is held
    :param margin: ``None`` (default) for the computed margin field (:class:`MarginField`), or a constant
        ``>= 0`` of your own, in the value's units (those of the soft constraint ``c2``)
    :param rule: ``"switch"`` (least restrictive) or ``"smooth"`` (see the module docstring)
    :param model: if given, the table must have been solved for it (name and parameters), else
        :class:`~softreach.reach.TableError`; by default the table's own model is used
    :param fallback_action: physical action applied where even ``a*`` is undefined (non-finite gradient);
        default the centre of the model's control box
    :param smooth_iterations: bisection steps of the smooth rule
    :param smooth_tolerance: allowed value increase per period in the smooth rule (default 0)
    :param interpolation_error: include the interpolation terms in the computed margin
    :param max_margin_bytes: memory budget of the margin field (larger tables are max-pooled)
    :param eps: the ``h_eps`` width used to predict the budget in the smooth rule (default: the table's)
    :param layout: how :class:`TableField` reads the table (``"stacked"``, ``"stencil"``; default: stacked when
        the copy fits 1 GiB)
    """

    def __init__(self, table: Table, dt: float, *, margin: float | None = None, rule: str = "switch",
                 model: Any = None, fallback_action: Any = None, smooth_iterations: int = 10,
                 smooth_tolerance: float = 0.0, interpolation_error: bool = True,
                 max_margin_bytes: int = 256 * 2**20, eps: float | None = None, layout: str | None = None):
        if not isinstance(table, Table):
            raise TypeError(f"table must be a softreach.reach.Table (load_table(path)), got {type(table).__name__}")
        if rule not in RULES:
            raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
        if not (isinstance(dt, (int, float, np.floating)) and not isinstance(dt, bool) and math.isfinite(dt)
                and dt > 0):
            raise ValueError(f"dt must be a finite positive number of seconds, got {dt!r}")
        if margin is not None and not (isinstance(margin, (int, float, np.floating)) and not isinstance(margin, bool)
                                       and math.isfinite(margin) and margin >= 0):
            raise ValueError(f"margin must be None (computed) or a finite number >= 0, got {margin!r}")
        if not (isinstance(smooth_iterations, (int, np.integer)) and smooth_iterations >= 0):
            raise ValueError(f"smooth_iterations must be a non-negative integer, got {smooth_iterations!r}")
        if not (math.isfinite(smooth_tolerance) and smooth_tolerance >= 0):
            raise ValueError(f"smooth_tolerance must be a finite number >= 0, got {smooth_tolerance!r}")
        if model is not None:
            table.check_compatible(model)  # TableError on another model or other parameters
        self.table = table
        self.model = model if model is not None else table.model
        self.field = TableField(table, layout=layout)
        if self.field.n != self.model.state_dim:
            raise TableError(f"table {table.path} has {self.field.n} states, the model {self.model.state_dim}")
        self.dt = float(dt)
        self.rule = rule
        self.smooth_iterations = int(smooth_iterations)
        self.smooth_tolerance = float(smooth_tolerance)
        self.eps = float(table.eps if eps is None else eps)
        #: below this budget a* is read at it (the Table API's convention; half a budget cell)
        self.budget_resolution = float(getattr(table, "budget_resolution", 0.0))
        self.n, self.m, self.k = self.model.state_dim, self.model.control_dim, self.model.disturbance_dim
        self.a_lo = np.array(self.model.control_bounds[0], dtype=np.float64)
        self.a_hi = np.array(self.model.control_bounds[1], dtype=np.float64)
        self.a_mid = 0.5 * (self.a_lo + self.a_hi)
        self.a_half = 0.5 * (self.a_hi - self.a_lo)
        self.b_lo = np.array(self.model.disturbance_bounds[0], dtype=np.float64)
        self.b_hi = np.array(self.model.disturbance_bounds[1], dtype=np.float64)
        self.wind_corners = np.array(list(itertools.product(*zip(self.b_lo, self.b_hi))), dtype=np.float64)
        if fallback_action is None:
            self.fallback_action = self.a_mid.copy()
        else:
            fb = np.asarray(fallback_action, dtype=np.float64).reshape(-1)
            if fb.shape != (self.m,) or not np.all(np.isfinite(fb)):
                raise ValueError(f"fallback_action must be {self.m} finite physical value(s), got {fallback_action!r}")
            self.fallback_action = np.clip(fb, self.a_lo, self.a_hi)
        self.constant_margin = None if margin is None else float(margin)
        self.margin_field = None
        if margin is None:
            self.margin_field = MarginField.compute(table, self.dt, interpolation_error=interpolation_error,
                                                    max_bytes=max_margin_bytes)

    # ---------------------------------------------------------------- conversions
    def physical(self, action: Any) -> np.ndarray:
        """Normalised ``[-1, 1]`` actions to physical ones (clipped; the environments' affine map)."""
        return self.a_mid + self.a_half * np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)

    def normalized(self, physical: Any) -> np.ndarray:
        """Physical actions to the normalised ``[-1, 1]`` space (inverse of :meth:`physical`)."""
        return (np.asarray(physical, dtype=np.float64) - self.a_mid) / self.a_half

    # ---------------------------------------------------------------- inputs
    def _inputs(self, t: Any, x: Any, z: Any, action: Any | None):
        xs, x_tensor = _to_numpy(x)
        single = xs.ndim == 1
        if single:
            xs = xs[None, :]
        if xs.ndim != 2 or xs.shape[1] != self.n:
            raise ValueError(f"x must have shape (N, {self.n}) or ({self.n},) (states {self.model.state_names}), "
                             f"got {tuple(np.shape(x))}")
        N = len(xs)
        cols = []
        for name, v in (("t", t), ("z", z)):
            arr, _ = _to_numpy(v)
            arr = arr.reshape(-1)
            if arr.size == 1:
                arr = np.full(N, float(arr[0]))
            if arr.shape != (N,):
                raise ValueError(f"{name} must be a scalar or have shape ({N},), got {tuple(np.shape(v))}")
            cols.append(arr)
        tt, zz = cols
        for name, arr in (("x", xs), ("t", tt), ("z", zz)):
            if not np.isfinite(arr).all():
                raise ValueError(f"{name} must be finite, got {_first_bad(arr)}")
        act = tensor = None
        if action is not None:
            act, tensor = _to_numpy(action)
            if act.ndim == 1 and single:
                act = act[None, :]
            if act.ndim != 2 or act.shape != (N, self.m):
                raise ValueError(f"action must have shape ({N}, {self.m})" + (f" or ({self.m},)" if single else "")
                                 + f" to match x, got {tuple(np.shape(action))}")
            if not np.isfinite(act).all():
                raise ValueError(f"action must be finite, got {_first_bad(act)}")
        ref = tensor if tensor is not None else x_tensor
        return tt, xs, zz, act, single, ref

    # ---------------------------------------------------------------- queries
    def _evaluate(self, tt: np.ndarray, xs: np.ndarray, zz: np.ndarray):
        """Value, margin, ``a*``, gradient and location flags (``inside``, ``after``) of a validated batch."""
        N = len(xs)
        X = np.concatenate([xs, zz[:, None]], axis=1)
        low = np.nonzero(zz < self.budget_resolution)[0]
        if len(low):
            # Table.optimal_control's convention: below the smallest budget the grid resolves, the gradient is read
            # there (at z = 0 the exact W_eps is flat and its gradient says nothing); value and margin are not.
            # One call serves both: rows N.. repeat the low-budget queries at their own budget.
            Xg = X.copy()
            Xg[low, -1] = self.budget_resolution
            value, grad, loc = self.field.value_and_gradient(np.concatenate([tt, tt[low]]),
                                                             np.concatenate([Xg, X[low]]))
            value[low] = value[N:]
            value = value[:N]
            grad = grad[:N]
            for key in ("inside", "after", "I", "k"):
                arr = loc[key]
                arr[low] = arr[N:]
                loc[key] = arr[:N]
        else:
            value, grad, loc = self.field.value_and_gradient(tt, X)
        comps = [X[:, i] for i in range(self.n)]
        # the optimal inputs depend on the gradient only through the model's closed form; z enters neither
        t_arg = float(tt[0]) if tt[0] == tt[-1] and np.all(tt == tt[0]) else tt
        p = [grad[:, i] for i in range(self.n)]
        a_star = np.stack([np.broadcast_to(np.asarray(o, dtype=np.float64), (N,))
                           for o in self.model.optimal_control(t_arg, comps, p)], axis=1)
        if self.margin_field is None:
            margin = np.full(N, self.constant_margin)
        else:
            margin = self.margin_field.lookup(loc)
        return value, margin, a_star, grad, loc

    def value(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """``W~(t, x, z)`` (the table's interpolant; ``+inf`` outside) for a batch; numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        out = self.field.value(tt, np.concatenate([xs, zz[:, None]], axis=1))
        return out[0] if single else out

    def margin(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The margin at each query (the constant, or the computed field's entry); numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        if self.margin_field is None:
            out = np.full(len(xs), self.constant_margin)
        else:
            out = self.margin_field.lookup(self.field.locate(tt, np.concatenate([xs, zz[:, None]], axis=1)))
        return out[0] if single else out

    def optimal_action(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The table's ``a*(t, x, z)``, ``(N, m)`` physical (as :meth:`Table.optimal_control`); numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        out = self._evaluate(tt, xs, zz)[2]
        return out[0] if single else out

    def worst_disturbance(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """The table's ``b*(t, x, z)``, ``(N, k)`` physical (as :meth:`Table.worst_disturbance`); numpy out."""
        tt, xs, zz, _, single, _ = self._inputs(t, x, z, None)
        grad = self._evaluate(tt, xs, zz)[3]
        out = self._worst(tt, xs, grad)
        return out[0] if single else out

    def _worst(self, tt: np.ndarray, xs: np.ndarray, grad: np.ndarray) -> np.ndarray:
        t_arg = float(tt[0]) if np.all(tt == tt[0]) else tt
        comps = [xs[:, i] for i in range(self.n)]
        out = self.model.worst_disturbance(t_arg, comps, [grad[:, i] for i in range(self.n)])
        return np.stack([np.broadcast_to(np.asarray(o, dtype=np.float64), (len(xs),)) for o in out], axis=1)

    # ---------------------------------------------------------------- prediction (smooth rule)
    def _rhs(self, t: float | np.ndarray, x: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        comps = [x[:, i] for i in range(self.n)]
        f = self.model.f(t, comps, [a[:, j] for j in range(self.m)], [b[:, j] for j in range(self.k)])
        fx = np.stack([np.broadcast_to(np.asarray(fi, dtype=np.float64), (len(x),)) for fi in f], axis=1)
        fz = -np.asarray(self.model.violation_rate(t, comps, self.eps), dtype=np.float64) * np.ones(len(x))
        return fx, fz

    def predicted_value(self, t: np.ndarray, x: np.ndarray, z: np.ndarray, a: np.ndarray,
                        winds: np.ndarray) -> np.ndarray:
        """Worst predicted ``W~`` after one period: one Heun (RK2) step of ``(x, z)`` with ``a`` and each wind.

        :param t: ``(N,)`` times
        :param x: ``(N, n)`` states
        :param z: ``(N,)`` budgets
        :param a: ``(N, m)`` physical actions
        :param winds: ``(N, J, k)`` candidate winds per row (the table's ``b*`` and the box corners)
        :return: ``(N,)`` the largest predicted value over the winds (``+inf`` where a prediction leaves the table)
        """
        N, J = winds.shape[0], winds.shape[1]
        rep = lambda v: np.repeat(v, J, axis=0)  # noqa: E731 - row-major: each row's winds are contiguous
        tt, xx, zz, aa = rep(t), rep(x), rep(z), rep(a)
        bb = winds.reshape(N * J, self.k)
        dt = self.dt
        f1, g1 = self._rhs(tt, xx, aa, bb)
        f2, g2 = self._rhs(tt + dt, xx + dt * f1, aa, bb)
        x1 = xx + 0.5 * dt * (f1 + f2)
        z1 = zz + 0.5 * dt * (g1 + g2)
        bad = ~np.isfinite(x1).all(axis=1) | ~np.isfinite(z1)
        x1 = np.where(bad[:, None], 0.0, x1)
        z1 = np.where(bad, 0.0, z1)
        v = self.field.value(tt + dt, np.concatenate([x1, z1[:, None]], axis=1))
        v = np.where(bad | np.isnan(v), np.inf, v)
        return v.reshape(N, J).max(axis=1)

    # ---------------------------------------------------------------- the filter
    def filter(self, t: Any, x: Any, z: Any, action: Any, *, normalized: bool = False):
        """Filter a batch of actions.

        :param t: time(s) [s], scalar or ``(N,)``
        :param x: state(s), ``(N, n)`` or ``(n,)``, physical units
        :param z: remaining budget(s) [s], scalar or ``(N,)``
        :param action: the policy's action(s), ``(N, m)`` or ``(m,)``: physical units, or ``[-1, 1]`` with
            ``normalized=True`` (then every returned action is normalised too)
        :return: ``(applied, info)``: ``applied`` has the shape of ``action`` (where the policy's action passes:
            the numbers given, with ``normalized=True``, so that an environment receives them bit for bit; clipped
            to the control box otherwise); ``info`` holds ``value`` (``W~``,
            ``+inf`` outside the table), ``margin``, ``active`` (the filter changed the action), ``reason``
            (codes of :data:`REASONS`), ``optimal_action`` (``a*``, ``(N, m)``), ``blend`` (``1`` where the
            policy's action passed, ``0`` where ``a*`` was applied). Numpy in, numpy out; torch in, torch out
            (action's dtype and device; ``active`` as ``bool``, ``reason`` as ``int64``).
        :raises ValueError: non-finite or wrongly shaped inputs
        """
        if self.rule == "switch":
            fast = self._filter_single(t, x, z, action, normalized)
            if fast is not None:
                return fast
        tt, xs, zz, act, single, ref = self._inputs(t, x, z, action)
        # np.minimum/np.maximum rather than np.clip: the same result, without np.clip's Python-level dispatch
        pol = self.physical(act) if normalized else np.minimum(np.maximum(act, self.a_lo), self.a_hi)
        value, margin, a_star, grad, loc = self._evaluate(tt, xs, zz)

        # a* where defined; the fallback where not. A NaN gradient must be caught here: the models' bang-bang
        # closed forms map it silently to the middle of the box (neither sign test holds)
        a_ok = np.isfinite(a_star).all(axis=1) & np.isfinite(grad).all(axis=1)
        all_ok = bool(a_ok.all())
        if not all_ok:
            a_star = np.where(a_ok[:, None], a_star, self.fallback_action)
        a_star = np.minimum(np.maximum(a_star, self.a_lo), self.a_hi)

        if self.rule == "switch":
            applied, active = switch_rule(value, margin, pol, a_star)
            lam = (~active).astype(np.float64)
            reason = np.where(active, OPTIMAL, PASS)
        else:
            def predict(rows: np.ndarray, a: np.ndarray) -> np.ndarray:
                winds = np.concatenate([
                    self._worst(tt[rows], xs[rows], grad[rows])[:, None, :],
                    np.broadcast_to(self.wind_corners, (len(rows),) + self.wind_corners.shape),
                ], axis=1)
                return self.predicted_value(tt[rows], xs[rows], zz[rows], a, winds)

            applied, lam = smooth_rule(value, margin, pol, a_star, predict, self.smooth_iterations,
                                       self.smooth_tolerance)
            active = lam < 1.0
            reason = np.where(active, np.where(lam > 0.0, BLEND, OPTIMAL), PASS)
        if not (loc["inside"].all() and np.isfinite(value).all()):
            reason = np.where(~loc["inside"], np.where(loc["after"], AFTER_HORIZON, OUTSIDE), reason)
            reason = np.where(np.isnan(value), NONFINITE, reason)
        if not all_ok:
            reason = np.where(~a_ok & active & (lam == 0.0), FALLBACK, reason)
        reason = reason.astype(np.int64, copy=False)

        if normalized:
            applied = np.where(active[:, None], np.clip(self.normalized(applied), -1.0, 1.0), act)
            a_star = self.normalized(a_star)
        info = {"value": value, "margin": margin, "active": active, "reason": reason,
                "optimal_action": a_star, "blend": lam}
        if single:
            applied = applied[0]
            info = {k: v[0] for k, v in info.items()}
        if ref is not None:
            return _to_torch(applied, info, ref, action)
        return applied, info

    __call__ = filter

    def _filter_single(self, t: Any, x: Any, z: Any, action: Any, normalized: bool):
        """One query of the switch rule in Python floats: the same answer as the batch path, several times
        faster (numpy's per-call overhead dominates a batch of one). ``None`` where the batch path must answer
        (anything unusual: arrays, tensors, bad values, edge cells, non-finite ``a*``), which also raises the
        errors."""
        scalar = (int, float, np.floating, np.integer)
        if not (isinstance(t, scalar) and isinstance(z, scalar) and not isinstance(t, bool)
                and not isinstance(z, bool)):
            return None
        if isinstance(x, np.ndarray) and x.shape == (self.n,) and x.dtype.kind == "f":
            xs = x.tolist()
        elif isinstance(x, (list, tuple)) and len(x) == self.n and all(isinstance(v, scalar) for v in x):
            xs = [float(v) for v in x]
        else:
            return None
        if isinstance(action, np.ndarray) and action.shape == (self.m,) and action.dtype.kind == "f":
            act = action.tolist()
        elif isinstance(action, (list, tuple)) and len(action) == self.m and all(isinstance(v, scalar) for v in action):
            act = [float(v) for v in action]
        else:
            return None
        tf, zf = float(t), float(z)
        if not all(math.isfinite(v) for v in xs + act + [tf, zf]):
            return None
        found = self.field.single(tf, xs + [zf])
        if found is None:
            return None
        value, grad, k, I, inside, after = found
        if zf < self.budget_resolution:  # a* at the smallest resolved budget (see _evaluate)
            found = self.field.single(tf, xs + [self.budget_resolution])
            if found is None:
                return None
            grad = found[1]
        if not all(math.isfinite(v) for v in grad):
            return None
        a_star = [float(v) for v in self.model.optimal_control(tf, xs, grad)]
        if not all(math.isfinite(v) for v in a_star):
            return None
        if self.margin_field is None:
            margin = self.constant_margin
        else:
            mf = self.margin_field
            if mf.pool[0] != 1:
                I = [i // p for i, p in zip(I, mf.pool)]
            margin = float(mf.field[(min(k, mf.field.shape[0] - 1), *I)])
        lo, hi = self.a_lo.tolist(), self.a_hi.tolist()
        if normalized:
            mid, half = self.a_mid.tolist(), self.a_half.tolist()
            pol = [m_ + h_ * (1.0 if v > 1.0 else (-1.0 if v < -1.0 else v)) for v, m_, h_ in zip(act, mid, half)]
        else:
            pol = [l_ if v < l_ else (h_ if v > h_ else v) for v, l_, h_ in zip(act, lo, hi)]
        a_star = [l_ if v < l_ else (h_ if v > h_ else v) for v, l_, h_ in zip(a_star, lo, hi)]
        passes = value <= -margin
        if not inside:
            reason = AFTER_HORIZON if after else OUTSIDE
        elif value != value:  # NaN
            reason = NONFINITE
        else:
            reason = PASS if passes else OPTIMAL
        if normalized:
            a_out = self.normalized(a_star)
            applied = np.array(act, dtype=np.float64) if passes else np.clip(a_out, -1.0, 1.0)
        else:
            a_out = np.array(a_star)
            applied = np.array(pol if passes else a_star)
        info = {"value": np.float64(value), "margin": np.float64(margin), "active": np.bool_(not passes),
                "reason": np.int64(reason), "optimal_action": a_out, "blend": np.float64(1.0 if passes else 0.0)}
        return applied, info


def _to_torch(applied: np.ndarray, info: dict[str, Any], ref: Any, action: Any):
    """Convert the outputs to tensors on the reference tensor's device, in its floating dtype."""
    dtype = ref.dtype if ref.dtype.is_floating_point else torch.float32
    if torch is not None and isinstance(action, torch.Tensor) and action.dtype.is_floating_point:
        dtype_a = action.dtype
    else:
        dtype_a = dtype
    dev = ref.device
    out = {}
    for key, v in info.items():
        if key == "active":
            out[key] = torch.as_tensor(np.asarray(v), dtype=torch.bool, device=dev)
        elif key == "reason":
            out[key] = torch.as_tensor(np.asarray(v), dtype=torch.int64, device=dev)
        elif key == "optimal_action":
            out[key] = torch.as_tensor(np.asarray(v), dtype=dtype_a, device=dev)
        else:
            out[key] = torch.as_tensor(np.asarray(v), dtype=dtype, device=dev)
    return torch.as_tensor(np.asarray(applied), dtype=dtype_a, device=dev), out
