"""Validated enclosures of the glider's motion over one control period with the angle of attack held
(:func:`held_box_kernel`), in interval arithmetic; the safety filter's look-ahead reads them.

The enclosure is one compiled kernel (numba), the glider's
:attr:`~softreach.reach.model_filter.FilterPart.held_box_kernel`: the numpy methods
:class:`~softreach.reach.model_filter.FilterPart` derives from it run it row by row
(:func:`~softreach.reach.proof.model_kernels.held_boxes`), and the filter's compiled decision calls it by address, so
both read the same boxes."""

from __future__ import annotations

import math

import numpy as np

from ..proof.intervals import HALF_PI, down, up
from ..jit import njit
from .glider_params import GliderParams

#: inflation of a failed Picard candidate: relative to its width, and absolute (plus relative to |x|) so that a
#: zero-width side still grows
_INFLATE_REL, _INFLATE_ABS, _INFLATE_STATE = 0.1, 1e-9, 1e-6
#: Picard candidates tried before a row is declared to have no enclosure, and refinements of a found tube
_MAX_TRIES, _REFINE = 20, 3


@njit(forceinline=True)
def _mul(a0, a1, b0, b1):
    # the extremes of a bilinear function over a box lie at its corners, whatever the signs
    p1, p2, p3, p4 = a0 * b0, a0 * b1, a1 * b0, a1 * b1
    return down(min(min(p1, p2), min(p3, p4))), up(max(max(p1, p2), max(p3, p4)))


@njit(forceinline=True)
def _div_pos(a0, a1, b0, b1):
    """``a / b`` for ``b0 > 0``: ``1 / b`` is decreasing, so its ends swap."""
    return _mul(a0, a1, down(1.0 / b1), up(1.0 / b0))


# The state is always (h, V, gamma): the kernel keeps its boxes in 3-tuples, in registers, because the arrays it
# would otherwise allocate at every call cost a third of the call, and the filter calls it hundreds of times a
# decision. Its helpers are inlined by LLVM (forceinline), not by numba (inline="always"), which would type each of
# their hundreds of call sites again; they take the parameters as a tuple of floats, as an array handed to a
# function is reference-counted at every call.


@njit(forceinline=True)
def _field(P, c0, c1, V0, V1, g0, g1):
    """Interval extension of :meth:`Glider.f` over the states with airspeed in ``[V0, V1]`` and flight-path angle
    in ``[g0, g1]`` (the field does not depend on ``h``), the lift coefficients ``[c0, c1]`` and every wind in
    ``[-wind_max, wind_max]``: the formulas of ``f`` term by term, each result rounded outwards (sin increasing and
    cos unimodal on ``(-pi/2, pi/2)``), so every value of ``f`` over the box lies in it (inclusion property).
    ``P`` is :attr:`GliderHeldEnclosure.held_box_params`.

    :return: ``(ok, lo, hi)``, the box as two 3-tuples; ``ok`` is ``False`` where the box leaves the formulas'
        domain (``V <= 0`` or ``|gamma| >= pi/2``, or NaN)
    """
    cd0, cd_k, mass, g, half_rho_s, wind_max = P[2], P[3], P[4], P[5], P[6], P[7]
    if not (V0 > 0.0 and g0 > -HALF_PI and g1 < HALF_PI):
        return False, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    s0, s1 = down(math.sin(g0)), up(math.sin(g1))
    k0, k1 = math.cos(g0), math.cos(g1)
    cg0, cg1 = down(min(k0, k1)), up(1.0 if (g0 <= 0.0 and g1 >= 0.0) else max(k0, k1))
    h0, h1 = _mul(V0, V1, s0, s1)
    cc0, cc1 = _mul(c0, c1, c0, c1)
    q0, q1 = _mul(cd_k, cd_k, cc0, cc1)
    dc0, dc1 = down(cd0 + q0), up(cd0 + q1)
    d0, d1 = _mul(dc0, dc1, down(V0 * V0), up(V1 * V1))
    drag0, drag1 = _div_pos(d0, d1, mass, mass)
    w0, w1 = _div_pos(-wind_max, wind_max, mass, mass)
    gs0, gs1 = _mul(g, g, s0, s1)
    a0, a1 = down(w0 - drag1), up(w1 - drag0)
    v0, v1 = down(a0 - gs1), up(a1 - gs0)
    l0, l1 = _mul(half_rho_s, half_rho_s, c0, c1)
    l0, l1 = _mul(l0, l1, V0, V1)
    l0, l1 = _div_pos(l0, l1, mass, mass)
    gc0, gc1 = _mul(g, g, cg0, cg1)
    r0, r1 = _div_pos(gc0, gc1, V0, V1)
    return True, (h0, v0, down(l0 - r1)), (h1, v1, up(l1 - r0))


