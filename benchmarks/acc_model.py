"""An adaptive cruise control written on the public model API (``docs/models.md``): the 2-D model of issue 37's
time-to-filter goal (``145 x 109`` states, 45 budget nodes, a 0.1 s control period).

The ego car follows a lead car. State ``(h, w)``: the gap [m] and the relative speed ``w = v_lead - v_ego``
[m/s]. The ego's acceleration ``u`` is the control, the lead's ``d`` the disturbance::

    h' = w,    w' = d - u

Sets (box distances in m and m/s): target, a following gap of 20-30 m at matched speed (``|w| <= 0.5``); hard
``C1``, a gap of 5-80 m and ``|w| <= 10``; soft ``C2``, a gap of at least 15 m (closer is allowed for the budget).

    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --model benchmarks.acc_model:CruiseControl \\
        --table-kind continuous
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from softreach.reach import Model, sets
from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.jit import njit


@dataclass(frozen=True)
class CruiseParams:
    """:param u_max: the ego's acceleration bound [m/s^2]; :param d_max: the lead's [m/s^2]."""

    u_max: float = 3.0
    d_max: float = 1.0


@njit
def held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi):
    """Every state at some time in ``[s0, s1]`` of a period with ``u = a[0]`` held, from every start in the box and
    any lead acceleration: ``w`` between two lines (extreme at the interval's ends), ``h`` between two parabolas
    (extreme at an end or where ``w`` vanishes); ``params`` is ``(d_max,)``."""
    acc_lo, acc_hi = -params[0] - a[0], params[0] - a[0]
    lo[1] = min(x_lo[1] + acc_lo * s0, x_lo[1] + acc_lo * s1)
    hi[1] = max(x_hi[1] + acc_hi * s0, x_hi[1] + acc_hi * s1)
    lo[0] = _parabola(x_lo[0], x_lo[1], acc_lo, s0, s1, False)
    hi[0] = _parabola(x_hi[0], x_hi[1], acc_hi, s0, s1, True)


@njit
def _parabola(y, v, acc, s0, s1, largest):
    """The smallest (or ``largest``) value of ``y + v s + acc s^2 / 2`` over ``s`` in ``[s0, s1]``."""
    q0 = y + v * s0 + 0.5 * acc * s0 * s0
    q1 = y + v * s1 + 0.5 * acc * s1 * s1
    out = max(q0, q1) if largest else min(q0, q1)
    s = -v / acc if acc != 0 else -1.0
    if s0 < s < s1:
        q = y + v * s + 0.5 * acc * s * s
        out = max(out, q) if largest else min(out, q)
    return out


TARGET = ((20.0, -0.5), (30.0, 0.5))
HARD = ((5.0, -10.0), (80.0, 10.0))
SOFT = ((15.0, -np.inf), (np.inf, np.inf))


class CruiseControl(Model, ControlAndDisturbanceAffine):
    """``h' = w``, ``w' = d - u``; state ``(h, w)`` in (m, m/s)."""

    name = "cruise"
    state_names = ("h", "w")
    state_units = ("m", "m/s")
    control_units = ("m/s^2",)
    disturbance_units = ("m/s^2",)
    horizon = 8.0
    domain = ((0.0, -12.0), (90.0, 12.0))
    hard_box = HARD
    default_shape = (145, 109)
    default_budget_points = 45
    default_budgets = (0.0, 1.0, 2.0)
    budget_scale = 2.0  # m/s of gap closing the control can undo per second
    control_period = 0.1
    substeps = 2
    start_box = ((10.0, -4.0), (70.0, 4.0))
    start_budget = (0.0, 2.0)
    set_boxes = {"target": TARGET, "hard_constraint": HARD, "soft_constraint": SOFT}
    cell_shape = (300, 400)
    cell_holds = (1, 2, 4)

    def __init__(self, u_max: float = 3.0, d_max: float = 1.0):
        self.params = CruiseParams(u_max, d_max)
        self.control_bounds = ((-u_max,), (u_max,))
        self.disturbance_bounds = ((-d_max,), (d_max,))
        self.held_box_kernel, self.held_box_params = held_box_kernel, np.array([d_max])

    def parameters(self):
        return asdict(self.params)

    def drift(self, t, x):
        return [x[1], 0]

    def control_matrix(self, t, x):
        return [[0], [-1.0]]

    def disturbance_matrix(self, t, x):
        return [[0], [1.0]]

    def target(self, t, x):
        return sets.box(x, *TARGET)

    def hard_constraint(self, t, x):
        return sets.box(x, *HARD)

    def soft_constraint(self, t, x):
        return sets.box(x, *SOFT)
