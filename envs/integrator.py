"""The environments' integrator: one control period with the action and the wind held, and the budget with it.

Integration (:func:`integrate_period`): the control and the wind are held constant over a control period
(zero-order hold) and the state is advanced by ``n_substeps`` classical Runge-Kutta (RK4) steps. The budget
``z`` follows the augmented dynamics ``z' = -h_eps(t, x)`` of the paper: the same RK4 stages give its
increment, which is the Simpson-type quadrature of ``h_eps`` over the stage states. Sub-steps whose stages are
all inside ``C2`` (``h_eps = 0``) or all beyond the ``eps`` band (``h_eps = 1``) cost exactly ``0`` or their
length. ``h_eps`` is only Lipschitz, with kinks where ``c2 = 0`` and ``c2 = eps``; in a sub-step whose stage
values straddle a kink (the path enters or leaves ``C2``) the integral is instead taken along the RK4 dense
output (cubic Hermite interpolant), resolving the kink to ``budget_resolution`` seconds: the budget then drains
by the violation time to within about ``budget_resolution`` per crossing. The state path does not depend on
this (it is the fixed-step RK4 path); excursions out of ``C2`` shorter than a sub-step that no RK4 stage sees
are missed.

Events: the episode ends at the first sub-step end where the state is out of ``C1`` (a hard violation) or
landed (in the target and inside ``C2``), as in the paper's game, which ends when the target is reached at any
instant. The sub-steps are therefore also the instants at which landing is detected: the safety filter counts
on landing only at those instants (:class:`~softreach.reach.lookahead.Lookahead`, ``target_checks``).

Per-step speed (:func:`scalar_model`): a model may also define scalar versions of these methods
(``f_scalar``, ``violation_rate_scalar``, ``hard_constraint_scalar``, ``target_scalar``; the point mass does)
that take one point of Python floats and repeat the vectorised arithmetic without building arrays. The
environments then use them for the RK4 stages and the end-of-step checks; the results are the same, bit for
bit (tests/test_envs_fastpath.py). Otherwise, or where a subclass overrides a vectorised method but not its
scalar version, the vectorised methods are used as they are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

from softreach.reach.problem import Model

Stage = list  # list[float]: one state, one Python float per component


def rk4_stages(f: Callable, t: float, x: Sequence[float], a: Sequence[float], b: Sequence[float],
               h: float) -> tuple[list[float], list[Stage]]:
    """One classical RK4 step of ``x' = f(t, x, a, b)`` with ``a`` and ``b`` held constant.

    :param f: the model's vector field ``f(t, x, a, b)`` taking and returning sequences of components
    :param t: start time [s]
    :param x: start state, one float per component
    :param a: control, one float per component (physical units)
    :param b: disturbance, one float per component (physical units)
    :param h: step length [s]
    :return: the state at ``t + h`` and the four stage states ``[x, x + h/2 k1, x + h/2 k2, x + h k3]``
        (the points where RK4 evaluates ``f``; the budget quadrature evaluates ``h_eps`` there too)
    """
    hh = 0.5 * h
    k1 = f(t, x, a, b)
    x2 = [xi + hh * ki for xi, ki in zip(x, k1)]
    k2 = f(t + hh, x2, a, b)
    x3 = [xi + hh * ki for xi, ki in zip(x, k2)]
    k3 = f(t + hh, x3, a, b)
    x4 = [xi + h * ki for xi, ki in zip(x, k3)]
    k4 = f(t + h, x4, a, b)
    h6 = h / 6.0
    xn = [float(xi + h6 * (c1 + 2.0 * c2 + 2.0 * c3 + c4)) for xi, c1, c2, c3, c4 in zip(x, k1, k2, k3, k4)]
    return xn, [x, x2, x3, x4]


def _rates(model: Model, times: list[float], points: list[Stage], eps: float) -> list[float]:
    """``model.violation_rate`` at many points in one vectorised call."""
    n = len(points[0])
    comps = [np.array([p[i] for p in points], dtype=np.float64) for i in range(n)]
    r = model.violation_rate(np.array(times, dtype=np.float64), comps, eps)
    if not (isinstance(r, np.ndarray) and r.shape == (len(points),)):
        r = np.broadcast_to(np.asarray(r, dtype=np.float64), (len(points),))
    return r.tolist()


# classification of the h_eps values at the four RK4 stages of a (sub-)step
_INSIDE, _OUTSIDE, _SMOOTH, _KINK = 0, 1, 2, 3


def _classify(v: Sequence[float]) -> int:
    lo, hi = min(v), max(v)
    if hi == 0.0:
        return _INSIDE
    if lo == 1.0:
        return _OUTSIDE
    if lo > 0.0 and hi < 1.0:
        return _SMOOTH  # inside the eps band throughout: h_eps is as smooth as c2 there
    return _KINK


def _simpson(v: Sequence[float], h: float) -> float:
    return h / 6.0 * (v[0] + 2.0 * v[1] + 2.0 * v[2] + v[3])


def _piece_cost(v: Sequence[float], h: float) -> float | None:
    """The budget spent over a piece whose stage rates are ``v``, or ``None`` if the piece needs bisection."""
    kind = _classify(v)
    if kind == _INSIDE:
        return 0.0
    if kind == _OUTSIDE:
        return h
    if kind == _SMOOTH:
        return _simpson(v, h)
    return None


def _hermite_basis(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cubic Hermite basis at ``theta``: ``h00``, ``h10 / h``, ``h01``, ``h11 / h``."""
    t2 = theta * theta
    t3 = t2 * theta
    return 2.0 * t3 - 3.0 * t2 + 1.0, t3 - 2.0 * t2 + theta, 3.0 * t2 - 2.0 * t3, t3 - t2


