"""Emergency landing of a fixed-wing aircraft after propulsion failure, "glider" (paper §VI-B, spec §3).

State ``x = (h, V, gamma)``: altitude [m], airspeed [m/s], flight-path angle [**rad**]. Control: the angle of
attack ``alpha`` [**rad**] (minimises). Disturbance: the wind force ``F_wind`` [N] (maximises). Every angle the
API takes or returns is in radians; :func:`degrees_to_radians` converts, and :meth:`Glider.validate_state` /
:meth:`Glider.validate_control` reject values that look like degrees.

Dynamics (the DC9-30 landing model of Bayen, Mitchell, Oishi and Tomlin, JGCD 2007, which the paper's
parameters come from)::

    h'     = V sin(gamma)
    V'     = (-D(alpha, V) - m g sin(gamma) + F_wind) / m
    gamma' = L(alpha, V) / (m V) - g cos(gamma) / V
    C_L = cl0 + cl_alpha alpha,   L = half_rho_s C_L V^2,   D = (cd0 + cd_k C_L^2) V^2

The Hamiltonian is not control-affine: the drag is quadratic in ``C_L``, hence in ``alpha``, so the model
minimises a quadratic over the interval of ``C_L`` exactly (:meth:`Glider.hamiltonian`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from .. import backend as B
from .. import sets
from ..dynamics import Components
from ..problem import Model
from ..intervals import (round_down, round_up, iv_point, iv_add, iv_sub, iv_mul,
                         iv_div_pos, iv_sqr_pos, iv_sin, iv_cos, iv_hull_step, HALF_PI)

Array = B.Array

#: an angle above this many radians (about 28.6 degrees) is far outside every set of this model and far more
#: likely a value in degrees; the checks below refuse it rather than fly a 5-radian dive
DEGREES_SUSPECT = 0.5


def degrees_to_radians(value: Any) -> Any:
    """Degrees to radians for a Python number, a numpy array or a torch tensor.

    :param value: angle(s) in degrees
    :return: the same angle(s) in radians, of the same kind
    """
    return value * (math.pi / 180.0)


def radians_to_degrees(value: Any) -> Any:
    """Radians to degrees for a Python number, a numpy array or a torch tensor.

    :param value: angle(s) in radians
    :return: the same angle(s) in degrees, of the same kind
    """
    return value * (180.0 / math.pi)


def _sin(v: Any) -> Any:
    # a component may be a Python number next to torch tensors; torch.sin refuses numbers
    return math.sin(v) if isinstance(v, (int, float)) else B.namespace(v).sin(v)


def _cos(v: Any) -> Any:
    return math.cos(v) if isinstance(v, (int, float)) else B.namespace(v).cos(v)


def _as_numpy(value: Any) -> np.ndarray:
    """A numpy copy of a number, array or tensor, for the (rare, user-facing) checks below."""
    return np.asarray(B.to_numpy(value), dtype=float)


def _check_radians(name: str, value: Any) -> None:
    """Raise if ``value`` is non-finite or large enough in magnitude to be an angle in degrees."""
    arr = _as_numpy(value)
    if arr.size == 0:
        return
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    worst = float(arr.flat[np.argmax(np.abs(arr))])
    if abs(worst) > DEGREES_SUSPECT:
        raise ValueError(
            f"radians expected for {name}, got {worst!r} (looks like degrees; "
            f"convert with softreach.reach.models.glider.degrees_to_radians)"
        )


@dataclass(frozen=True)
class GliderParams:
    """Parameters of the fixed-wing emergency landing (paper §VI-B, spec §3). Angles are in **radians**.

    Aircraft (DC9-30, Bayen et al. 2007):

    :param mass: ``m`` [kg]
    :param gravity: ``g`` [m/s^2]
    :param half_rho_s: ``rho S / 2`` [kg/m], the lift factor ``L = half_rho_s C_L V^2``; ``68.6`` is
        ``1.225 kg/m^3 * 112 m^2 / 2``
    :param cl0: lift coefficient at ``alpha = 0`` [-]
    :param cl_alpha: lift slope ``dC_L/dalpha`` [1/rad]; positive, so ``C_L`` grows with ``alpha``
    :param cd0: zero-lift drag factor [kg/m] in ``D = (cd0 + cd_k C_L^2) V^2`` (``rho S/2`` is folded in)
    :param cd_k: induced drag factor [kg/m] in the same formula

    Inputs:

    :param alpha_bounds: angle of attack range ``(lo, hi)`` [rad], default ``[0, 13 deg]``
    :param wind_max: wind force bound, ``F_wind in [-wind_max, wind_max]`` [N]

    Sets and horizon:

    :param hard_speed: stall / maximum descent speed, ``C1`` [m/s]
    :param hard_gamma: flight-path corridor, ``C1`` [rad], default ``[-3 deg, 0 deg]``
    :param min_altitude: ground level [m]; the touchdown band is centred on it and ``C1`` requires
        ``h >= min_altitude - touchdown_altitude`` (see :class:`Glider`, "Touchdown")
    :param soft_speed: recommended speed range (5 m/s margins inside ``hard_speed``), ``C2`` [m/s]
    :param touchdown_altitude: half-width ``hb`` of the touchdown band ``|h - min_altitude| <= hb`` [m]
    :param max_sink_rate: largest touchdown sink rate ``-V sin(gamma)`` [m/s] (3 ft/s)
    :param horizon: ``T`` [s]

    Scales of the implicit functions (each set function is a distance divided by these):

    :param altitude_scale: [m] per unit of the implicit functions
    :param speed_scale: [m/s] per unit
    :param gamma_scale: [rad] per unit, default one degree, so flight-path distances count in degrees
    :param sink_rate_scale: [m/s] per unit of the sink-rate term of the target
    """

    mass: float = 60000.0
    gravity: float = 9.8
    half_rho_s: float = 68.6
    cl0: float = 1.25
    cl_alpha: float = 4.2
    cd0: float = 2.7
    cd_k: float = 3.08
    alpha_bounds: tuple[float, float] = (0.0, math.radians(13.0))
    wind_max: float = 10000.0
    hard_speed: tuple[float, float] = (61.0, 83.0)
    hard_gamma: tuple[float, float] = (math.radians(-3.0), 0.0)
    min_altitude: float = 0.0
    soft_speed: tuple[float, float] = (66.0, 78.0)
    touchdown_altitude: float = 0.5
    max_sink_rate: float = 0.91
    horizon: float = 10.0
    altitude_scale: float = 1.0
    speed_scale: float = 1.0
    gamma_scale: float = math.radians(1.0)
    sink_rate_scale: float = 1.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            values = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
                raise ValueError(f"GliderParams.{name} must be finite numbers, got {value!r}")
        positive = ("mass", "gravity", "half_rho_s", "cl_alpha", "horizon", "touchdown_altitude", "max_sink_rate",
                    "altitude_scale", "speed_scale", "gamma_scale", "sink_rate_scale")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"GliderParams.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("cd0", "cd_k", "wind_max"):  # drag never pushes forward; the wind box is symmetric
            if getattr(self, name) < 0:
                raise ValueError(f"GliderParams.{name} must be non-negative, got {getattr(self, name)!r}")
        for name in ("alpha_bounds", "hard_speed", "hard_gamma", "soft_speed"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"GliderParams.{name} must be an interval lo < hi, got {(lo, hi)!r}")
        for name in ("alpha_bounds", "hard_gamma"):
            _check_radians(f"GliderParams.{name}", getattr(self, name))
        if self.hard_speed[0] <= 0:
            # gamma' divides by V; the hard constraint keeps trajectories away from V = 0
            raise ValueError(f"GliderParams.hard_speed must be positive, got {self.hard_speed!r}")


class Glider(Model):
    """Longitudinal glide of a DC9-30 without thrust; state ``(h, V, gamma)`` in (m, m/s, **rad**).

    Control ``alpha`` [rad] in ``alpha_bounds`` (minimises); disturbance ``F_wind`` [N] in
    ``[-wind_max, wind_max]`` (maximises). Defaults (paper §VI-B):

    * hard ``C1 = {V in [61, 83], gamma in [-3 deg, 0 deg], h >= -hb}``; soft ``C2 = {V in [66, 78]}``
      (``h`` and ``gamma`` free: only the speed margins cost budget);
    * target ``T = {|h| <= hb, -V sin(gamma) <= 0.91 m/s}`` with ``hb = 0.5 m``;
    * horizon ``T = 10 s``.

    **Touchdown.** The paper's target is touchdown at ``h = 0`` with a sink rate of at most 0.91 m/s, and its
    ``C1`` keeps ``h >= 0``. On a grid the set "at ``h = 0`` and ``h >= 0``" has no interior: every node of it
    has ``c1 = 0``, so ``W >= 0`` there and the sets hang on exact ties (measured with the ground bound at
    ``h >= 0``, 21 x 15 x 13 x 21 nodes: ``min W = 0`` exactly, every set was made of ties ``W = 0`` only and
    empty under the paper's ``W + 1e-3 <= 0`` proxy). Touchdown is therefore the band ``|h| <= hb`` and the
    ground bound of ``C1`` is the band's bottom, ``h >= -hb``: the aircraft must bring its sink rate within
    0.91 m/s while within ``hb`` of the ground, and may not pass below the band. Since ``h' = V sin(gamma) <= 0``
    in ``C1``, a descent that leaves the band downwards without landing can never land afterwards, so the ground
    bound only cuts off states that are lost anyway. ``T`` and ``C1`` then share the interior
    ``|h| < hb`` (depth ``hb / altitude_scale`` = 0.5 units at ``h = 0``).

    **Scaling of the implicit functions.** Each is a Chebyshev box distance (:func:`softreach.reach.sets.box`)
    with every coordinate divided by its scale: ``h`` by ``altitude_scale`` (1 m), ``V`` by ``speed_scale``
    (1 m/s), ``gamma`` by ``gamma_scale`` (1 degree, so a flight-path distance counts in degrees: 1 deg is as
    far as 1 m/s or 1 m). The sink-rate term of the target is ``(-V sin(gamma) - max_sink_rate) /
    sink_rate_scale`` (1 m/s); its slope along ``gamma`` is ``V cos(gamma)`` m/s per rad, about 1.26 per
    degree at 72 m/s, the same order as the box terms. ``c2`` is in m/s, so ``eps`` is in m/s too.

    **Default grid box** (:attr:`domain`): ``h in [-3, 42] m``, ``V in [58, 86] m/s``,
    ``gamma in [-4 deg, 1 deg]``: 2.5 m below the ground bound, 2 m above the 40 m start altitudes, 3 m/s and
    one degree beyond ``C1``, so the sets' boundaries lie inside the grid, away from its edges. The default
    grid, 91 x 29 x 31 nodes (0.5 m, 1 m/s, 1/6 deg) with 31 budget nodes, puts ``h = 0``, ``+-hb``, the speed
    limits 61, 66, 78, 83 m/s and the flight-path limits -3, 0 deg on nodes; so do 46 (1 m) or 181 (0.25 m)
    altitude nodes, 57 (0.5 m/s) speed nodes and 21, 41 or 51 (0.25, 0.125, 0.1 deg) flight-path nodes.

    **Units.** The grid path (:meth:`f`, :meth:`hamiltonian`, ...) takes radians and checks nothing, for speed.
    The batched-point path :meth:`f_array` checks its inputs with :meth:`validate_state` and
    :meth:`validate_control`, which refuse angles beyond 0.5 rad as "looks like degrees"; call them yourself
    on states and controls that come from users.
    """

    name = "glider"
    state_names = ("h", "V", "gamma")
    state_units = ("m", "m/s", "rad")
    control_units = ("rad",)
    disturbance_units = ("N",)
    #: the start distribution of ``GliderLanding-v0`` (and of the generic env with this model)
    start_box = ((2.0, 66.0, math.radians(-2.5)), (40.0, 78.0, math.radians(-0.5)))
    start_budget = (0.0, 10.0)

    def __init__(self, params: GliderParams | None = None, **overrides: Any):
        """:param params: a full parameter set; or pass :class:`GliderParams` fields as keyword overrides"""
        if params is None:
            params = GliderParams(**overrides)
        elif overrides:
            raise TypeError("pass either params or keyword overrides, not both")
        self.params = params
        p = params
        self.control_bounds = ((float(p.alpha_bounds[0]),), (float(p.alpha_bounds[1]),))
        self.disturbance_bounds = ((-float(p.wind_max),), (float(p.wind_max),))
        self.horizon = p.horizon
        self.domain = ((-3.0, 58.0, math.radians(-4.0)), (42.0, 86.0, math.radians(1.0)))
        # C1 is unbounded above in h; the start altitudes [0, 40] m stand in for its top so that a grid must hold them
        self.hard_box = ((p.min_altitude - p.touchdown_altitude, p.hard_speed[0], p.hard_gamma[0]),
                         (40.0, p.hard_speed[1], p.hard_gamma[1]))
        # 0.5 m x 1 m/s x 1/6 deg x 0.37 s: about 3 min for V and W_eps at --accuracy very_high with one torch
        # thread on the shared 2-core machine (docs/glider.md has the grid study and a finer grid)
        self.default_shape = (91, 29, 31)
        self.default_budget_points = 31
        # kappa [m/s per s]: about the rate at which the inputs change the speed margin c2 (|V'| from drag, gravity
        # and wind is 0.5-2 m/s^2 in C1); measured: the set measures change by at most 10% for kappa in [0.5, 5],
        # and kappa = 1 keeps the most of RA~_0 (docs/glider.md)
        self.budget_scale = 1.0
        self.default_budgets = (0.0, 5.0, 10.0)
        self.paper_budgets = (0.0, 5.0, 10.0)
        self.default_snapshots = 21
        #: the environment's control period [s]: the sampled-data table and the filter hold actions this long
        self.control_period = 0.1
        #: RK4 sub-steps per control period in the environment; their ends are where landing and ``C1`` are checked
        #: (0.05 s, RK4 error below 1e-9 (envs/glider_landing.py))
        self.substeps = 2
        #: the target's altitude band (its sink-rate term is not a box, so the other axes are unbounded)
        self.target_box = ((p.min_altitude - p.touchdown_altitude, -math.inf, -math.inf),
                           (p.min_altitude + p.touchdown_altitude, math.inf, math.inf))
        # C_L over the control box; cl_alpha > 0 maps the alpha interval onto it in order
        self._cl_bounds = (p.cl0 + p.cl_alpha * p.alpha_bounds[0], p.cl0 + p.cl_alpha * p.alpha_bounds[1])

    def parameters(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self.params).items()}

    # ------------------------------------------------------------------------------------------ dynamics
    def lift_coefficient(self, alpha: Array | float) -> Array | float:
        """``C_L(alpha) = cl0 + cl_alpha alpha``.

        :param alpha: angle of attack [rad]
        """
        return self.params.cl0 + self.params.cl_alpha * alpha

    def lift(self, alpha: Array | float, V: Array | float) -> Array | float:
        """``L = half_rho_s C_L V^2`` [N].

        :param alpha: angle of attack [rad]
        :param V: airspeed [m/s]
        """
        return self.params.half_rho_s * self.lift_coefficient(alpha) * V * V

    def drag(self, alpha: Array | float, V: Array | float) -> Array | float:
        """``D = (cd0 + cd_k C_L^2) V^2`` [N].

        :param alpha: angle of attack [rad]
        :param V: airspeed [m/s]
        """
        c = self.lift_coefficient(alpha)
        return (self.params.cd0 + self.params.cd_k * c * c) * V * V

    def trim_alpha(self, V: Array | float, gamma: Array | float) -> Array | float:
        """The angle of attack [rad] that holds the flight path (``gamma' = 0``), not clipped to the bounds.

        ``L = m g cos(gamma)`` gives ``C_L = m g cos(gamma) / (half_rho_s V^2)``. Above the upper bound the
        aircraft cannot hold its path at that speed (near stall); below the lower bound it climbs even at the
        lowest angle.

        :param V: airspeed [m/s]
        :param gamma: flight-path angle [rad]
        """
        p = self.params
        c = p.mass * p.gravity * _cos(gamma) / (p.half_rho_s * V * V)
        return (c - p.cl0) / p.cl_alpha

    def f(self, t: float, x: Components, a: Components, b: Components) -> list[Array]:
        """The vector field ``(h', V', gamma')``.

        :param t: time [s] (unused: the dynamics are autonomous)
        :param x: ``(h [m], V [m/s], gamma [rad])``, broadcastable components
        :param a: ``(alpha [rad],)``
        :param b: ``(F_wind [N],)``
        """
        p = self.params
        _, V, gamma = x
        (alpha,), (wind,) = a, b
        c = self.lift_coefficient(alpha)
        sg, cg = _sin(gamma), _cos(gamma)
        h_dot = V * sg
        V_dot = -(p.cd0 + p.cd_k * c * c) * V * V / p.mass - p.gravity * sg + wind / p.mass
        gamma_dot = p.half_rho_s * c * V / p.mass - p.gravity * cg / V
        return [h_dot, V_dot, gamma_dot]

    def f_array(self, t: float, x: Array, a: Array, b: Array) -> Array:
        """:meth:`f` on stacked arrays ``x (..., 3)``, ``a (..., 1)``, ``b (..., 1)``, after unit checks.

        :raises ValueError: on angles that look like degrees, ``V <= 0`` or non-finite values
        """
        self.validate_state(x)
        self.validate_control(a)
        return super().f_array(t, x, a, b)

    # ------------------------------------------------------------------------------------------ enclosures
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
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != 3:
            raise ValueError(f"x must have shape (N, 3) (h, V, gamma), got {x.shape}")
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
        self.validate_control(alpha)
        p = self.params
        # C_L is computed once per row as an interval: the float product cl_alpha * alpha is itself rounded
        c = iv_add(iv_point(p.cl0), iv_mul(iv_point(p.cl_alpha), iv_point(alpha)))

        def describe(i: int) -> str:
            return (f"row {i}: state (h, V, gamma) = ({float(x[i, 0])!r} m, {float(x[i, 1])!r} m/s, "
                    f"{float(x[i, 2])!r} rad), alpha = {float(alpha[i])!r} rad, dt = {dt!r} s")

        def field(lo: np.ndarray, hi: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            # the helpers name only the offending interval; add which row and state it came from
            bad_V = ~(lo[:, 1] > 0)
            bad_g = ~((lo[:, 2] > -HALF_PI) & (hi[:, 2] < HALF_PI))
            if np.any(bad_V | bad_g):
                k = int(np.flatnonzero(bad_V | bad_g)[0])
                what = (f"V in [{float(lo[k, 1])!r}, {float(hi[k, 1])!r}] m/s reaches <= 0" if bad_V[k] else
                        f"gamma in [{float(lo[k, 2])!r}, {float(hi[k, 2])!r}] rad leaves (-pi/2, pi/2)")
                raise ValueError(f"no enclosure for {describe(int(rows[k]))}: a candidate tube has {what}; "
                                 f"shorten dt")
            return self._interval_field(lo, hi, (c[0][rows], c[1][rows]))

        def inflate(lo: np.ndarray, hi: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            pad = (self._ENCLOSURE_INFLATE_REL * (hi - lo) + self._ENCLOSURE_INFLATE_ABS
                   + self._ENCLOSURE_INFLATE_STATE * np.abs(x[rows]))
            return lo - pad, hi + pad

        all_rows = np.arange(n)
        X_lo, X_hi = inflate(*iv_hull_step(x, dt, field(x, x, all_rows)), all_rows)
        tube_lo, tube_hi = np.empty((n, 3)), np.empty((n, 3))
        todo = all_rows
        for _ in range(self._ENCLOSURE_MAX_TRIES):
            Y_lo, Y_hi = iv_hull_step(x[todo], dt, field(X_lo, X_hi, todo))
            # strict containment: the exit-time argument needs Y inside the interior of X
            ok = np.all((Y_lo > X_lo) & (Y_hi < X_hi), axis=1)
            # Y (not X) is kept: it is contained in X and holds the trajectories too (step 3)
            tube_lo[todo[ok]], tube_hi[todo[ok]] = Y_lo[ok], Y_hi[ok]
            todo = todo[~ok]
            if todo.size == 0:
                break
            X_lo, X_hi = inflate(Y_lo[~ok], Y_hi[~ok], todo)
        else:
            raise ValueError(f"no enclosure for {describe(int(todo[0]))} after {self._ENCLOSURE_MAX_TRIES} "
                             f"candidates ({todo.size} rows failed); shorten dt")

        for _ in range(self._ENCLOSURE_REFINE):
            Y_lo, Y_hi = iv_hull_step(x, dt, field(tube_lo, tube_hi, all_rows))
            tube_lo, tube_hi = np.maximum(tube_lo, Y_lo), np.minimum(tube_hi, Y_hi)

        d_lo, d_hi = field(tube_lo, tube_hi, all_rows)
        end_lo = np.maximum(round_down(x + round_down(dt * d_lo)), tube_lo)
        end_hi = np.minimum(round_up(x + round_up(dt * d_hi)), tube_hi)
        return tube_lo, tube_hi, end_lo, end_hi

    # ------------------------------------------------------------------------------------------ game
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

    # ------------------------------------------------------------------------------------------ sets
    def _scales(self) -> tuple[float, float, float]:
        p = self.params
        return (p.altitude_scale, p.speed_scale, p.gamma_scale)

    def sink_rate(self, x: Components) -> Array:
        """``-V sin(gamma)`` [m/s], positive when descending.

        :param x: ``(h, V, gamma)`` components [m, m/s, rad] (arrays, or numbers for one state)
        """
        return -x[1] * _sin(x[2])

    def start_difficulty(self, x: Components) -> Array:
        """The altitude ``h``: the paper's representative starts are the highest of each set."""
        return x[0]

    def target(self, t: float, x: Components) -> Array:
        """``g = max(box distance to |h| <= hb in altitude units, (sink rate - max_sink_rate) / sink_rate_scale)``.

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        """
        p = self.params
        band = sets.box([x[0]], (p.min_altitude - p.touchdown_altitude,), (p.min_altitude + p.touchdown_altitude,),
                        (p.altitude_scale,))
        sink = (self.sink_rate(x) - p.max_sink_rate) / p.sink_rate_scale
        return B.maximum(band, sink) if hasattr(band, "shape") else B.maximum(sink, band)

    def hard_constraint(self, t: float, x: Components) -> Array:
        """``c1``: scaled box distance to ``{h >= min_altitude - hb, V in hard_speed, gamma in hard_gamma}``.

        The ground bound sits at the bottom of the touchdown band (class docstring, "Touchdown").

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        """
        p = self.params
        lo = (p.min_altitude - p.touchdown_altitude, p.hard_speed[0], p.hard_gamma[0])
        hi = (sets.INF, p.hard_speed[1], p.hard_gamma[1])
        return sets.box(x, lo, hi, self._scales())

    def soft_constraint(self, t: float, x: Components) -> Array:
        """``c2``: scaled distance to ``{V in soft_speed}`` [units of ``speed_scale``].

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        """
        p = self.params
        return sets.box([x[1]], (p.soft_speed[0],), (p.soft_speed[1],), (p.speed_scale,))

    # ------------------------------------------------------------------------------------------ units
    def validate_state(self, x: Array | Sequence[Any]) -> None:
        """Refuse a state that is non-finite, has ``V <= 0`` or an angle that looks like degrees.

        :param x: a stacked array ``(..., 3)`` or a sequence ``(h, V, gamma)`` of numbers or arrays
        :raises ValueError: naming the offending value
        """
        if hasattr(x, "shape") and len(x.shape) >= 1 and not isinstance(x, (list, tuple)):
            if x.shape[-1] != 3:
                raise ValueError(f"a glider state has 3 components (h, V, gamma), got shape {tuple(x.shape)}")
            h, V, gamma = x[..., 0], x[..., 1], x[..., 2]
        else:
            if len(x) != 3:
                raise ValueError(f"a glider state has 3 components (h, V, gamma), got {len(x)}")
            h, V, gamma = x
        for name, v in (("h", h), ("V", V)):
            arr = _as_numpy(v)
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"state component {name} must be finite, got {v!r}")
            if name == "V" and arr.size and float(arr.min()) <= 0:
                # gamma' divides by V; a zero or negative airspeed is a wrong unit or a wrong column
                raise ValueError(f"airspeed V must be positive [m/s], got {float(arr.min())!r}")
        _check_radians("gamma", gamma)

    def validate_control(self, alpha: Array | float) -> None:
        """Refuse an angle of attack that is non-finite or looks like degrees.

        Values inside 0.5 rad but outside ``alpha_bounds`` pass: the simulator clips them
        (:meth:`clip_control`), as it does any control.

        :param alpha: angle(s) of attack [rad], a number or an array (a trailing axis of size 1 is fine)
        :raises ValueError: naming the offending value
        """
        _check_radians("alpha", alpha)


def _register() -> None:
    # at the end of the module: the package's __init__ imports this module lazily, after it is complete
    from . import register_model

    register_model("glider", Glider)


_register()

__all__ = ["Glider", "GliderParams", "degrees_to_radians", "radians_to_degrees", "DEGREES_SUSPECT"]
