"""The budget integral ``int h_eps(t, x(t)) dt`` over RK4 sub-steps, exact at the kinks of ``h_eps``.

``h_eps = min(1, max(0, c2 / eps))`` is only Lipschitz: it has kinks where the path enters or leaves ``C2``
(``c2 = 0``) and where it crosses the top of the ``eps`` band (``c2 = eps``). A Simpson-type sum of the four RK4
stage rates (the plain RK4 increment of ``z' = -h_eps``) is then off by a fraction of a sub-step at every
crossing. The rule here (:func:`budget_piece`), per sub-step from its four stage rates:

* all ``0`` (inside ``C2``): cost ``0``; all ``1`` (beyond the band): cost exactly the sub-step's length;
* all strictly inside the band: Simpson's sum (``h_eps`` is as smooth as ``c2`` there);
* otherwise the sub-step holds a kink: :func:`kink_costs` integrates ``h_eps`` along the RK4 dense output (the
  cubic Hermite interpolant of the step), refining the cells that hold a kink until they are shorter than the
  resolution, so the budget drains by the violation time to within a fraction of that resolution per crossing.

Everything works on many sub-steps at once (arrays over sub-steps and states); the single-state integrator
calls the same functions with one row. The state path does not depend on any of this.
"""

from __future__ import annotations

import operator
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..problem import Model


def simpson(v0: Any, v1: Any, v2: Any, v3: Any, h: float) -> Any:
    """Simpson's sum of the four RK4 stage values over a step of length ``h`` (floats or arrays)."""
    return h / 6.0 * (v0 + 2.0 * v1 + 2.0 * v2 + v3)


def settled(lo: Any, hi: Any) -> Any:
    """Whether ``h_eps`` has no kink between values whose least is ``lo`` and largest ``hi``: all ``0`` (inside
    ``C2``), all ``1`` (beyond the band) or all strictly inside the band (floats, or arrays elementwise)."""
    return (hi == 0.0) | (lo == 1.0) | ((lo > 0.0) & (hi < 1.0))


class _FloatOps:
    """The numpy functions :func:`budget_piece` uses, for Python floats: one state's sub-steps are decided
    without numpy's per-call cost (about a microsecond each, as much as the rest of a sub-step)."""

    minimum = staticmethod(min)
    maximum = staticmethod(max)
    logical_not = staticmethod(operator.not_)

    @staticmethod
    def where(condition: bool, x: float, y: float) -> float:
        """``numpy.where`` for one value.

        :param condition: which to take
        :param x: the value where ``condition``
        :param y: the value elsewhere
        """
        return x if condition else y


#: :func:`budget_piece`'s ``ops`` for stage rates given as Python floats
FLOATS = _FloatOps()

#: the cells into which :func:`kink_costs` cuts a sub-step, and each refined cell (the environments' number; the
#: filter's budget allowance counts the roundings of a sum over this many, :func:`~softreach.reach.proof.lookahead.
#: budget_allowance`)
KINK_SAMPLES = 128


def budget_piece(v0: Any, v1: Any, v2: Any, v3: Any, h: float, ops: Any = np) -> tuple[Any, Any]:
    """The budget spent over a sub-step from its four stage rates, and whether a kink needs :func:`kink_costs`.

    :param v0: ``h_eps`` at the first RK4 stage (``v1``, ``v2``, ``v3``: at the others), in ``[0, 1]``: floats,
        or arrays over many sub-steps
    :param h: the sub-step length [s]
    :param ops: ``numpy`` for arrays, :data:`FLOATS` for floats
    :return: ``(cost, kink)``: the cost (``0`` inside ``C2``, ``h`` beyond the band, else Simpson's sum, a
        placeholder where ``kink``) and whether the stages straddle a kink of ``h_eps``
    """
    lo = ops.minimum(ops.minimum(v0, v1), ops.minimum(v2, v3))
    hi = ops.maximum(ops.maximum(v0, v1), ops.maximum(v2, v3))
    cost = ops.where(lo == 1.0, h, ops.where(hi == 0.0, 0.0, simpson(v0, v1, v2, v3, h)))
    return cost, ops.logical_not(settled(lo, hi))