def _hermite(theta: np.ndarray, x0: Stage, f0: Sequence[float], x1: Stage, f1: Sequence[float],
             h: float, basis: tuple[np.ndarray, ...] | None = None) -> list[np.ndarray]:
    """The cubic Hermite dense output of a step at fractions ``theta`` of it (exact for cubic paths).

    :param basis: ``_hermite_basis(theta)`` if already known
    """
    h00, p10, h01, p11 = _hermite_basis(theta) if basis is None else basis
    h10 = p10 * h
    h11 = p11 * h
    return [h00 * p + h10 * fp + h01 * q + h11 * fq for p, fp, q, fq in zip(x0, f0, x1, f1)]


_KINK_GRIDS: dict[int, tuple[np.ndarray, tuple[np.ndarray, ...]]] = {}


def _kink_grid(samples: int) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """``linspace(0, 1, samples + 1)`` and the Hermite basis there (read-only; the first level of every
    :func:`_kink_cost` samples exactly these fractions)."""
    out = _KINK_GRIDS.get(samples)
    if out is None:
        grid = np.linspace(0.0, 1.0, samples + 1)
        basis = _hermite_basis(grid)
        for arr in (grid, *basis):
            arr.flags.writeable = False
        out = _KINK_GRIDS[samples] = (grid, basis)
    return out


def _kink_cost(model: Model, t: float, x0: Stage, x1: Stage, a: Stage, b: Stage, h: float, eps: float,
               resolution: float, samples: int = 128, max_levels: int = 8, f: Callable | None = None) -> float:
    """``int h_eps dt`` over a sub-step in which ``h_eps`` has a kink (the path enters or leaves ``C2``).

    ``h_eps`` is sampled along the cubic Hermite interpolant of the RK4 step (end states and ``f`` there) at
    ``samples`` cells in one vectorised call of ``model.violation_rate``; cells that lie inside, outside or in
    the ``eps`` band throughout are summed (``0``, their length, trapezoid), the few cells that contain a kink
    are sampled again in the same way, until a cell is shorter than ``resolution`` (then: trapezoid, an error
    below half the cell per kink).

    :param f: the vector field to take ``f`` at the ends with (default ``model.f``; the scalar fast path passes
        its ``f_scalar``, which gives the same numbers)
    """
    if f is None:
        f = model.f
    f0, f1 = f(t, x0, a, b), f(t + h, x1, a, b)
    grid, basis = _kink_grid(samples)
    starts = np.zeros(1)
    width = 1.0
    total = 0.0
    for level in range(max_levels):
        if level == 0:
            theta = grid  # = (0 + 1 * grid): the first level samples the grid itself, with its basis cached
            path = _hermite(theta, x0, f0, x1, f1, h, basis)
        else:
            theta = (starts[:, None] + width * grid[None, :]).reshape(-1)
            path = _hermite(theta, x0, f0, x1, f1, h)
        r = model.violation_rate(t + h * theta, path, eps)
        if not (type(r) is np.ndarray and r.dtype == np.float64 and r.shape == theta.shape):
            r = np.broadcast_to(np.asarray(r, dtype=np.float64), theta.shape)
        r = r.reshape(len(starts), samples + 1)
        left, right = r[:, :-1], r[:, 1:]
        lo, hi = np.minimum(left, right), np.maximum(left, right)
        cell = width / samples * h
        kink = ~((hi == 0.0) | (lo == 1.0) | ((lo > 0.0) & (hi < 1.0)))
        last = cell <= resolution
        settled = ~kink | last
        total += cell * 0.5 * float(np.sum((left + right)[settled]))
        if last or not kink.any():
            return total
        rows, cols = np.nonzero(kink)
        starts = starts[rows] + width * grid[cols]
        width /= samples
    return total + cell * 0.5 * float(np.sum((left + right)[kink]))