@njit(forceinline=True)
def _field_over(P, c0, c1, lo, hi):
    """:func:`_field` over the box ``[lo, hi]`` (3-tuples)."""
    return _field(P, c0, c1, lo[1], hi[1], lo[2], hi[2])


@njit(forceinline=True)
def _hull_lo(x, s, d):
    # a rate that cannot be negative adds nothing below the start: its end is exact, no rounding to widen it
    return x if d >= 0.0 else down(x + down(s * d))


@njit(forceinline=True)
def _hull_hi(x, s, d):
    return x if d <= 0.0 else up(x + up(s * d))


@njit(forceinline=True)
def _hull_step(x_lo, x_hi, s, d_lo, d_hi):
    """``[x_lo, x_hi] + [0, s] * [d_lo, d_hi]`` (``s >= 0``), rounded outwards, as two 3-tuples. Along an axis
    whose rate has one sign the start's end is kept exactly: the motion only leaves it the other way."""
    return ((_hull_lo(x_lo[0], s, d_lo[0]), _hull_lo(x_lo[1], s, d_lo[1]), _hull_lo(x_lo[2], s, d_lo[2])),
            (_hull_hi(x_hi[0], s, d_hi[0]), _hull_hi(x_hi[1], s, d_hi[1]), _hull_hi(x_hi[2], s, d_hi[2])))


@njit(forceinline=True)
def _pad(X_lo, X_hi, x_lo, x_hi, i):
    """How far a failed Picard candidate grows along axis ``i``."""
    return _INFLATE_REL * (X_hi[i] - X_lo[i]) + _INFLATE_ABS + _INFLATE_STATE * max(abs(x_lo[i]), abs(x_hi[i]))


