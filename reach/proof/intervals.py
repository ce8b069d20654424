"""Outward rounding and interval bounds of cos and sin, compiled, for validated enclosures of a model's motion over
one held control period (:mod:`softreach.reach.models.glider_enclosure`, :func:`softreach.reach.models.dubins.
held_box_kernel`)."""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit

# Intervals are ``(lo, hi)`` pairs of floats. Every result is widened outwards by a few units in
# the last place: arithmetic rounds to nearest, so an unwidened end could sit up to half an ulp inside the true
# range (and libm's sin/cos up to about one ulp), which would make the enclosure unsound by a rounding error.
# 4 eps relative plus the smallest normal number covers either.
ROUND_REL = 4.0 * float(np.finfo(np.float64).eps)
ROUND_ABS = float(np.finfo(np.float64).tiny)
HALF_PI = 0.5 * math.pi  # rounds below the true pi/2, so "< HALF_PI" is inside the real open interval


@njit(inline="always")
def down(v: float) -> float:
    """``v`` moved outwards below by the rounding allowance (:data:`ROUND_REL`, :data:`ROUND_ABS`)."""
    return v - (abs(v) * ROUND_REL + ROUND_ABS)


@njit(inline="always")
def up(v: float) -> float:
    """``v`` moved outwards above by the rounding allowance."""
    return v + (abs(v) * ROUND_REL + ROUND_ABS)


@njit(inline="always")
def cos_range(lo: float, hi: float) -> tuple[float, float]:
    """cos over any interval ``[lo, hi]`` (a heading that may turn through several quadrants): the larger end
    value, or 1 where the interval holds a multiple of ``2 pi``; the smaller, or -1 where it holds an odd multiple
    of ``pi``."""
    two_pi = 2.0 * math.pi
    c_lo, c_hi = math.cos(lo), math.cos(hi)
    # the first multiple of 2 pi (and of 2 pi shifted by pi) at or above lo, compared with hi; widened by an ulp so
    # that a peak on the interval's end is counted (the bound is then 1 or -1, never too tight)
    has_peak = math.ceil(down(lo) / two_pi) * two_pi <= up(hi)
    has_trough = math.ceil(down(lo - math.pi) / two_pi) * two_pi + math.pi <= up(hi)
    top = 1.0 if has_peak else up(max(c_lo, c_hi))
    bottom = -1.0 if has_trough else down(min(c_lo, c_hi))
    return max(bottom, -1.0), min(top, 1.0)


@njit(inline="always")
def sin_range(lo: float, hi: float) -> tuple[float, float]:
    """sin over any interval: ``sin(a) = cos(a - pi/2)`` (the shift widened by more than the rounding of ``pi/2``
    and of the subtraction)."""
    return cos_range(down(lo - HALF_PI) - 1e-15, up(hi - HALF_PI) + 1e-15)