_AUTO: Any = object()  # integrate_period(fast=...): look the model's scalar fast path up


def integrate_period(model: Model, t: float, x: Sequence[float], a: Sequence[float], b: Sequence[float],
                     h: float, n_substeps: int, eps: float, budget_resolution: float, *, fast: Any = _AUTO,
                     rate0: float | None = None, stop: Callable | None = None
                     ) -> tuple[list[float], float, float, float]:
    """Advance the budget-augmented state over one control period with ``a`` and ``b`` held.

    :param model: the model whose ``f`` and ``violation_rate`` are integrated
    :param t: start time [s]
    :param x: start state (physical), one float per component
    :param a: physical control
    :param b: physical disturbance
    :param h: period length [s]
    :param n_substeps: RK4 steps per period
    :param eps: the ``eps`` of ``h_eps``
    :param budget_resolution: resolve the kinks of ``h_eps`` (entering or leaving ``C2``) to this length [s]
    :param fast: the model's scalar fast path (:func:`scalar_model`), ``None`` for the vectorised methods;
        by default it is looked up. Both give the same numbers (the fast path repeats the same arithmetic).
    :param rate0: ``h_eps(t, x)`` if already known (the fast path then does not evaluate it again)
    :param stop: ``stop(t, x, rate) -> bool`` asked at every substep end (``rate`` is ``h_eps`` there); the
        period ends at the first substep where it says yes (the environments' events: landed, or out of ``C1``)
    :return: ``(x_end, cost, rate_end, elapsed)``: the state where the period ended, the budget spent
        ``int h_eps dt`` until then, ``h_eps`` at that state (``> 0`` exactly when it is outside ``C2``), and the
        time elapsed (``h`` unless ``stop`` ended it early)
    """
    if fast is _AUTO:
        fast = scalar_model(model)
    if fast is not None:
        return _integrate_period_scalar(fast, model, t, x, a, b, h, n_substeps, eps, budget_resolution, rate0,
                                        stop)
    f = model.f
    hs = h / n_substeps
    path: list[Stage] = [list(x)]
    points: list[Stage] = []
    times: list[float] = []
    xc = path[0]
    done = n_substeps
    for j in range(n_substeps):
        tc = t + j * hs
        xc, stages = rk4_stages(f, tc, xc, a, b, hs)
        path.append(xc)
        points.extend(stages)
        times.extend((tc, tc + 0.5 * hs, tc + 0.5 * hs, tc + hs))
        if stop is not None and j < n_substeps - 1:
            te = tc + hs
            if stop(te, xc, float(model.violation_rate(te, [np.float64(v) for v in xc], eps))):
                done = j + 1
                break
    points.append(xc)
    times.append(t + h if done == n_substeps else t + done * hs)
    r = _rates(model, times, points, eps)
    costs: list[float] = []  # summed with math.fsum: whole sub-steps out of C2 add up to exactly h
    for j in range(done):
        v = r[4 * j: 4 * j + 4]
        piece = _piece_cost(v, hs)
        if piece is None:
            if hs <= budget_resolution:
                piece = _simpson(v, hs)
            else:
                piece = _kink_cost(model, t + j * hs, path[j], path[j + 1], a, b, hs, eps, budget_resolution)
        costs.append(piece)
    return xc, math.fsum(costs), r[-1], (h if done == n_substeps else done * hs)


