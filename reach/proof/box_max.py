"""The exact maximum of a table's interpolant over boxes of states: the safety filter's one-period test
(:mod:`softreach.reach.proof.lookahead`) bounds the certificate over where holding an action can go."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..numerics.grid import Grid
from ..tables.interpolation import geometry
from .kernels import box_max_rows, frozen


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
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    out = np.empty(len(lo))
    t = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (len(lo),)))
    box_max_rows(kernel_field(values, times, grid), t, lo, hi, int(max_nodes), out)
    return out


def kernel_field(values: Any, times: Any, grid: Grid) -> tuple:
    """A field as the compiled loops read it (:mod:`softreach.reach.proof.kernels`): its values ``(n_times, size)`` (a
    memory map stays mapped), its snapshot times and its grid."""
    g = geometry(grid)
    # values and times come loaded (read-only) or made here (writable): read-only views, for one compilation
    return (frozen(np.asarray(values).reshape(len(times), -1)), frozen(np.asarray(times, dtype=np.float64)), g.shape,
            g.lo, g.hi, g.h, g.inv_h, g.periodic)