@njit
def held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """The box of every state reachable at some time in ``[s0, s1]`` of a period with ``alpha = a[0]`` held, from
    every start in ``[x_lo, x_hi]``, for every wind signal of the box, written into ``lo`` and ``hi``; NaN where
    no enclosure is found. ``params``: :attr:`GliderHeldEnclosure.held_box_params`.

    Method, and why each step is sound:

    1. ``F(X)``, the interval extension :func:`_field`: ``f(y, alpha, w)`` lies in ``F(X)`` for every ``y`` in the
       box ``X`` and wind ``w``, despite floating point (each result widened by a few ulps).
    2. Tube (Picard, a-priori enclosure): if ``Y = [x_lo, x_hi] + [0, s1] F(X)`` lies strictly inside ``X``, every
       trajectory stays in ``X`` on ``[0, s1]``. Were there a first exit time ``s* <= s1``, on ``[0, s*]`` the
       path is in ``X``, so ``x(s*) - x(0)``, the integral of ``f``, lies in ``s* F(X)``, hence ``x(s*)`` in
       ``Y``, the interior of ``X``: a contradiction. The bound keeps the solution in a compact set, so it exists
       on all of ``[0, s1]``; it uses only the values of ``f``, so it holds for any measurable wind, also one that
       switches at any instant or answers the control. Candidates start from the Euler hull
       ``[x_lo, x_hi] + [0, s1] F([x_lo, x_hi])``; a failed one is replaced by its ``Y``, inflated, and retried.
    3. Refinement: once ``X`` holds every trajectory, the argument of 2 shows that ``Y`` does too, so ``X`` is
       intersected with it a few times without a new containment test.
    4. The box of ``[s0, s1]``: ``x(s) - x(0)`` lies in ``s F(X)``, whose ends are linear in ``s``, so over
       ``s`` in ``[s0, s1]`` every ``x(s)`` is in ``[x_lo + min(s0 d_lo, s1 d_lo), x_hi + max(s0 d_hi, s1 d_hi)]``
       (``[d_lo, d_hi] = F(X)``), intersected with ``X``. With ``s0 = s1`` it is the end box at ``s1``.
    5. Signs: where ``d_lo[i] >= 0`` every ``x_i(s) = x_i(0) + (integral of f_i) >= x_lo[i]``, and where
       ``d_hi[i] <= 0`` every ``x_i(s) <= x_hi[i]``: the box and every hull of 2 and 3 keep that end of the start
       box exactly, with no outward rounding (a float bound needs none). A glider at the soft airspeed limit that
       decelerates, or at ``gamma = 0`` pitching down, is then not charged the rounding's 1e-13 s of budget, nor
       taken to leave ``C1`` by it.
    6. The end box (``s0 = s1``) tightened to second order along every axis (:func:`_second_order`).
    """
    P = (params[0], params[1], params[2], params[3], params[4], params[5], params[6], params[7])
    alpha = a[0]
    c0, c1 = _mul(P[1], P[1], alpha, alpha)
    c0, c1 = down(P[0] + c0), up(P[0] + c1)
    for i in range(3):
        lo[i], hi[i] = np.nan, np.nan
    xl, xh = (x_lo[0], x_lo[1], x_lo[2]), (x_hi[0], x_hi[1], x_hi[2])
    ok, e_lo, e_hi = _field_over(P, c0, c1, xl, xh)
    if not ok:
        return
    X_lo, X_hi = _hull_step(xl, xh, s1, e_lo, e_hi)
    found = False
    for _ in range(_MAX_TRIES):
        p0, p1, p2 = _pad(X_lo, X_hi, xl, xh, 0), _pad(X_lo, X_hi, xl, xh, 1), _pad(X_lo, X_hi, xl, xh, 2)
        X_lo, X_hi = (X_lo[0] - p0, X_lo[1] - p1, X_lo[2] - p2), (X_hi[0] + p0, X_hi[1] + p1, X_hi[2] + p2)
        ok, d_lo, d_hi = _field_over(P, c0, c1, X_lo, X_hi)
        if not ok:
            return
        Y_lo, Y_hi = _hull_step(xl, xh, s1, d_lo, d_hi)
        # strict containment: the exit-time argument needs Y inside the interior of X
        inside = (Y_lo[0] > X_lo[0] and Y_hi[0] < X_hi[0] and Y_lo[1] > X_lo[1] and Y_hi[1] < X_hi[1]
                  and Y_lo[2] > X_lo[2] and Y_hi[2] < X_hi[2])
        X_lo, X_hi = Y_lo, Y_hi
        if inside:
            found = True
            break
    if not found:
        return
    for _ in range(_REFINE):
        # Y lies in X, which keeps the domain: the field is defined on every refined tube
        ok, d_lo, d_hi = _field_over(P, c0, c1, X_lo, X_hi)
        Y_lo, Y_hi = _hull_step(xl, xh, s1, d_lo, d_hi)
        X_lo = (max(X_lo[0], Y_lo[0]), max(X_lo[1], Y_lo[1]), max(X_lo[2], Y_lo[2]))
        X_hi = (min(X_hi[0], Y_hi[0]), min(X_hi[1], Y_hi[1]), min(X_hi[2], Y_hi[2]))
    ok, d_lo, d_hi = _field_over(P, c0, c1, X_lo, X_hi)
    for i in range(3):
        lo[i] = max(down(xl[i] + down(min(s0 * d_lo[i], s1 * d_lo[i]))), X_lo[i])
        hi[i] = min(up(xh[i] + up(max(s0 * d_hi[i], s1 * d_hi[i]))), X_hi[i])
        # step 5: a rate of one sign over X moves the axis one way only, so the start's far end bounds it exactly
        if d_lo[i] >= 0.0:
            lo[i] = max(lo[i], xl[i])
        if d_hi[i] <= 0.0:
            hi[i] = min(hi[i], xh[i])
    if s0 == s1:
        # the tube over [0, s1] (X cut to the hull of that time), and the field over it
        H_lo, H_hi = _hull_step(xl, xh, s1, d_lo, d_hi)
        T_lo = (max(H_lo[0], X_lo[0]), max(H_lo[1], X_lo[1]), max(H_lo[2], X_lo[2]))
        T_hi = (min(H_hi[0], X_hi[0]), min(H_hi[1], X_hi[1]), min(H_hi[2], X_hi[2]))
        ok, t_lo, t_hi = _field_over(P, c0, c1, T_lo, T_hi)
        if ok:
            _second_order(P, c0, c1, xl, xh, e_lo, e_hi, T_lo, T_hi, t_lo, t_hi, s1, lo, hi)


