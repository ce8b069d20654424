"""Interval arithmetic on ``(lo, hi)`` pairs of numpy arrays, rounded outwards: validated enclosures of a
model's motion over one held control period (:meth:`softreach.reach.models.glider.Glider.held_enclosure`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# Intervals are ``(lo, hi)`` pairs of numpy arrays (or scalars), used by :meth:`Glider.held_enclosure`. Every
# result is widened outwards by a few units in the last place: numpy rounds to nearest, so an unwidened end could
# sit up to half an ulp inside the true range (and libm's sin/cos up to about one ulp), which would make the
# enclosure unsound by a rounding error. 4 eps relative plus the smallest normal number covers either.
_ROUND_REL = 4.0 * float(np.finfo(np.float64).eps)
_ROUND_ABS = float(np.finfo(np.float64).tiny)
HALF_PI = 0.5 * math.pi  # rounds below the true pi/2, so "< HALF_PI" is inside the real open interval


def round_down(v: Any) -> Any:
    return v - (np.abs(v) * _ROUND_REL + _ROUND_ABS)


def round_up(v: Any) -> Any:
    return v + (np.abs(v) * _ROUND_REL + _ROUND_ABS)


def iv_point(c: Any) -> tuple[Any, Any]:
    return c, c


def iv_add(x: tuple[Any, Any], y: tuple[Any, Any]) -> tuple[Any, Any]:
    return round_down(x[0] + y[0]), round_up(x[1] + y[1])


def iv_sub(x: tuple[Any, Any], y: tuple[Any, Any]) -> tuple[Any, Any]:
    return round_down(x[0] - y[1]), round_up(x[1] - y[0])


def iv_mul(x: tuple[Any, Any], y: tuple[Any, Any]) -> tuple[Any, Any]:
    # the extremes of a bilinear function over a box lie at its corners, whatever the signs
    p1, p2, p3, p4 = x[0] * y[0], x[0] * y[1], x[1] * y[0], x[1] * y[1]
    lo = np.minimum(np.minimum(p1, p2), np.minimum(p3, p4))
    hi = np.maximum(np.maximum(p1, p2), np.maximum(p3, p4))
    return round_down(lo), round_up(hi)


def iv_div_pos(x: tuple[Any, Any], y: tuple[Any, Any], name: str = "divisor") -> tuple[Any, Any]:
    """``x / y`` for an interval ``y`` with ``y_lo > 0`` (1/y is then decreasing, so its ends swap)."""
    y_lo, y_hi = (np.ravel(v) for v in np.broadcast_arrays(y[0], y[1]))
    bad = ~(y_lo > 0)  # NaN fails too
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"interval {name} [{float(y_lo[i])!r}, {float(y_hi[i])!r}] reaches <= 0; cannot divide by it")
    recip = (round_down(1.0 / y[1]), round_up(1.0 / y[0]))
    return iv_mul(x, recip)


def iv_sqr_pos(x: tuple[Any, Any]) -> tuple[Any, Any]:
    """``x^2`` for ``x_lo > 0``, where squaring is increasing (tighter than ``x * x``, which ignores that both
    factors are the same number)."""
    if np.any(~(np.asarray(x[0]) > 0)):
        raise ValueError(f"square of a positive interval expected, got lower end {float(np.min(x[0]))!r}")
    return round_down(x[0] * x[0]), round_up(x[1] * x[1])


def check_gamma_interval(g: tuple[np.ndarray, np.ndarray]) -> None:
    bad = ~((g[0] > -HALF_PI) & (g[1] < HALF_PI))  # NaN fails too
    if np.any(bad):
        i = int(np.flatnonzero(np.ravel(bad))[0])
        raise ValueError(f"flight-path angle interval [{float(np.ravel(g[0])[i])!r}, {float(np.ravel(g[1])[i])!r}] "
                         f"rad leaves (-pi/2, pi/2), where the interval sin/cos below are valid")


def iv_sin(g: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """sin over ``g`` inside ``(-pi/2, pi/2)``, where sin is increasing."""
    check_gamma_interval(g)
    return round_down(np.sin(g[0])), round_up(np.sin(g[1]))


def iv_cos(g: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """cos over ``g`` inside ``(-pi/2, pi/2)``: increasing up to 0, decreasing after, so its minimum is at an end
    and its maximum is 1 where the interval holds 0."""
    check_gamma_interval(g)
    c_lo, c_hi = np.cos(g[0]), np.cos(g[1])
    top = np.where((g[0] <= 0) & (g[1] >= 0), 1.0, np.maximum(c_lo, c_hi))
    return round_down(np.minimum(c_lo, c_hi)), round_up(top)


def iv_cos_any(g: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """cos over any interval ``g`` (a heading that may turn through several quadrants): the larger end value, or
    1 where ``g`` holds a multiple of ``2 pi``; the smaller, or -1 where it holds an odd multiple of ``pi``."""
    lo, hi = np.asarray(g[0], dtype=np.float64), np.asarray(g[1], dtype=np.float64)
    two_pi = 2.0 * math.pi
    c_lo, c_hi = np.cos(lo), np.cos(hi)
    # the first multiple of 2 pi (and of 2 pi shifted by pi) at or above lo, compared with hi; widened by an ulp so
    # that a peak on the interval's end is counted (the bound is then 1 or -1, never too tight)
    has_peak = np.ceil(round_down(lo) / two_pi) * two_pi <= round_up(hi)
    has_trough = np.ceil(round_down(lo - math.pi) / two_pi) * two_pi + math.pi <= round_up(hi)
    top = np.where(has_peak, 1.0, round_up(np.maximum(c_lo, c_hi)))
    bottom = np.where(has_trough, -1.0, round_down(np.minimum(c_lo, c_hi)))
    return np.maximum(bottom, -1.0), np.minimum(top, 1.0)


def iv_sin_any(g: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """sin over any interval ``g``: ``sin(a) = cos(a - pi/2)`` (the shift widened by more than the rounding of
    ``pi/2`` and of the subtraction)."""
    lo, hi = np.asarray(g[0], dtype=np.float64), np.asarray(g[1], dtype=np.float64)
    return iv_cos_any((round_down(lo - HALF_PI) - 1e-15, round_up(hi - HALF_PI) + 1e-15))


def iv_hull_step(x: np.ndarray, dt: float, d: tuple[np.ndarray, np.ndarray],
                 x_hi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``x + [0, dt] * d``: every ``x + s v`` with ``s`` in ``[0, dt]`` and ``v`` in ``d`` (``dt > 0``); with
    ``x_hi``, every start in the box ``[x, x_hi]``."""
    lo = round_down(dt * np.minimum(d[0], 0.0))
    hi = round_up(dt * np.maximum(d[1], 0.0))
    return round_down(x + lo), round_up((x if x_hi is None else x_hi) + hi)


