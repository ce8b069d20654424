"""An adaptive cruise control written on the public model API (``docs/models.md``): the 2-D model of issue 37's
time-to-filter goal (``109 x 145`` states, 45 budget nodes, a 0.1 s control period).

The ego car follows a lead car. State ``(w, h)``: the relative speed ``w = v_lead - v_ego`` [m/s] and the gap [m].
The ego's deceleration ``u`` (braking positive) is the control, the lead's acceleration ``d`` the disturbance::

    w' = u + d,    h' = w

Sets (box distances in m/s and m): target, a following gap of 20-30 m at matched speed (``|w| <= 0.5``); hard
``C1``, ``|w| <= 10`` and a gap of 5-80 m; soft ``C2``, a gap of at least 15 m (closer is allowed for the budget).

This is the point mass's motion without gravity (``v' = u - g + d``, ``y' = v``), so its motion bound is the point
mass's kernel with ``g = 0``.

    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --model benchmarks.acc_model:CruiseControl \\
        --table-kind continuous
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from softreach.reach import Model, sets
from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.models.pointmass import held_box_kernel


@dataclass(frozen=True)
class CruiseParams:
    """:param u_max: the ego's deceleration bound [m/s^2]; :param d_max: the lead's acceleration bound [m/s^2]."""

    u_max: float = 3.0
    d_max: float = 1.0


TARGET = ((-0.5, 20.0), (0.5, 30.0))
HARD = ((-10.0, 5.0), (10.0, 80.0))
SOFT = ((-np.inf, 15.0), (np.inf, np.inf))


class CruiseControl(Model, ControlAndDisturbanceAffine):
    """``w' = u + d``, ``h' = w``; state ``(w, h)`` in (m/s, m)."""

    name = "cruise"
    state_names = ("w", "h")
    state_units = ("m/s", "m")
    control_units = ("m/s^2",)
    disturbance_units = ("m/s^2",)
    horizon = 8.0
    domain = ((-12.0, 0.0), (12.0, 90.0))
    hard_box = HARD
    default_shape = (109, 145)
    default_budget_points = 45
    default_budgets = (0.0, 1.0, 2.0)
    budget_scale = 2.0  # m/s of gap closing the control can undo per second
    control_period = 0.1
    substeps = 2
    start_box = ((-4.0, 10.0), (4.0, 70.0))
    start_budget = (0.0, 2.0)
    set_boxes = {"target": TARGET, "hard_constraint": HARD, "soft_constraint": SOFT}
    cell_shape = (400, 300)
    cell_holds = (1, 2, 4)
    held_box_kernel = staticmethod(held_box_kernel)

    def __init__(self, u_max: float = 3.0, d_max: float = 1.0):
        self.params = CruiseParams(u_max, d_max)
        self.control_bounds = ((-u_max,), (u_max,))
        self.disturbance_bounds = ((-d_max,), (d_max,))
        self.held_box_params = np.array([0.0, d_max])  # the point mass kernel's (gravity, d_max)

    def parameters(self):
        return asdict(self.params)

    def drift(self, t, x):
        return [0, x[0]]

    def control_matrix(self, t, x):
        return [[1.0], [0]]

    def disturbance_matrix(self, t, x):
        return [[1.0], [0]]

    def target(self, t, x):
        return sets.box(x, *TARGET)

    def hard_constraint(self, t, x):
        return sets.box(x, *HARD)

    def soft_constraint(self, t, x):
        return sets.box(x, *SOFT)
