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
from dataclasses import asdict
from typing import Any, Sequence

import numpy as np

from .. import backend as B
from .. import sets
from ..dynamics import Components
from ..jit import njit
from ..proof.model_kernels import box_distance_max, box_params
from ..model_report import LANDING_WORDS
from ..problem import Model
from .glider_enclosure import GliderHeldEnclosure
from .glider_game import GliderGame
# re-exported: users take the parameters and the angle helpers from the model module
from .glider_params import (DEGREES_SUSPECT, GliderParams, _as_numpy, _check_radians, _cos, _sin,
                            degrees_to_radians, radians_to_degrees)

Array = B.Array


@njit
def _set_max(params, which, lo, hi):
    """The largest value of the glider's set ``which`` (:data:`~softreach.reach.proof.model_kernels.SET_INDEX`) over the box
    ``[lo, hi]``: its box distance's, and for the target also the sink-rate term's, which is ``-V sin(gamma)``,
    bilinear in ``V`` and ``sin(gamma)`` with ``sin`` increasing on ``(-pi/2, pi/2)``: largest at a corner."""
    out = box_distance_max(params, 9 * which, lo, hi)
    if which == 0 and not math.isnan(out):
        limit, scale = params[27], params[28]
        for V in (lo[1], hi[1]):
            for gamma in (lo[2], hi[2]):
                sink = (-V * math.sin(gamma) - limit) / scale
                if math.isnan(sink):
                    return np.nan
                out = max(out, sink)
    return out


class Glider(GliderGame, GliderHeldEnclosure, Model):
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

    **Structure.** The dynamics and the sets are here; the game (Hamiltonian, optimal inputs, dissipation) is the
    base class :class:`~softreach.reach.models.glider_game.GliderGame`, the held-period enclosures of the safety
    filter are :class:`~softreach.reach.models.glider_enclosure.GliderHeldEnclosure`, and the parameters are
    :class:`~softreach.reach.models.glider_params.GliderParams`.

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
    words = LANDING_WORDS

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
        # the cell certificates (0.25 m x 0.125 m/s x 1/12 deg) and plans of every length up to 8 periods: finer cells
        # and every plan length certify more of the table's own set, twice these cells little more for twice the
        # memory (the shapes measured against each other: docs/filters.md, "The glider on cells")
        self.cell_shape = (164, 176, 36)
        self.cell_holds = (1, 2, 3, 4, 5, 6, 7, 8)
        # a start's own plan may hold two angles in sequence: it certifies starts the table puts in its set where no
        # single angle does, for tens of milliseconds a reset (docs/filters.md, "A start's own plan")
        self.start_segments = 2
        # nine angles of attack (1.625 deg apart) held for a period, not five: the cells then certify more states, for
        # a held solve and a cell build that take about twice as long (docs/filters.md, "The glider on cells")
        self.held_levels = 9
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
        band = sets.box(x, *self._set_boxes()["target"])
        sink = (self.sink_rate(x) - p.max_sink_rate) / p.sink_rate_scale
        return B.maximum(band, sink) if hasattr(band, "shape") else B.maximum(sink, band)

    def hard_constraint(self, t: float, x: Components) -> Array:
        """``c1``: scaled box distance to ``{h >= min_altitude - hb, V in hard_speed, gamma in hard_gamma}``.

        The ground bound sits at the bottom of the touchdown band (class docstring, "Touchdown").

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        """
        return sets.box(x, *self._set_boxes()["hard_constraint"])

    def soft_constraint(self, t: float, x: Components) -> Array:
        """``c2``: scaled distance to ``{V in soft_speed}`` [units of ``speed_scale``].

        :param t: time [s] (unused)
        :param x: ``(h, V, gamma)`` components [m, m/s, rad]
        """
        return sets.box(x, *self._set_boxes()["soft_constraint"])

    def _set_boxes(self) -> dict[str, tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]]:
        """``(lo, hi, scale)`` of the box distance in each set: the target's altitude band (its sink-rate term is
        not a box), ``C1`` and ``C2``; an unbounded axis has no term."""
        p, inf = self.params, sets.INF
        return {"target": ((p.min_altitude - p.touchdown_altitude, -inf, -inf),
                           (p.min_altitude + p.touchdown_altitude, inf, inf), (p.altitude_scale, 1.0, 1.0)),
                "hard_constraint": ((p.min_altitude - p.touchdown_altitude, p.hard_speed[0], p.hard_gamma[0]),
                                    (inf, p.hard_speed[1], p.hard_gamma[1]), self._scales()),
                "soft_constraint": ((-inf, p.soft_speed[0], -inf), (inf, p.soft_speed[1], inf),
                                    (1.0, p.speed_scale, 1.0))}

    #: the sets over boxes, compiled (:attr:`~softreach.reach.problem.Model.set_max_kernel`)
    set_max_kernel = staticmethod(_set_max)

    @property
    def set_max_params(self) -> np.ndarray:
        """:func:`_set_max`'s numbers: the three sets' box distances
        (:func:`~softreach.reach.proof.model_kernels.box_params`), then the sink-rate limit and scale."""
        p = self.params
        return np.concatenate([box_params(self._set_boxes(), 3), [p.max_sink_rate, p.sink_rate_scale]])

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
