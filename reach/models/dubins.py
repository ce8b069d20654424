"""A planar Dubins vehicle in a cross-wind: reach a goal past an obstacle, crossing a soft zone for a limited time.

Not from the paper: a third system built on the public model API only (this file and its registration in
:mod:`softreach.reach.registry` are all it adds). State ``(x, y, theta)``: position [m] and heading [rad], the
heading axis **periodic** (``[-pi, pi)``). The vehicle flies at a constant speed ``v`` and turns at a rate
``u`` (the control, minimises); a wind ``(w_x, w_y)`` in a box (the disturbance, maximises) adds to the position
rates::

    x' = v cos(theta) + w_x,    y' = v sin(theta) + w_y,    theta' = u

Sets (implicit functions in metres, so ``eps`` is in metres too):

* target: the goal disc, ``g = |p - goal| - goal_radius``;
* hard ``C1``: outside the obstacle disc and inside the arena box,
  ``c1 = max(obstacle_radius - |p - obstacle|, box distance to the arena)``;
* soft ``C2``: outside the soft zone (a restricted airspace, a puddle), ``c2 = zone_radius - |p - zone|``.

The default layout puts the obstacle between the start region (west) and the goal (east) and the soft zone just
north of the obstacle: the short way passes through the zone, the ways around it take longer than the horizon
allows against the wind from most western starts, so the sets grow with the budget (measured on a 33 x 33 x 24
grid: of the default starts, 10 % are in ``RA~_0``, 18 % in ``RA~_1`` and 86 % in ``RA~_2``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .. import backend as B
from .. import sets
from ..dynamics import Components, ControlAndDisturbanceAffine
from ..jit import njit
from ..proof.intervals import cos_range, down, sin_range, up
from ..proof.model_kernels import SET_INDEX, set_max_address, set_max_rows
from ..problem import Model

Array = B.Array


def _cos(v: Any) -> Any:
    # the environments pass Python floats, the solver torch tensors (torch.cos refuses floats)
    return math.cos(v) if isinstance(v, (int, float)) else B.namespace(v).cos(v)


def _sin(v: Any) -> Any:
    return math.sin(v) if isinstance(v, (int, float)) else B.namespace(v).sin(v)


def _sqrt(v: Any) -> Any:
    return math.sqrt(v) if isinstance(v, (int, float)) else B.namespace(v).sqrt(v)


@njit
def held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """The box of every state at some time in ``[s0, s1]`` of a period with the turn rate ``a[0]`` held, from every
    start in ``[x_lo, x_hi]`` and any wind signal, written into ``lo`` and ``hi``; ``params`` is ``(speed,
    wind_max)``. The heading is exact, ``theta(s) = theta_0 + u s``. The position moves by
    ``int_0^s v (cos, sin)(theta)``, which lies in ``s v`` times the range of ``(cos, sin)`` over every heading of
    ``[0, s1]`` (:func:`~softreach.reach.proof.intervals.cos_range`), plus the wind's ``[-w s, w s]``; every end
    rounded outwards. At one instant (``s0 = s1 = s``, an end box) the turn's part is exact instead:
    ``int_0^s (cos, sin)(theta_0 + u r) dr = s sinc(u s / 2) (cos, sin)(theta_0 + u s / 2)``."""
    speed, wind, u = params[0], params[1], a[0]
    h_lo = down(x_lo[2] + min(0.0, u * s1))
    h_hi = up(x_hi[2] + max(0.0, u * s1))
    half = 0.5 * u * s1
    k = speed * s1 * (math.sin(half) / half if half != 0.0 else 1.0)
    # sinc's rounding is below 1e-15 absolute (below 1 relative near its zeros), the products' within down and up
    k_lo, k_hi = down(k) - 1e-15 * speed * s1, up(k) + 1e-15 * speed * s1
    if s0 == s1:
        h_lo, h_hi = down(x_lo[2] + half) - 1e-15, up(x_hi[2] + half) + 1e-15
    for axis in range(2):
        r_lo, r_hi = cos_range(h_lo, h_hi) if axis == 0 else sin_range(h_lo, h_hi)
        # s * [r_lo, r_hi] over s in [s0, s1]: the extremes are at the interval's ends; at s0 = s1, [k] * [r_lo, r_hi]
        p1, p2, p3, p4 = k_lo * r_lo, k_lo * r_hi, k_hi * r_lo, k_hi * r_hi
        move_lo = down(min(min(p1, p2), min(p3, p4))) if s0 == s1 else speed * min(s0 * r_lo, s1 * r_lo)
        move_hi = up(max(max(p1, p2), max(p3, p4))) if s0 == s1 else speed * max(s0 * r_hi, s1 * r_hi)
        lo[axis] = down(x_lo[axis] + down(move_lo - wind * s1))
        hi[axis] = up(x_hi[axis] + up(move_hi + wind * s1))
    lo[2] = down(x_lo[2] + min(u * s0, u * s1))
    hi[2] = up(x_hi[2] + max(u * s0, u * s1))


@njit(inline="always")
def _disc_max(cx, cy, radius, lo, hi):
    """The largest value of ``radius - |p - c|`` over the box: at the nearest point of the box, the centre clipped
    to it; the distance rounded down."""
    nx, ny = min(max(cx, lo[0]), hi[0]), min(max(cy, lo[1]), hi[1])
    return radius - down(math.sqrt((nx - cx) ** 2 + (ny - cy) ** 2))


@njit
def set_max_kernel(params, which, lo, hi):
    """The largest value of set ``which`` (:data:`~softreach.reach.proof.model_kernels.SET_INDEX`) over the box
    ``[lo, hi]``; ``params``: goal, obstacle and zone as ``(x, y, radius)`` each, then the arena's half-width. The
    target's distance is convex: largest at a corner. ``c1`` and ``c2`` are not (the complement of a disc): the
    disc term at the box's nearest point to its centre (:func:`_disc_max`), the arena term, a box distance, at the
    box's far ends. NaN where the box is (a failed enclosure). No set depends on the heading, so a box's heading
    may lie anywhere, across the seam ``+-pi`` too."""
    for i in range(2):
        if math.isnan(lo[i]) or math.isnan(hi[i]):
            return np.nan
    if which == 0:
        out = -np.inf
        for px in (lo[0], hi[0]):
            for py in (lo[1], hi[1]):
                out = max(out, math.sqrt((px - params[0]) ** 2 + (py - params[1]) ** 2) - params[2])
        return out
    if which == 2:
        return _disc_max(params[6], params[7], params[8], lo, hi)
    arena = params[9]
    edge = max(max(-arena - lo[0], hi[0] - arena), max(-arena - lo[1], hi[1] - arena))
    return max(_disc_max(params[3], params[4], params[5], lo, hi), edge)


@dataclass(frozen=True)
class DubinsParams:
    """Parameters of the Dubins vehicle.

    :param speed: forward speed ``v`` [m/s]
    :param turn_max: turn-rate bound, ``u in [-turn_max, turn_max]`` [rad/s]
    :param wind_max: wind bound per axis, ``w_x, w_y in [-wind_max, wind_max]`` [m/s]
    :param goal: goal centre ``(x, y)`` [m]
    :param goal_radius: goal radius [m]
    :param obstacle: obstacle centre [m]
    :param obstacle_radius: obstacle radius [m]
    :param zone: soft-zone centre [m]
    :param zone_radius: soft-zone radius [m]
    :param arena: half-width of the square arena ``|x|, |y| <= arena`` [m] (part of ``C1``)
    :param horizon: ``T`` [s]
    """

    speed: float = 1.0
    turn_max: float = 1.0
    wind_max: float = 0.1
    goal: tuple[float, float] = (3.0, 0.0)
    goal_radius: float = 0.6
    obstacle: tuple[float, float] = (0.0, -0.6)
    obstacle_radius: float = 1.0
    zone: tuple[float, float] = (0.0, 1.2)
    zone_radius: float = 0.8
    arena: float = 4.0
    horizon: float = 7.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            values = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
                raise ValueError(f"DubinsParams.{name} must be finite, got {value!r}")
        for name in ("speed", "turn_max", "goal_radius", "obstacle_radius", "zone_radius", "arena", "horizon"):
            if getattr(self, name) <= 0:
                raise ValueError(f"DubinsParams.{name} must be positive, got {getattr(self, name)!r}")
        if self.wind_max < 0:
            raise ValueError(f"DubinsParams.wind_max must be >= 0, got {self.wind_max!r}")
        for name in ("goal", "obstacle", "zone"):
            if len(getattr(self, name)) != 2:
                raise ValueError(f"DubinsParams.{name} must be a point (x, y), got {getattr(self, name)!r}")


class Dubins(Model, ControlAndDisturbanceAffine):
    """The Dubins vehicle of this module's docstring; state ``(x, y, theta)`` in (m, m, rad), heading periodic.

    Control- and disturbance-affine (``G = e_theta``, ``E = [e_x, e_y]``), so the Hamiltonian, the bang-bang
    optimal turn ``u* = -turn_max sign(p_theta)``, the worst wind ``w* = wind_max sign(p_x, p_y)`` and the
    Lax-Friedrichs bounds ``|v cos(theta)| + wind_max``, ``|v sin(theta)| + wind_max``, ``turn_max`` are closed
    forms of :class:`~softreach.reach.dynamics.ControlAndDisturbanceAffine`.

    Default grid: ``x, y in [-4.5, 4.5]`` m (the arena and half a metre beyond), ``theta in [-pi, pi)``,
    41 x 41 x 32 nodes and 17 budget nodes (docs/models.md times ``softreach solve dubins`` on this grid).
    Horizon 7 s, speed 1 m/s, turn rate up to 1 rad/s, wind up to 0.1 m/s per axis; the environment steps
    0.1 s periods and starts west of the obstacle, heading roughly east (:attr:`start_box`).
    """

    name = "dubins"
    state_names = ("x", "y", "theta")
    state_units = ("m", "m", "rad")
    control_units = ("rad/s",)
    disturbance_units = ("m/s", "m/s")
    periodic = (False, False, True)
    plot_axes = (0, 1)  # x across, y up

    def __init__(self, params: DubinsParams | None = None, **overrides: Any):
        """:param params: a full parameter set; or pass :class:`DubinsParams` fields as keyword overrides"""
        if params is None:
            params = DubinsParams(**overrides)
        elif overrides:
            raise TypeError("pass either params or keyword overrides, not both")
        self.params = p = params
        self.control_bounds = ((-p.turn_max,), (p.turn_max,))
        self.disturbance_bounds = ((-p.wind_max, -p.wind_max), (p.wind_max, p.wind_max))
        self.horizon = p.horizon
        edge = p.arena + 0.5
        self.domain = ((-edge, -edge, -math.pi), (edge, edge, math.pi))
        self.hard_box = ((-p.arena, -p.arena, -math.pi), (p.arena, p.arena, math.pi))
        self.default_shape = (41, 41, 32)
        self.default_budget_points = 17
        self.default_snapshots = 21
        self.default_budgets = (0.0, 0.5, 1.0, 2.0)
        self.paper_budgets = (0.0, 1.0, 2.0)
        # c2 is a distance [m]; the vehicle leaves the zone at up to its speed
        self.budget_scale = p.speed
        self.control_period = 0.1
        self.substeps = 2  # RK4 error on a 0.05 s sub-step of this smooth motion is far below a millimetre
        # west of the obstacle, roughly facing the goal
        self.start_box = ((-2.5, -1.0, -0.5), (-1.5, 1.0, 0.5))
        self.start_budget = (0.0, 2.0)
        # the cell certificates (8 m / 60 = 0.133 m x 0.133 m x 5 deg) and plans of every length up to 8 periods: the
        # heading's resolution certifies more than the position's, longer plans nothing more (the shapes measured
        # against each other: docs/filters.md, "Dubins on cells"). The heading's cells tile its period once, and a box
        # across the seam touches those at both of its ends (docs/filters.md, "The heading's seam")
        self.cell_shape = (60, 60, 72)
        self.cell_holds = (1, 2, 3, 4, 5, 6, 7, 8)
        (gx, gy), r = p.goal, p.goal_radius
        self.target_box = ((gx - r, gy - r, -math.inf), (gx + r, gy + r, math.inf))

    def parameters(self) -> dict[str, Any]:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self.params).items()}

    # ------------------------------------------------------------------------------------------ dynamics
    def drift(self, t: float, x: Components) -> list[Array | float]:
        v = self.params.speed
        return [v * _cos(x[2]), v * _sin(x[2]), 0]

    def control_matrix(self, t: float, x: Components) -> list[list[Array | float]]:
        return [[0], [0], [1.0]]

    def disturbance_matrix(self, t: float, x: Components) -> list[list[Array | float]]:
        return [[1.0, 0], [0, 1.0], [0, 0]]

    # ------------------------------------------------------------------------------------------ sets
    def _distance(self, x: Components, centre: tuple[float, float]) -> Array:
        return _sqrt((x[0] - centre[0]) ** 2 + (x[1] - centre[1]) ** 2)

    def target(self, t: float, x: Components) -> Array:
        """``g = |p - goal| - goal_radius`` [m]."""
        return self._distance(x, self.params.goal) - self.params.goal_radius

    def hard_constraint(self, t: float, x: Components) -> Array:
        """``c1 = max(obstacle_radius - |p - obstacle|, box distance to the arena)`` [m]."""
        p = self.params
        obstacle = p.obstacle_radius - self._distance(x, p.obstacle)
        arena = sets.box([x[0], x[1]], (-p.arena, -p.arena), (p.arena, p.arena))
        return B.maximum(obstacle, arena) if hasattr(obstacle, "shape") else B.maximum(arena, obstacle)

    def soft_constraint(self, t: float, x: Components) -> Array:
        """``c2 = zone_radius - |p - zone|`` [m]: positive inside the soft zone."""
        return self.params.zone_radius - self._distance(x, self.params.zone)

    #: the held period's boxes and the sets' maxima over boxes, compiled (:attr:`~softreach.reach.dynamics.Dynamics.
    #: held_box_kernel`, from which the base class derives every enclosure the filter reads, and
    #: :attr:`~softreach.reach.problem.Model.set_max_kernel`, which :meth:`set_box_max` runs)
    held_box_kernel = staticmethod(held_box_kernel)
    set_max_kernel = staticmethod(set_max_kernel)

    def rk4_error(self, h: float) -> np.ndarray:
        """RK4 on this motion is Simpson's rule plus an admissible wind: the heading's rate is the held turn rate, so
        the stage headings lie on the exact heading line and the position's rate ``v (cos, sin)(theta)`` is a function
        of time alone, which RK4 weighs ``1/6, 4/6, 1/6`` at the sub-step's start, middle and end; the wind's stage
        values, weighed ``1/6, 2/6, 2/6, 1/6``, make a constant wind in the box. Simpson's rule over ``h`` errs by at
        most ``h^5 / 2880`` times the largest fourth derivative, ``v turn_max^4``; the heading by nothing."""
        p = self.params
        error = h ** 5 * p.speed * p.turn_max ** 4 / 2880.0
        return np.array([error, error, 0.0])

    def rk4_stage_error(self, h: float) -> np.ndarray:
        """Zero: a stage state is the start plus its elapsed time ``s`` times a weighted mean of rates along the
        heading line, which :func:`held_box_kernel`'s box over an interval holding ``s`` holds (``s v`` times the
        range of the rate over the headings, plus the wind's)."""
        return np.zeros(3)

    @property
    def held_box_params(self) -> np.ndarray:
        """:func:`held_box_kernel`'s numbers: the speed and the wind bound."""
        return np.array([self.params.speed, self.params.wind_max], dtype=np.float64)

    @property
    def set_max_params(self) -> np.ndarray:
        """:func:`set_max_kernel`'s numbers: goal, obstacle and zone ``(x, y, radius)``, the arena's half-width."""
        p = self.params
        return np.array([*p.goal, p.goal_radius, *p.obstacle, p.obstacle_radius, *p.zone, p.zone_radius, p.arena],
                        dtype=np.float64)

    def set_box_max(self, which: str, t: Any, lo: Any, hi: Any) -> Any:
        """The exact maximum of ``c1`` or ``c2`` over boxes (:func:`set_max_kernel`); ``None`` for the target
        (convex: its corners suffice)."""
        if which not in ("hard_constraint", "soft_constraint"):
            return None
        lo, hi = (np.ascontiguousarray(v, dtype=np.float64) for v in (lo, hi))
        out = np.empty(len(lo))
        set_max_rows(set_max_address(self), self.set_max_params, SET_INDEX[which], lo, hi, out)
        return out

    # ------------------------------------------------------------------------------------------ model metadata
    def start_difficulty(self, x: Components) -> Array:
        """The distance to the goal: the representative starts are the farthest of each set."""
        return self._distance(x, self.params.goal)


def _register() -> None:
    from ..registry import register_model

    register_model("dubins", Dubins)


_register()

__all__ = ["Dubins", "DubinsParams"]