@njit(forceinline=True)
def _second_order(P, c0, c1, xl, xh, e_lo, e_hi, X_lo, X_hi, d_lo, d_hi, s, lo, hi):
    """Step 6, the end box at ``s`` tightened to second order over the tube ``X`` of ``[0, s]`` and ``F(X)``
    (``d_lo``, ``d_hi``, the wind in ``V'``). ``h`` and ``gamma`` have rates without wind, absolutely continuous
    along a path: ``x(s) = x(0) + s f(x(0)) + int_0^s (s - r) x''(r) dr`` lies in ``[xl, xh] + s F([xl, xh]) +
    s^2 / 2 X''``, ``X''`` the interval extension over ``X`` of ``h'' = V' sin(gamma) + V cos(gamma) gamma'`` and
    ``gamma'' = half_rho_s C_L V' / m + (g sin(gamma) gamma' + g cos(gamma) V' / V) / V``. ``V' = A(V, gamma) +
    w / m`` takes the wind additively: its integral lies in ``s [-w_max, w_max] / m`` for any signal, and ``A``'s
    by the same expansion, ``A' = -2 (cd0 + cd_k C_L^2) V V' / m - g cos(gamma) gamma'``; ``s F([xl, xh])`` holds
    both first terms. The first-order box counts the period's whole turn as if any rate of it held all period; this
    counts its curvature only."""
    cd0, cd_k, mass, g, half_rho_s = P[2], P[3], P[4], P[5], P[6]
    sg0, sg1 = down(math.sin(X_lo[2])), up(math.sin(X_hi[2]))
    k0, k1 = math.cos(X_lo[2]), math.cos(X_hi[2])
    cg0, cg1 = down(min(k0, k1)), up(1.0 if (X_lo[2] <= 0.0 and X_hi[2] >= 0.0) else max(k0, k1))
    a0, a1 = _mul(d_lo[1], d_hi[1], sg0, sg1)
    b0, b1 = _mul(X_lo[1], X_hi[1], cg0, cg1)
    b0, b1 = _mul(b0, b1, d_lo[2], d_hi[2])
    iv0, iv1 = _div_pos(1.0, 1.0, X_lo[1], X_hi[1])
    p0, p1 = _mul(half_rho_s, half_rho_s, c0, c1)
    p0, p1 = _mul(p0, p1, d_lo[1], d_hi[1])
    p0, p1 = _div_pos(p0, p1, mass, mass)
    q0, q1 = _mul(g, g, sg0, sg1)
    q0, q1 = _mul(q0, q1, d_lo[2], d_hi[2])
    gc0, gc1 = _mul(g, g, cg0, cg1)
    r0, r1 = _mul(gc0, gc1, d_lo[1], d_hi[1])
    r0, r1 = _mul(r0, r1, iv0, iv1)
    q0, q1 = _mul(down(q0 + r0), up(q1 + r1), iv0, iv1)
    # A' of V's windless part: the drag's 2 (cd0 + cd_k C_L^2) V V' / m and g cos(gamma) gamma'
    cc0, cc1 = _mul(c0, c1, c0, c1)
    e0, e1 = _mul(cd_k, cd_k, cc0, cc1)
    e0, e1 = _mul(down(cd0 + e0), up(cd0 + e1), X_lo[1], X_hi[1])
    e0, e1 = _mul(e0, e1, d_lo[1], d_hi[1])
    e0, e1 = _div_pos(down(2.0 * e0), up(2.0 * e1), mass, mass)
    f0, f1 = _mul(gc0, gc1, d_lo[2], d_hi[2])
    half_s2 = 0.5 * s * s
    for i, w0, w1 in ((0, down(a0 + b0), up(a1 + b1)), (1, down(-e1 - f1), up(-e0 - f0)),
                      (2, down(p0 + q0), up(p1 + q1))):
        m0, m1 = _mul(s, s, e_lo[i], e_hi[i])
        n0, n1 = _mul(down(half_s2), up(half_s2), w0, w1)
        lo[i] = max(lo[i], down(down(xl[i] + m0) + n0))
        hi[i] = min(hi[i], up(up(xh[i] + m1) + n1))


