"""Outward rounding and interval bounds of cos and sin, compiled, for validated enclosures
(:mod:`softreach.reach.models.glider_enclosure`, :func:`softreach.reach.models.dubins.held_box_kernel`)."""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit

# Intervals are ``(lo, hi)`` pairs, every end widened outwards: rounding to nearest (half an ulp) and libm's sin/cos
# (about one ulp) could put an end inside the true range; 4 eps relative plus the smallest normal covers either.
ROUND_REL = 4.0 * float(np.finfo(np.float64).eps)
ROUND_ABS = float(np.finfo(np.float64).tiny)
HALF_PI = 0.5 * math.pi  # rounds below the true pi/2, so "< HALF_PI" is inside the real open interval


@njit(forceinline=True)
def down(v: float) -> float:
    """``v`` moved down by the rounding allowance (:data:`ROUND_REL`, :data:`ROUND_ABS`)."""
    return v - (abs(v) * ROUND_REL + ROUND_ABS)


@njit(forceinline=True)
def up(v: float) -> float:
    """``v`` moved up by the rounding allowance."""
    return v + (abs(v) * ROUND_REL + ROUND_ABS)


@njit(forceinline=True)
def cos_range(lo: float, hi: float) -> tuple[float, float]:
    """cos over any ``[lo, hi]``: the ends' range widened, 1 (-1) where it holds an even (odd) multiple of ``pi``."""
    two_pi = 2.0 * math.pi
    c_lo, c_hi = math.cos(lo), math.cos(hi)
    # widened so that a peak on an end is counted (the bound is then 1 or -1, never too tight)
    has_peak = math.ceil(down(lo) / two_pi) * two_pi <= up(hi)
    has_trough = math.ceil(down(lo - math.pi) / two_pi) * two_pi + math.pi <= up(hi)
    top = 1.0 if has_peak else up(max(c_lo, c_hi))
    bottom = -1.0 if has_trough else down(min(c_lo, c_hi))
    return max(bottom, -1.0), min(top, 1.0)


@njit(forceinline=True)
def sin_range(lo: float, hi: float) -> tuple[float, float]:
    """sin over any interval as ``cos(a - pi/2)``, the shift widened beyond its rounding."""
    return cos_range(down(lo - HALF_PI) - 1e-15, up(hi - HALF_PI) + 1e-15)