def hermite_basis(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cubic Hermite basis at ``theta``: ``h00``, ``h10 / h``, ``h01``, ``h11 / h``."""
    t2 = theta * theta
    t3 = t2 * theta
    return 2.0 * t3 - 3.0 * t2 + 1.0, t3 - 2.0 * t2 + theta, 3.0 * t2 - 2.0 * t3, t3 - t2


def hermite(theta: np.ndarray, x0: Sequence[Any], f0: Sequence[Any], x1: Sequence[Any], f1: Sequence[Any],
            h: float, basis: tuple[np.ndarray, ...] | None = None) -> list[np.ndarray]:
    """The cubic Hermite dense output of a step at fractions ``theta`` of it (exact for cubic paths).

    :param theta: fractions of the step, broadcasting against the components
    :param x0: start state, one float or array per component (``f0``, ``x1``, ``f1`` alike: ``f`` at the start,
        the end state, ``f`` at the end)
    :param h: the step length [s]
    :param basis: ``hermite_basis(theta)`` if already known
    """
    h00, p10, h01, p11 = hermite_basis(theta) if basis is None else basis
    h10 = p10 * h
    h11 = p11 * h
    return [h00 * p + h10 * fp + h01 * q + h11 * fq for p, fp, q, fq in zip(x0, f0, x1, f1)]


_KINK_GRIDS: dict[int, tuple[np.ndarray, tuple[np.ndarray, ...]]] = {}


def kink_grid(samples: int) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """``linspace(0, 1, samples + 1)`` and the Hermite basis there (read-only; the first level of every
    :func:`kink_costs` samples exactly these fractions)."""
    out = _KINK_GRIDS.get(samples)
    if out is None:
        grid = np.linspace(0.0, 1.0, samples + 1)
        basis = hermite_basis(grid)
        for arr in (grid, *basis):
            arr.flags.writeable = False
        out = _KINK_GRIDS[samples] = (grid, basis)
    return out


def kink_costs(model: Model, t0: np.ndarray, h: float, x0: np.ndarray, f0: np.ndarray, x1: np.ndarray,
               f1: np.ndarray, eps: float, resolution: float, samples: int = KINK_SAMPLES, max_levels: int = 8
               ) -> np.ndarray:
    """``int h_eps dt`` over ``K`` sub-steps in each of which ``h_eps`` has a kink.

    ``h_eps`` is sampled along the cubic Hermite interpolant of each step at ``samples`` cells, all steps in
    one vectorised call of ``model.violation_rate``; cells that lie inside, outside or in the ``eps`` band
    throughout are summed (``0``, their length, trapezoid), the few cells that hold a kink are sampled again in
    the same way, until a cell is shorter than ``resolution`` (then: trapezoid, an error below half the cell
    per kink).

    :param model: the model whose ``violation_rate`` is integrated
    :param t0: ``(K,)`` start times of the sub-steps [s]
    :param h: their common length [s]
    :param x0: ``(K, n)`` start states; ``f0``: ``f`` there; ``x1``: ``(K, n)`` end states; ``f1``: ``f`` there
    :param eps: the ``eps`` of ``h_eps``
    :param resolution: refine kink cells until they are this short [s]
    :param samples: cells per refined cell
    :param max_levels: refinement levels at most
    :return: ``(K,)`` the integrals [s]
    """
    n_rows = len(x0)
    grid, basis = kink_grid(samples)
    # the ends' components against the samples: (K, 1) arrays, or floats for one sub-step (numpy multiplies a
    # float into an array faster than it broadcasts a (1, 1) array, and one sub-step is what an env step refines)
    single = n_rows == 1
    ends = [arr[0].tolist() if single else arr.T[:, :, None] for arr in (x0, f0, x1, f1)]
    rows = np.arange(n_rows)  # the step each refined cell belongs to
    starts = np.zeros(n_rows)  # where each refined cell starts, as a fraction of its step
    width = 1.0
    total = np.zeros(n_rows)
    for level in range(max_levels):
        if level == 0:  # the first level samples the grid itself, with its basis cached
            theta, t, path = grid[None, :], t0[:, None] + h * grid[None, :], hermite(grid, *ends, h, basis)
        else:
            theta = starts[:, None] + width * grid[None, :]
            t = t0[rows][:, None] + h * theta
            path = hermite(theta, *(ends if single else [e[:, rows] for e in ends]), h)
        r = model.violation_rate(t.reshape(-1), [p.reshape(-1) for p in path], eps)
        if not (type(r) is np.ndarray and r.dtype == np.float64 and r.size == t.size):
            r = np.broadcast_to(np.asarray(r, dtype=np.float64), (t.size,))
        r = r.reshape(t.shape)
        left, right = r[:, :-1], r[:, 1:]
        kink = ~settled(np.minimum(left, right), np.maximum(left, right))
        cell = width / samples * h
        last = cell <= resolution or level == max_levels - 1
        sums = np.sum(left + right if last else np.where(kink, 0.0, left + right), axis=1)
        total += cell * 0.5 * (sums if level == 0 else np.bincount(rows, sums, n_rows))
        if last or not kink.any():
            break
        cells, cols = np.nonzero(kink)
        rows, starts = rows[cells], starts[cells] + width * grid[cols]
        width /= samples
    return total