class GliderHeldEnclosure:
    """The held-period enclosure of :class:`~softreach.reach.models.glider.Glider`, a base class of it.

    It gives the compiled motion bound only: the base class :class:`~softreach.reach.model_filter.FilterPart` derives
    :meth:`held_enclosure`, :meth:`held_tube_pieces` and their ``_box`` versions from it, checking their arguments
    with the glider's :meth:`validate_state` and :meth:`validate_control` (which refuse ``V <= 0`` and angles that
    look like degrees) and refusing, in :meth:`held_enclosure`, a row with no box (no Picard candidate within the
    kernel's tries, or one that reached ``V <= 0`` or ``|gamma| >= pi/2``: the period is too long for that state).
    """

    params: GliderParams
    #: the compiled enclosure (:attr:`~softreach.reach.model_filter.FilterPart.held_box_kernel`)
    held_box_kernel = staticmethod(held_box_kernel)

    def rk4_error(self, h: float) -> np.ndarray:
        """Zero: :func:`held_box_kernel`'s boxes hold the states of the environments' RK4 themselves, not only the
        exact motion's. An RK4 state at elapsed time ``s`` (a stage or a sub-step's end) is the start plus ``s``
        times a mean, with weights of one sign, of ``f`` at earlier stages, the wind's stage values a mean in its
        box; so by induction every stage lies in ``[x_lo, x_hi] + s F(X)``, inside the Picard tube ``X`` and each
        refinement of it (steps 2 and 3), in the box of step 4 and on the side that step 5 keeps. At a sub-step's end
        ``s`` the second-order box of step 6 holds it too: ``f(y) - f(x_0)`` at a stage ``y`` of elapsed time ``t``
        lies in ``t`` times the gradient over the tube times its ``F`` (the mean-value theorem), the interval
        ``X''`` is made of, and RK4's weights sum ``t`` to ``s^2 / 2`` over the sub-steps, the factor of the exact
        motion's remainder."""
        return np.zeros(3)

    def rk4_stage_error(self, h: float) -> np.ndarray:
        """Zero: every RK4 stage lies in the kernel's box over an interval holding its instant (:meth:`rk4_error`)."""
        return np.zeros(3)

    @property
    def held_box_params(self) -> np.ndarray:
        """The numbers :func:`held_box_kernel` reads: ``(cl0, cl_alpha, cd0, cd_k, mass, gravity, half_rho_s,
        wind_max)``."""
        p = self.params
        return np.array([p.cl0, p.cl_alpha, p.cd0, p.cd_k, p.mass, p.gravity, p.half_rho_s, p.wind_max],
                        dtype=np.float64)


__all__ = ["GliderHeldEnclosure", "held_box_kernel"]
