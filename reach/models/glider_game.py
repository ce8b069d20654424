"""The glider's differential game: ``min_alpha max_F p . f`` in closed form, its optimal inputs and the
dissipation bounds of the upwind scheme. The drag is quadratic in the lift coefficient, so the Hamiltonian is
not control-affine and the minimum over the angle of attack is that of a quadratic over an interval."""

from __future__ import annotations

from .. import backend as B
from ..dynamics import Components
from .glider_params import GliderParams, _cos, _sin

Array = B.Array


class GliderGame:
    """The Hamiltonian, optimal inputs and dissipation of :class:`~softreach.reach.models.glider.Glider`, a base
    class of it.

    It reads the model's ``params`` (:class:`GliderParams`) and ``_cl_bounds``, the interval of the lift coefficient
    over the control box.
    """

    params: GliderParams
    _cl_bounds: tuple[float, float]

    def _quadratic(self, x: Components, p: Components):
        """The ``alpha``-dependent part of ``p . f`` as ``q(C) = a2 C^2 + a1 C`` in ``C = C_L(alpha)``, and the
        part that depends on neither input."""
        prm = self.params
        _, V, gamma = x
        p_h, p_V, p_g = p
        sg, cg = _sin(gamma), _cos(gamma)
        a2 = -p_V * (prm.cd_k * V * V / prm.mass)
        a1 = p_g * (prm.half_rho_s * V / prm.mass)
        rest = p_h * (V * sg) - p_V * (prm.cd0 * V * V / prm.mass + prm.gravity * sg) - p_g * (prm.gravity * cg / V)
        return a2, a1, rest

    def _vertex(self, a2: Array, a1: Array) -> Array:
        """``argmin`` of ``q`` over ``[C_lo, C_hi]`` where ``q`` is strictly convex (``a2 > 0``); elsewhere some
        point of the interval (a safe divisor keeps it finite)."""
        lo, hi = self._cl_bounds
        convex = a2 > 0
        return B.clip(-a1 / (2.0 * B.where(convex, a2, 1.0)), lo, hi)

    def hamiltonian(self, t: float, x: Components, p: Components) -> Array:
        """``min_alpha max_F p . f``, exactly.

        The wind enters ``V'`` alone and linearly: ``max_F`` gives ``wind_max |p_V| / m``. The control enters
        through ``q(C) = -(p_V V^2/m)(cd0 + cd_k C^2) + (p_gamma half_rho_s V/m) C`` with ``C = C_L(alpha)``
        over ``[C_L(alpha_lo), C_L(alpha_hi)]``. Its minimum is at an end of the interval, or at the clipped
        vertex ``-a1 / (2 a2)`` when ``q`` is convex (``p_V < 0``). Taking the minimum of all three is exact in
        every case: where ``q`` is concave or linear the clipped point is just another point of the interval,
        never below the ends.

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        :param p: co-state components ``(p_h, p_V, p_gamma)``
        """
        prm = self.params
        a2, a1, rest = self._quadratic(x, p)
        lo, hi = self._cl_bounds
        c_star = self._vertex(a2, a1)
        q_lo = a2 * lo * lo + a1 * lo
        q_hi = a2 * hi * hi + a1 * hi
        q_star = a2 * c_star * c_star + a1 * c_star
        q_min = B.minimum(B.minimum(q_lo, q_hi), q_star)
        return rest + q_min + (prm.wind_max / prm.mass) * abs(p[1])

    def optimal_control(self, t: float, x: Components, p: Components) -> list[Array]:
        """``argmin_alpha max_F p . f`` [rad].

        Convex ``q`` (``p_V < 0``): the clipped vertex. Otherwise the end where ``q`` is smaller: the sign of
        ``q(C_hi) - q(C_lo) = (C_hi - C_lo)(a2 (C_lo + C_hi) + a1)`` decides. On a tie of a linear ``q``
        (``p_V = p_gamma = 0``: every angle is optimal) the midpoint, as for the bang-bang models; on a tie of
        a concave ``q`` (both ends optimal, the middle not) the lower end.

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        :param p: co-state components ``(p_h, p_V, p_gamma)``
        :return: ``[alpha]`` in radians
        """
        prm = self.params
        a2, a1, _ = self._quadratic(x, p)
        lo, hi = self._cl_bounds
        c_star = self._vertex(a2, a1)
        ref = 0 * c_star
        s = a2 * (lo + hi) + a1
        tie = B.where(a2 < 0, ref + lo, ref + 0.5 * (lo + hi))
        c_end = B.where(s > 0, ref + lo, B.where(s < 0, ref + hi, tie))
        c = B.where(a2 > 0, c_star, c_end)
        return [(c - prm.cl0) / prm.cl_alpha]

    def worst_disturbance(self, t: float, x: Components, p: Components) -> list[Array]:
        """``argmax_F``: ``+wind_max`` where ``p_V > 0``, ``-wind_max`` where ``p_V < 0``, ``0`` on ``p_V = 0``.

        The wind term does not depend on ``alpha``, so this is the worst wind against every control.

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        :param p: co-state components ``(p_h, p_V, p_gamma)``
        :return: ``[F_wind]`` in newtons
        """
        p_V = p[1]
        w = float(self.params.wind_max)
        if isinstance(p_V, (int, float)):
            return [w if p_V > 0 else (-w if p_V < 0 else 0.0)]
        ref = 0 * p_V + 0 * _sin(x[2]) * x[1]
        return [B.where(p_V > 0, ref + w, B.where(p_V < 0, ref - w, ref))]

    def dissipation(self, t: float, x: Components, p_lo: Components | None = None,
                    p_hi: Components | None = None) -> list[Array | float]:
        """Bounds ``alpha_i >= |dH/dp_i|``: ``max |f_i|`` over the inputs, in closed form per node.

        ``dH/dp_i`` is ``f_i`` at an optimal pair of inputs, so ``max |f_i|`` over the whole control and wind
        boxes bounds it for every co-state: ``|V sin(gamma)|`` along ``h`` (no input enters), the ends of the
        drag interval ``(cd0 + cd_k [C^2 range]) V^2`` and of the wind interval along ``V``, and the ends of the
        ``C_L`` interval along ``gamma`` (linear in ``C_L``). Given a co-state box whose ``p_V`` keeps one sign,
        only the matching end of the wind interval can be optimal, which tightens the ``V`` bound by up to
        ``2 wind_max / m``; the control bound is not tightened.

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        :param p_lo: lower corner of the co-state box, or ``None`` for a bound valid for every co-state
        :param p_hi: upper corner of the co-state box, or ``None``
        """
        prm = self.params
        _, V, gamma = x
        sg, cg = _sin(gamma), _cos(gamma)
        lo, hi = self._cl_bounds
        sq = (lo * lo, hi * hi)
        c2_min = 0.0 if lo <= 0.0 <= hi else min(sq)
        c2_max = max(sq)
        VV = V * V / prm.mass
        drag_min = (prm.cd0 + prm.cd_k * c2_min) * VV  # cd_k >= 0: the ends of C^2 give the ends of D
        drag_max = (prm.cd0 + prm.cd_k * c2_max) * VV
        w = prm.wind_max / prm.mass
        base = -prm.gravity * sg
        if p_lo is None:
            v_lo = base - drag_max - w
            v_hi = base - drag_min + w
        else:
            # the maximiser takes -wind_max only where p_V <= 0 is possible, +wind_max where p_V >= 0 is
            ref = 0 * p_lo[1]
            w_lo = B.where(p_lo[1] > 0, ref + w, ref - w)
            w_hi = B.where(p_hi[1] < 0, ref - w, ref + w)
            v_lo = base - drag_max + w_lo
            v_hi = base - drag_min + w_hi
        h_bound = abs(V * sg)
        v_bound = B.maximum(abs(v_lo), abs(v_hi)) if hasattr(v_lo, "shape") else max(abs(v_lo), abs(v_hi))
        g_term = prm.gravity * cg / V
        g_lo = prm.half_rho_s * lo * V / prm.mass - g_term
        g_hi = prm.half_rho_s * hi * V / prm.mass - g_term
        g_bound = B.maximum(abs(g_lo), abs(g_hi)) if hasattr(g_lo, "shape") else max(abs(g_lo), abs(g_hi))
        return [h_bound, v_bound, g_bound]


__all__ = ["GliderGame"]