def _integrate_period_scalar(fast: ScalarModel, model: Model, t: float, x: Sequence[float], a: Sequence[float],
                             b: Sequence[float], h: float, n_substeps: int, eps: float, budget_resolution: float,
                             rate0: float | None, stop: Callable | None = None
                             ) -> tuple[list[float], float, float, float]:
    """:func:`integrate_period` on the model's scalar fast path: the same RK4 stages, stage times and budget
    pieces with the same arithmetic, evaluated point by point on Python floats instead of in one vectorised
    call (two-component states, the point mass, have the stage updates written out)."""
    f, rate = fast.f, fast.violation_rate
    hs = h / n_substeps
    hh = 0.5 * hs
    h6 = hs / 6.0
    xc = x if type(x) is list else list(x)
    r0 = rate(t, xc, eps) if rate0 is None else rate0
    two = len(xc) == 2
    costs: list[float] = []  # summed with math.fsum: whole sub-steps out of C2 add up to exactly h
    for j in range(n_substeps):
        tc = t + j * hs
        tm = tc + hh
        te = tc + hs
        if two:
            p, q = xc
            k1 = f(tc, xc, a, b)
            x2 = [p + hh * k1[0], q + hh * k1[1]]
            k2 = f(tm, x2, a, b)
            x3 = [p + hh * k2[0], q + hh * k2[1]]
            k3 = f(tm, x3, a, b)
            x4 = [p + hs * k3[0], q + hs * k3[1]]
            k4 = f(te, x4, a, b)
            xn = [p + h6 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0]),
                  q + h6 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])]
        else:
            k1 = f(tc, xc, a, b)
            x2 = [xi + hh * ki for xi, ki in zip(xc, k1)]
            k2 = f(tm, x2, a, b)
            x3 = [xi + hh * ki for xi, ki in zip(xc, k2)]
            k3 = f(tm, x3, a, b)
            x4 = [xi + hs * ki for xi, ki in zip(xc, k3)]
            k4 = f(te, x4, a, b)
            xn = [xi + h6 * (c1 + 2.0 * c2 + 2.0 * c3 + c4) for xi, c1, c2, c3, c4 in zip(xc, k1, k2, k3, k4)]
        r2, r3, r4 = rate(tm, x2, eps), rate(tm, x3, eps), rate(te, x4, eps)
        # the cases of _piece_cost, spelled out
        if r0 == 0.0 and r2 == 0.0 and r3 == 0.0 and r4 == 0.0:
            piece = 0.0
        elif r0 == 1.0 and r2 == 1.0 and r3 == 1.0 and r4 == 1.0:
            piece = hs
        else:
            v = (r0, r2, r3, r4)
            if (min(v) > 0.0 and max(v) < 1.0) or hs <= budget_resolution:
                piece = _simpson(v, hs)
            else:
                piece = _kink_cost(model, tc, xc, xn, a, b, hs, eps, budget_resolution, f=f)
        costs.append(piece)
        xc = xn
        r0 = rate(t + h if j == n_substeps - 1 else te, xn, eps)
        if stop is not None and j < n_substeps - 1 and stop(te, xn, r0):
            return xc, math.fsum(costs), r0, (j + 1) * hs
    return xc, math.fsum(costs), r0, h


# --------------------------------------------------------------------------------------------- scalar fast path


class ScalarModel(NamedTuple):
    """A model's scalar fast paths, bound to the model: the same functions as its vectorised ``f``,
    ``violation_rate``, ``hard_constraint`` and ``target`` at one point given as Python floats (sequences of
    floats in, floats or a sequence of floats out), for the per-step work of the environments."""

    f: Callable
    violation_rate: Callable
    hard_constraint: Callable
    target: Callable


#: the scalar methods a model provides for the fast path, each with the vectorised methods it stands for
_SCALAR_METHODS = (
    ("f_scalar", ("f",)),
    ("violation_rate_scalar", ("violation_rate", "soft_constraint")),
    ("hard_constraint_scalar", ("hard_constraint",)),
    ("target_scalar", ("target",)),
)


def _owner(cls: type, name: str) -> type | None:
    for c in cls.__mro__:
        if name in c.__dict__:
            return c
    return None


def scalar_model(model: Model) -> ScalarModel | None:
    """The model's scalar fast path, or ``None`` (then the environments use the vectorised methods).

    A model opts in by defining ``f_scalar``, ``violation_rate_scalar``, ``hard_constraint_scalar`` and
    ``target_scalar``. A scalar method is used only where it is defined in the same class as the vectorised
    methods it stands for, or in a subclass of it: a subclass that overrides ``f`` (or replaces it on the
    instance) but not ``f_scalar`` falls back to the vectorised methods instead of silently ignoring the change.
    """
    cls = type(model)
    own = getattr(model, "__dict__", {})
    methods = []
    for fast, slows in _SCALAR_METHODS:
        owner = _owner(cls, fast)
        if owner is None or fast in own:
            return None
        for slow in slows:
            slow_owner = _owner(cls, slow)
            if slow in own or slow_owner is None or not issubclass(owner, slow_owner):
                return None
        methods.append(getattr(model, fast))
    return ScalarModel(*methods)
