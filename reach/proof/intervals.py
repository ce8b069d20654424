"""Outward rounding and interval bounds of cos and sin, for validated enclosures of a model's motion over one held
control period (:mod:`softreach.reach.models.glider_enclosure`, :meth:`softreach.reach.models.dubins.Dubins.
held_enclosure`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# Intervals are ``(lo, hi)`` pairs of numpy arrays (or scalars). Every result is widened outwards by a few units in
# the last place: arithmetic rounds to nearest, so an unwidened end could sit up to half an ulp inside the true
# range (and libm's sin/cos up to about one ulp), which would make the enclosure unsound by a rounding error.
# 4 eps relative plus the smallest normal number covers either.
ROUND_REL = 4.0 * float(np.finfo(np.float64).eps)
ROUND_ABS = float(np.finfo(np.float64).tiny)
HALF_PI = 0.5 * math.pi  # rounds below the true pi/2, so "< HALF_PI" is inside the real open interval


def round_down(v: Any) -> Any:
    return v - (np.abs(v) * ROUND_REL + ROUND_ABS)


def round_up(v: Any) -> Any:
    return v + (np.abs(v) * ROUND_REL + ROUND_ABS)


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
