"""The point mass's exact ceiling from rest (spec §4), derived here from the spec's parameters alone, in exact
rational arithmetic, for the tests that grade the model's closed form and the solver against it.

The disturbance enters where the control does, so the game is a control-only double integrator ``y'' = u' - g``
with ``|u'| <= 60 - 10``. With ``Q = 0`` the speed may not pass the soft limit ``-10 m/s``. The farthest descent
by ``T = 1 s`` that ends in the target (speed in ``[-1, 0]``, altitude at most 0.7 m) accelerates down at
``50 + g`` to ``-10 m/s``, coasts, and brakes at ``50 - g`` to ``-1 m/s`` as it reaches 0.7 m. The distances
are ``v^2 / (2 a)`` for the two ramps and speed times time for the coast.
"""

from __future__ import annotations

from fractions import Fraction


def analytic_ceiling() -> float:
    g, u_max, d_max = Fraction(98, 10), Fraction(60), Fraction(10)
    v_soft, v_land, horizon, band_top = Fraction(10), Fraction(1), Fraction(1), Fraction(7, 10)
    down, brake = u_max - d_max + g, u_max - d_max - g
    t_down, t_brake = v_soft / down, (v_soft - v_land) / brake
    t_coast = horizon - t_down - t_brake
    assert t_coast > 0
    drop = v_soft**2 / (2 * down) + v_soft * t_coast + (v_soft**2 - v_land**2) / (2 * brake)
    return float(band_top + drop)


#: 8.85641... m (the spec's "8.854" is this value rounded down)
CEILING = analytic_ceiling()
