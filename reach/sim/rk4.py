"""The classical Runge-Kutta (RK4) step of softreach, on state components.

A state is a sequence of components: Python floats for one state (the environments' steps), or ``(N,)`` numpy
arrays for ``N`` states at once (the rollouts). :func:`rk4_step` takes one step on either, with the control and
the disturbance held; the period loops of :mod:`softreach.reach.sim.integrator` call it once per sub-step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np


def rk4_step(f: Callable, tc: float, tm: float, te: float, hh: float, hs: float, h6: float, xc: Sequence[Any],
             a: Sequence[Any], b: Sequence[Any]) -> tuple[list[Any], list[Any], list[Any], list[Any]]:
    """One classical RK4 step of ``x' = f(t, x, a, b)`` with ``a`` and ``b`` held.

    The step's start ``tc``, its middle ``tm = tc + hh`` and end ``te = tc + hs``, ``hh = hs / 2`` and
    ``h6 = hs / 6`` are given (a period's loop knows them already).

    :param f: the vector field ``f(t, x, a, b)``, one float or array per component in and out
    :param xc: the state at ``tc``; ``a``: the control; ``b``: the disturbance (one float or array per component)
    :return: ``(x_end, x2, x3, x4)``: the state at ``te`` and the stage states ``xc + hh k1``, ``xc + hh k2``,
        ``xc + hs k3`` (where RK4 evaluates ``f`` at ``tm``, ``tm``, ``te``; the budget evaluates ``h_eps`` there
        too)
    """
    n = len(xc)
    each = range(n)
    k1 = f(tc, xc, a, b)
    x2 = [0.0] * n
    for i in each:
        x2[i] = xc[i] + hh * k1[i]
    k2 = f(tm, x2, a, b)
    x3 = [0.0] * n
    for i in each:
        x3[i] = xc[i] + hh * k2[i]
    k3 = f(tm, x3, a, b)
    x4 = [0.0] * n
    for i in each:
        x4[i] = xc[i] + hs * k3[i]
    k4 = f(te, x4, a, b)
    xn = [0.0] * n
    for i in each:
        xn[i] = xc[i] + h6 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    return xn, x2, x3, x4


def rk4_rows(f: Callable, tc: Any, tm: Any, te: Any, h: Any, x: np.ndarray, a: np.ndarray, b: np.ndarray
             ) -> np.ndarray:
    """:func:`rk4_step` on rows: ``x``, ``a``, ``b`` of shape ``(N, n)``, ``(N, m)``, ``(N, k)``, the step ``h``
    (and the times) floats or ``(N,)``; the ``(N, n)`` states at ``te``."""
    out = rk4_step(f, tc, tm, te, 0.5 * h, h, h / 6.0, list(x.T), list(a.T), list(b.T))[0]
    return np.stack([np.broadcast_to(np.asarray(c, dtype=np.float64), (len(x),)) for c in out], axis=1)


def rk4_stages(f: Callable, t: float, x: Sequence[Any], a: Sequence[Any], b: Sequence[Any],
               h: float) -> tuple[list[Any], list[list[Any]]]:
    """One RK4 step (:func:`rk4_step`): the state at ``t + h`` and the four stage states
    ``[x, x + h/2 k1, x + h/2 k2, x + h k3]``.

    :param f: the vector field ``f(t, x, a, b)``, one float or array per component in and out
    :param t: start time [s]
    :param x: start state; ``a``: control; ``b``: disturbance (physical units, one float or array per component)
    :param h: step length [s]
    """
    xn, x2, x3, x4 = rk4_step(f, t, t + 0.5 * h, t + h, 0.5 * h, h, h / 6.0, x, a, b)
    return xn, [list(x), x2, x3, x4]
