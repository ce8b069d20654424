"""Validated enclosures of the glider's motion over one control period with the angle of attack held
(:meth:`GliderHeldEnclosure.held_enclosure`), in interval arithmetic; the safety filter's look-ahead reads them."""

from __future__ import annotations

import math

import numpy as np

from ..intervals import (round_down, round_up, iv_point, iv_add, iv_sub, iv_mul,
                         iv_div_pos, iv_sqr_pos, iv_sin, iv_cos, iv_hull_step, HALF_PI)
from .glider_params import GliderParams


class GliderHeldEnclosure:
    """The held-period enclosure of :class:`~softreach.reach.models.glider.Glider`, a base class of it.

    It reads the model's ``params`` (:class:`GliderParams`), :meth:`validate_state` and :meth:`validate_control`.
    """

    params: GliderParams

    #: inflation of a failed Picard candidate: relative to its width, and absolute (plus relative to |x|) so that
    #: a zero-width side still grows
    _ENCLOSURE_INFLATE_REL = 0.1
    _ENCLOSURE_INFLATE_ABS = 1e-9
    _ENCLOSURE_INFLATE_STATE = 1e-6
    _ENCLOSURE_MAX_TRIES = 20
    _ENCLOSURE_REFINE = 3

    def _interval_field(self, lo: np.ndarray, hi: np.ndarray, c: tuple[np.ndarray, np.ndarray]
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Interval extension of :meth:`f` over the state boxes ``[lo, hi]`` (N, 3), the lift coefficients ``c``
        (an interval per row, from the held control) and every wind in ``[-wind_max, wind_max]``.

        The formulas are those of :meth:`f`, term by term, so each value of ``f`` over the box is in the result
        (inclusion property of interval arithmetic, with outward rounding).

        :return: ``(lo, hi)``, each (N, 3)
        """
        p = self.params
        V = (lo[:, 1], hi[:, 1])
        g = (lo[:, 2], hi[:, 2])
        if np.any(~(V[0] > 0)):
            i = int(np.flatnonzero(~(V[0] > 0))[0])
            raise ValueError(f"airspeed interval [{float(V[0][i])!r}, {float(V[1][i])!r}] m/s reaches <= 0 "
                             f"(row {i}); gamma' divides by V")
        sg, cg = iv_sin(g), iv_cos(g)
        mass = iv_point(p.mass)
        h_dot = iv_mul(V, sg)
        drag_coef = iv_add(iv_point(p.cd0), iv_mul(iv_point(p.cd_k), iv_mul(c, c)))
        drag_acc = iv_div_pos(iv_mul(drag_coef, iv_sqr_pos(V)), mass, "mass")
        wind_acc = iv_div_pos((-float(p.wind_max), float(p.wind_max)), mass, "mass")
        V_dot = iv_sub(iv_sub(wind_acc, drag_acc), iv_mul(iv_point(p.gravity), sg))
        lift_acc = iv_div_pos(iv_mul(iv_mul(iv_point(p.half_rho_s), c), V), mass, "mass")
        gamma_dot = iv_sub(lift_acc, iv_div_pos(iv_mul(iv_point(p.gravity), cg), V, "airspeed"))
        out_lo = np.stack(np.broadcast_arrays(h_dot[0], V_dot[0], gamma_dot[0]), axis=1)
        out_hi = np.stack(np.broadcast_arrays(h_dot[1], V_dot[1], gamma_dot[1]), axis=1)
        return out_lo, out_hi

    def held_enclosure(self, t: float, x: np.ndarray, a: np.ndarray, dt: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Boxes that provably contain every trajectory of one control period with the control held.

        For every disturbance signal b(.) with values in the disturbance box (any measurable signal: it may switch
        at any instant, also in answer to the control), the solution x(s), s in [0, dt], of x' = f(t, x, a, b(s))
        from x with the control ``a`` held constant satisfies tube_lo <= x(s) <= tube_hi for all s, and
        end_lo <= x(dt) <= end_hi.

        Method and why each step is sound (all rows at once, numpy only):

        1. ``F(X)``, an interval extension of :meth:`f` over a state box ``X`` with ``alpha`` fixed and every
           wind of the box: the same formulas as :meth:`f` in interval arithmetic (sin increasing and cos
           unimodal on ``(-pi/2, pi/2)``), each result rounded outwards by a few ulps. By the inclusion property
           ``f(y, a, w)`` lies in ``F(X)`` for every ``y`` in ``X`` and wind ``w``, despite floating point.
        2. Tube (Picard / a-priori enclosure test): if ``Y = x + [0, dt] F(X)`` lies strictly inside ``X``, every
           trajectory stays in ``X`` on ``[0, dt]``. Were there a first exit time ``s* <= dt``, then on
           ``[0, s*]`` the path is in ``X``, so ``x(s*) - x``, the integral of ``f`` over ``[0, s*]``, lies in
           ``s* F(X)``, hence ``x(s*)`` in ``Y``, the interior of ``X``: not on its boundary, a contradiction.
           The same bound keeps the solution in a compact set, so it exists on all of ``[0, dt]``; and it holds
           for any measurable wind, since it uses only the values of ``f``. Candidates start from the Euler hull
           ``x + [0, dt] F([x, x])``; a failed candidate is replaced by its ``Y``, inflated, and retried.
        3. Refinement: once ``X`` holds every trajectory, the argument of 2 shows ``x + [0, dt] F(X)`` does too, so
           ``X`` may be intersected with it a few times without a new containment test.
        4. End box: ``x(dt) - x`` is the integral of ``f`` over the tube, in ``dt F(X)`` (mean value for
           integrals), so ``x(dt)`` is in ``x + dt F(X)``, intersected with the tube.

        :param t: time [s] (unused: the dynamics are autonomous)
        :param x: (N, 3) states (h [m], V [m/s], gamma [rad]), float64
        :param a: (N, 1) physical controls (alpha [rad]) in the control box (``(N,)`` is accepted too; the
            bound holds for any held angle, the control box is not needed for soundness)
        :param dt: the period [s] (> 0)
        :return: (tube_lo, tube_hi, end_lo, end_hi), each (N, 3) float64
        :raises ValueError: on a bad shape, ``dt <= 0``, ``V <= 0``, non-finite values or angles that look like
            degrees; or when no enclosure is found for a row within ``_ENCLOSURE_MAX_TRIES`` candidates, or a
            candidate reaches ``V <= 0`` or leaves ``|gamma| < pi/2`` (the period is too long for that state),
            naming the row and its state
        """
        return self._enclose(x, x, a, dt, strict=True)

    def held_enclosure_box(self, t: float, x_lo: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`held_enclosure` from every start in the boxes ``[x_lo, x_hi]`` (rows of ``(N, 3)``): the same
        steps with the start an interval (``x + [0, dt] F(X)`` holds every start of the box, and the end box is
        ``[x_lo, x_hi] + dt F(X)``). A row with no enclosure (a box too wide for one period, or reaching ``V <= 0``
        or ``|gamma| >= pi/2``) is returned as NaN, which every caller reads as unbounded: not admissible."""
        return self._enclose(x_lo, x_hi, a, dt, strict=False)

    def _enclose(self, x: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float, strict: bool
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x = np.asarray(x, dtype=np.float64)
        x_hi = np.asarray(x_hi, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3 or x_hi.shape != x.shape:
            raise ValueError(f"x must have shape (N, 3) (h, V, gamma), got {x.shape}"
                             + (f" (upper corners {x_hi.shape})" if x_hi.shape != x.shape else ""))
        if np.any(x_hi < x):
            i = int(np.flatnonzero((x_hi < x).any(axis=1))[0])
            raise ValueError(f"start box {i} has an upper corner below its lower one: {x[i].tolist()} .. "
                             f"{x_hi[i].tolist()}")
        n = x.shape[0]
        a = np.asarray(a, dtype=np.float64)
        if a.shape not in ((n, 1), (n,)):
            raise ValueError(f"a must have shape ({n}, 1) (alpha), got {a.shape}")
        alpha = a.reshape(n)
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite positive period [s], got {dt!r}")
        if n == 0:
            empty = np.empty((0, 3))
            return empty, empty.copy(), empty.copy(), empty.copy()
        self.validate_state(x)
        self.validate_state(x_hi)
        self.validate_control(alpha)
        p = self.params
        # C_L is computed once per row as an interval: the float product cl_alpha * alpha is itself rounded
        c = iv_add(iv_point(p.cl0), iv_mul(iv_point(p.cl_alpha), iv_point(alpha)))
        size = np.maximum(np.abs(x), np.abs(x_hi))
        failed = np.zeros(n, bool)

        def describe(i: int) -> str:
            return (f"row {i}: state (h, V, gamma) = ({float(x[i, 0])!r} m, {float(x[i, 1])!r} m/s, "
                    f"{float(x[i, 2])!r} rad), alpha = {float(alpha[i])!r} rad, dt = {dt!r} s")

        def field(lo: np.ndarray, hi: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            # the helpers name only the offending interval; add which row and state it came from
            bad_V = ~(lo[:, 1] > 0)
            bad_g = ~((lo[:, 2] > -HALF_PI) & (hi[:, 2] < HALF_PI))
            if np.any(bad_V | bad_g):
                if strict:
                    k = int(np.flatnonzero(bad_V | bad_g)[0])
                    what = (f"V in [{float(lo[k, 1])!r}, {float(hi[k, 1])!r}] m/s reaches <= 0" if bad_V[k] else
                            f"gamma in [{float(lo[k, 2])!r}, {float(hi[k, 2])!r}] rad leaves (-pi/2, pi/2)")
                    raise ValueError(f"no enclosure for {describe(int(rows[k]))}: a candidate tube has {what}; "
                                     f"shorten dt")
                # such a row has no enclosure: evaluate it on its start box and mark it failed
                bad = bad_V | bad_g
                failed[rows[bad]] = True
                lo, hi = np.where(bad[:, None], x[rows], lo), np.where(bad[:, None], x_hi[rows], hi)
            return self._interval_field(lo, hi, (c[0][rows], c[1][rows]))

        def inflate(lo: np.ndarray, hi: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            pad = (self._ENCLOSURE_INFLATE_REL * (hi - lo) + self._ENCLOSURE_INFLATE_ABS
                   + self._ENCLOSURE_INFLATE_STATE * size[rows])
            return lo - pad, hi + pad

        all_rows = np.arange(n)
        X_lo, X_hi = inflate(*iv_hull_step(x, dt, field(x, x_hi, all_rows), x_hi), all_rows)
        tube_lo, tube_hi = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        todo = all_rows
        for _ in range(self._ENCLOSURE_MAX_TRIES):
            Y_lo, Y_hi = iv_hull_step(x[todo], dt, field(X_lo, X_hi, todo), x_hi[todo])
            # strict containment: the exit-time argument needs Y inside the interior of X
            ok = np.all((Y_lo > X_lo) & (Y_hi < X_hi), axis=1) & ~failed[todo]
            # Y (not X) is kept: it is contained in X and holds the trajectories too (step 3)
            tube_lo[todo[ok]], tube_hi[todo[ok]] = Y_lo[ok], Y_hi[ok]
            retry = ~ok & ~failed[todo]
            X_lo, X_hi = inflate(Y_lo[retry], Y_hi[retry], todo[retry])
            todo = todo[retry]
            if todo.size == 0:
                break
        else:
            if strict:
                raise ValueError(f"no enclosure for {describe(int(todo[0]))} after {self._ENCLOSURE_MAX_TRIES} "
                                 f"candidates ({todo.size} rows failed); shorten dt")
            failed[todo] = True

        good = np.flatnonzero(~failed)
        tube_lo[failed], tube_hi[failed] = np.nan, np.nan
        lo, hi, xl, xh = tube_lo[good], tube_hi[good], x[good], x_hi[good]
        for _ in range(self._ENCLOSURE_REFINE):
            Y_lo, Y_hi = iv_hull_step(xl, dt, field(lo, hi, good), xh)
            lo, hi = np.maximum(lo, Y_lo), np.minimum(hi, Y_hi)

        d_lo, d_hi = field(lo, hi, good)
        end_lo, end_hi = np.full((n, 3), np.nan), np.full((n, 3), np.nan)
        tube_lo[good], tube_hi[good] = lo, hi
        end_lo[good] = np.maximum(round_down(xl + round_down(dt * d_lo)), lo)
        end_hi[good] = np.minimum(round_up(xh + round_up(dt * d_hi)), hi)
        return tube_lo, tube_hi, end_lo, end_hi


__all__ = ["GliderHeldEnclosure"]
