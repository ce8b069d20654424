"""The 1-D point-mass landing of the paper's §VI-A (spec §2)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .. import sets
from ..dynamics import ControlAndDisturbanceAffine
from ..jit import njit
from ..model_report import LANDING_WORDS
from ..problem import Model


@dataclass(frozen=True)
class PointMassParams:
    """Parameters of the point-mass landing (paper §VI-A).

    :param gravity: ``g`` [m/s^2]
    :param u_max: thrust acceleration bound, ``u in [-u_max, u_max]`` [m/s^2]
    :param d_max: disturbance bound, ``d in [-d_max, d_max]`` [m/s^2]
    :param target_speed: touchdown speed band [m/s]
    :param target_altitude: touchdown altitude band [m]
    :param hard_speed: design speed range (``C1``) [m/s]
    :param soft_speed: recommended speed range (``C2``) [m/s]
    :param altitude: altitude range shared by ``C1`` and ``C2`` [m]
    :param horizon: ``T`` [s]
    """

    gravity: float = 9.8
    u_max: float = 60.0
    d_max: float = 10.0
    target_speed: tuple[float, float] = (-1.0, 0.0)
    target_altitude: tuple[float, float] = (0.0, 0.7)
    hard_speed: tuple[float, float] = (-15.0, 15.0)
    soft_speed: tuple[float, float] = (-10.0, 10.0)
    altitude: tuple[float, float] = (0.0, 18.0)
    horizon: float = 1.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            values = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
                raise ValueError(f"PointMassParams.{name} must be finite, got {value!r}")
        for name in ("u_max", "d_max", "horizon", "gravity"):
            if getattr(self, name) <= 0:
                raise ValueError(f"PointMassParams.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("target_speed", "target_altitude", "hard_speed", "soft_speed", "altitude"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"PointMassParams.{name} must be an interval lo < hi, got {(lo, hi)!r}")


class PointMass(Model, ControlAndDisturbanceAffine):
    """Vertical point mass ``y'' = u - g + d``; state ``(v, y) = (y', y)`` in (m/s, m).

    Control ``u`` [m/s^2] in ``[-u_max, u_max]`` (minimises); disturbance ``d`` [m/s^2] in ``[-d_max, d_max]``
    (maximises). Sets are boxes; their implicit functions are Chebyshev box distances **unscaled**, i.e. in m/s
    along ``v`` and in m along ``y`` (as the paper's signed distances), so ``eps`` is in m/s.

    * target ``T = {v in [-1, 0], y in [0, 0.7]}``
    * hard ``C1 = {v in [-15, 15], y in [0, 18]}``, soft ``C2 = {v in [-10, 10], y in [0, 18]}``
    * horizon ``T = 1 s``; default grid box ``v in [-20, 20]``, ``y in [-5, 20]``.
    """

    name = "pointmass"
    state_names = ("v", "y")
    state_units = ("m/s", "m")
    control_units = ("m/s^2",)
    disturbance_units = ("m/s^2",)
    #: the start distribution of ``PointMassLanding-v0`` (and of the generic env with this model)
    start_box = ((-5.0, 1.0), (5.0, 12.0))
    start_budget = (0.0, 0.6)
    words = LANDING_WORDS

    def __init__(self, params: PointMassParams | None = None, **overrides: Any):
        if params is None:
            params = PointMassParams(**overrides)
        elif overrides:
            raise TypeError("pass either params or keyword overrides, not both")
        self.params = params
        p = params
        self.control_bounds = ((-p.u_max,), (p.u_max,))
        self.disturbance_bounds = ((-p.d_max,), (p.d_max,))
        self.horizon = p.horizon
        self.domain = ((-20.0, -5.0), (20.0, 20.0))
        self.hard_box = ((p.hard_speed[0], p.altitude[0]), (p.hard_speed[1], p.altitude[1]))
        self.target_box = ((p.target_speed[0], p.target_altitude[0]), (p.target_speed[1], p.target_altitude[1]))
        self.default_shape = (101, 101)
        # the cell certificates: 0.0857 m/s x 6.25 mm. A run that rides a speed limit keeps a cell's width from it,
        # and landing rides the stopping boundary near the ground, where the altitude cell decides how much of it the
        # cells keep. Candidates 30 m/s^2 apart end a period 0.3 m/s apart, 3.5 cells (at 300 cells, 3: there the
        # states two neighbouring candidates pass from abut at one cell edge, and no single candidate passes from
        # an end box across it, which made more interventions needless). Plans of 2 and 4 periods let a cell
        # slower than 6.25 mm per period make progress; 8 certified no more (docs/filters.md, "Certificates on
        # cells", and the audit's table by cell shape)
        self.cell_shape = (350, 2880)
        self.cell_holds = (1, 2, 4)
        self.default_budget_points = 111
        # softreach solve --held: the filter's cells prove its certificate and the held table only ranks candidates,
        # so a coarser table certifies the same states in a fraction of the time (docs/filters.md, "Time to a
        # certified filter")
        self.held_shape, self.held_budget_points = (51, 51), 56
        self.default_snapshots = 41  # every 25 ms: the filter and the W-derived control read W(t, .) over the horizon
        # c2 is a speed margin [m/s]; the net authority u_max - d_max [m/s^2] is how fast it can be restored
        self.budget_scale = p.u_max - p.d_max
        #: the environment's control period [s]: the sampled-data table and the filter hold actions this long
        self.control_period = 0.01
        #: RK4 sub-steps per control period in the environment; their ends are where landing and ``C1`` are checked
        #: (every millisecond; RK4 is exact at any count for this quadratic motion)
        self.substeps = 10
        # hover (v' = d): the held action that rides a speed limit with the least drift
        self.trim_controls = ((p.gravity,),) if p.gravity <= p.u_max else ()
        self.held_box_kernel, self.held_box_params = held_box_kernel, np.array([p.gravity, p.d_max])
        # every set is a plain box distance (sets.box, no scale): the filter's compiled test bounds them
        self.set_boxes = {"target": self.target_box, "hard_constraint": self.hard_box,
                          "soft_constraint": ((p.soft_speed[0], p.altitude[0]), (p.soft_speed[1], p.altitude[1]))}

    def parameters(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self.params).items()}

    # dynamics: v' = -g + u + d, y' = v
    def rk4_error(self, h: float) -> np.ndarray:
        """Zero: with the thrust and the wind held over a sub-step (as the environment holds them), the speed is
        linear and the altitude quadratic in time, and RK4 integrates a motion polynomial in time of degree at most 4
        exactly, rounding aside."""
        return np.zeros(2)

    def rk4_stage_error(self, h: float) -> np.ndarray:
        """RK4's middle stages read the altitude of the start's speed held for half the sub-step, ``y + h v / 2``,
        and of the speed after it, ``y + h (v + h a / 2) / 2``: ``h^2 / 8`` times the acceleration ``a`` below and
        above the exact ``y(h / 2)``, whatever the wind; the speed's stages and the last stage are exact. So at most
        ``h^2 / 8 (u_max + d_max + g)`` along ``y``."""
        p = self.params
        return np.array([0.0, h * h / 8.0 * (p.u_max + p.d_max + p.gravity)])

    def drift(self, t, x):
        return [-self.params.gravity, x[0]]

    def control_matrix(self, t, x):
        return [[1.0], [0]]

    def disturbance_matrix(self, t, x):
        return [[1.0], [0]]

    def sink_rate(self, x) -> float:
        """The vertical speed downwards, ``-v`` [m/s].

        :param x: one state ``(v, y)``
        """
        return -float(x[0])

    def start_difficulty(self, x):
        """The altitude ``y``: the paper's representative starts are the highest of each set."""
        return x[1]

    # sets
    def target(self, t, x):
        p = self.params
        return sets.box(x, (p.target_speed[0], p.target_altitude[0]), (p.target_speed[1], p.target_altitude[1]))

    def hard_constraint(self, t, x):
        p = self.params
        return sets.box(x, (p.hard_speed[0], p.altitude[0]), (p.hard_speed[1], p.altitude[1]))

    def soft_constraint(self, t, x):
        p = self.params
        return sets.box(x, (p.soft_speed[0], p.altitude[0]), (p.soft_speed[1], p.altitude[1]))

    # scalar fast paths: the same functions at one point of finite Python floats, without building arrays. The
    # environments call them for every RK4 stage; they repeat the arithmetic of f and of the sets above operation
    # for operation (box distances: the same differences, the larger kept), so they give the same numbers, which
    # tests/test_envs_fastpath.py checks. The maxima are written out: cheaper than max() on four floats.
    def f_scalar(self, t: float, x, a, b) -> tuple[float, float]:
        """:meth:`f` at one point: ``x = (v, y)``, ``a = (u,)``, ``b = (d,)`` Python floats; a tuple of floats."""
        return (-self.params.gravity + a[0] + b[0], x[0])

    def target_scalar(self, t: float, x) -> float:
        """:meth:`target` at one point ``x = (v, y)`` of finite Python floats."""
        return _box_scalar(x, self.params.target_speed, self.params.target_altitude)

    def hard_constraint_scalar(self, t: float, x) -> float:
        """:meth:`hard_constraint` at one point ``x = (v, y)`` of finite Python floats."""
        return _box_scalar(x, self.params.hard_speed, self.params.altitude)

    def violation_rate_scalar(self, t: float, x, eps: float) -> float:
        """:meth:`violation_rate` ``h_eps = min(1, max(0, c2 / eps))`` at one point ``x = (v, y)`` of finite Python
        floats."""
        r = _box_scalar(x, self.params.soft_speed, self.params.altitude) / eps
        return 0.0 if r <= 0.0 else (1.0 if r >= 1.0 else r)

    def exact_ceiling(self) -> float:
        """The highest altitude from ``v = 0`` at ``t = 0`` that lands with ``Q = 0`` (spec §4).

        The disturbance enters where the control does, so the game is a control-only double integrator with
        ``|u'| <= u_max - d_max``. From rest: full down-thrust to the soft speed limit, coast, full brake to the
        fastest touchdown speed, all within the horizon. Used by the tests as an exact reference.
        """
        p = self.params
        authority = p.u_max - p.d_max
        acc_down, acc_brake = p.gravity + authority, authority - p.gravity
        v_lim = min(-p.soft_speed[0], -p.hard_speed[0])
        v_land = -p.target_speed[0]  # touch down at the fastest allowed sink rate, at the top of the band
        t1 = v_lim / acc_down
        t3 = (v_lim - v_land) / acc_brake
        t2 = p.horizon - t1 - t3
        if t2 < 0:
            raise ValueError("horizon too short for the bang-coast-bang profile; no closed form here")
        drop = 0.5 * acc_down * t1**2 + v_lim * t2 + (v_lim * t3 - 0.5 * acc_brake * t3**2)
        return drop + p.target_altitude[1]


@njit
def held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """The box of every state reachable at some time in ``[s0, s1]`` of a period with the thrust ``a[0]`` held, from
    every start in ``[x_lo, x_hi]`` (:attr:`~softreach.reach.model_filter.FilterPart.held_box_kernel`, from which the
    model's enclosure methods are derived), written into ``lo`` and ``hi``; ``params`` is ``(gravity, d_max)``.

    ``v(s) = v + (u - g) s + D(s)`` and ``y(s) = y + v s + (u - g) s^2 / 2 + int_0^s D`` with ``D(s) = int_0^s d``,
    ``|D(s)| <= d_max s``: so ``v(s)`` lies between the two straight lines of slopes ``u - g -+ d_max``, extreme at
    the interval's ends, and ``y(s)`` between the two parabolas ``y + v s + (u - g -+ d_max) s^2 / 2``, extreme at
    an end or where ``v`` vanishes. Every bound grows with ``v`` and ``y`` (the motion is monotone in the start), so
    the lower bounds come from ``x_lo``, the upper from ``x_hi``. Every bound is reached by a constant extreme wind,
    so the boxes are the tightest boxes (the reachable set itself is a lens inside the end box)."""
    acc_lo = a[0] - params[0] - params[1]
    acc_hi = a[0] - params[0] + params[1]
    lo[0] = min(x_lo[0] + acc_lo * s0, x_lo[0] + acc_lo * s1)
    hi[0] = max(x_hi[0] + acc_hi * s0, x_hi[0] + acc_hi * s1)
    lo[1] = _parabola(x_lo[1], x_lo[0], acc_lo, s0, s1, False)
    hi[1] = _parabola(x_hi[1], x_hi[0], acc_hi, s0, s1, True)


@njit
def _parabola(y, v, acc, s0, s1, largest):
    """The smallest (or ``largest``) value of ``y + v s + acc s^2 / 2`` over ``s`` in ``[s0, s1]``: at an end or
    where its slope ``v + acc s`` vanishes."""
    q0 = y + v * s0 + 0.5 * acc * s0 * s0
    q1 = y + v * s1 + 0.5 * acc * s1 * s1
    out = max(q0, q1) if largest else min(q0, q1)
    s = -v / acc if acc != 0 else -1.0
    if s0 < s < s1:
        q = y + v * s + 0.5 * acc * s * s
        out = max(out, q) if largest else min(out, q)
    return out


def _box_scalar(x, speed: tuple[float, float], altitude: tuple[float, float]) -> float:
    """:func:`softreach.reach.sets.box` at one point ``(v, y)``: the same differences, the larger kept, in the same
    order (so the same float), with the maxima written out (cheaper than ``max()`` on four floats)."""
    v, y = x
    c = speed[0] - v
    d = v - speed[1]
    if d > c:
        c = d
    d = altitude[0] - y
    if d > c:
        c = d
    d = y - altitude[1]
    return d if d > c else c
