"""The exact maximum of a table's interpolant over boxes of states (:mod:`softreach.reach.proof.lookahead`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..numerics.grid import Grid
from ..tables.interpolation import geometry
from .kernels import box_max_rows, frozen


def box_max(values: np.ndarray, times: np.ndarray, grid: Grid, t: np.ndarray, lo: np.ndarray,
            hi: np.ndarray, max_nodes: int = 3) -> np.ndarray:
    """The maximum of the interpolant at time ``t[j]`` over the box ``[lo[j], hi[j]]``, per row.

    Multilinear in each grid cell, its maximum is at a corner of a sub-box the grid cuts the box into. A box with
    more than ``max_nodes`` nodes along an axis takes the largest node value of the cells it touches (an upper
    bound: in a cell the interpolant is a convex combination of its nodes); a box off the grid gets ``+inf``.

    :param values: ``(len(times), *grid.shape)``
    :param t: ``(N,)`` query times, inside the table's span
    :param lo: ``(N, d)`` lower corners; ``hi`` the upper ones
    :param max_nodes: the most nodes per axis for the exact maximum
    :return: ``(N,)`` float64
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    out = np.empty(len(lo))
    t = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (len(lo),)))
    box_max_rows(kernel_field(values, times, grid), t, lo, hi, int(max_nodes), out)
    return out


def kernel_field(values: Any, times: Any, grid: Grid) -> tuple:
    """A field as the compiled loops read it: values ``(n_times, size)`` (a memory map stays mapped), times, grid."""
    g = geometry(grid)
    return (frozen(np.asarray(values).reshape(len(times), -1)), frozen(np.asarray(times, dtype=np.float64)), g.shape,
            g.lo, g.hi, g.h, g.inv_h, g.periodic)
