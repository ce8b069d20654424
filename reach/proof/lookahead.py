"""The one-period look-ahead: does holding an action for one control period provably keep the state certified?

This module holds the test's parameters (:class:`Lookahead`: the candidates, the allowances, the table's fields as
the compiled code reads them); the period's bounds run compiled (:mod:`softreach.reach.proof.period`, which the
filter's decision, :mod:`softreach.filters.judge`, and the cells' builder share).

For a held action ``a`` and *every* disturbance signal in its box (switching at any instant, also in answer to ``a``),
the model's :meth:`~softreach.reach.model_filter.FilterPart.held_enclosure` gives a box ``T`` holding the whole
motion of the period and a box ``E`` holding its end point. The action is **admissible** when

1. ``max_T c1 <= 0``: the motion stays in ``C1`` for the whole period. ``c1`` is convex (a box distance), so its
   maximum over ``T`` is at a corner of ``T`` (a model with other sets bounds them itself,
   :meth:`~softreach.reach.problem.Model.set_box_max`);
2. ``z' = z - sum_j (dt / P) max_{T_j} h_eps >= 0``, ``T_j`` a box holding the motion over the ``j``-th of ``P``
   equal pieces of the period (:meth:`~softreach.reach.model_filter.FilterPart.held_tube_pieces`): the budget
   spent in the period, crossings of ``C2`` included, is at most that (``h_eps`` grows with ``c2``, also convex,
   so each maximum is at a corner), and the budget never goes negative, with no allowance of a period;
3. ``E x [z', z]`` lies in the landing cells at the next sample time
   (:mod:`softreach.reach.proof.cell_certificate`), which prove landing by ``T`` from every state in them.

The table only ranks: its interpolant ``D(t, x, z) = min(V~(t, x), W~(t, x, z))`` (``V~`` only with ``z >= 0``;
``V <= 0`` lands without spending budget, ``W_eps <= 0`` spending at most ``z``), maximised exactly over the end
box (:func:`softreach.reach.proof.box_max.box_max`), is an admissible action's worst next value, lower first.

The episode also ends when the target is reached *inside* a period, so an action also passes when every run
surely lands at one of the environment's check instants (:func:`softreach.reach.proof.period.lands`).

Each box compared with a set or a cell holds the environment's own numbers, rounding included: it is widened by
:func:`state_allowance` (``C1`` is asked of the exact tube and of the widened box from the environment's first
check instant on, :func:`~softreach.reach.proof.period.checked_c1`), and a period that may spend is charged
:func:`budget_allowance` more. The candidates are actions an environment applies exactly (:func:`representable`).

A budget-surface table (``softreach solve MODEL --budget-surface``) ranks with ``W~(t, x, z)`` replaced by
``Q~_min(t, x) - min(z, T - t)``: its maximum over ``E x [z', z]`` is ``max_E Q~_min - min(z', T - t)``, and
``+inf`` on every cell with a node where no budget suffices (there ``Q_min`` is infinite, stored at a cap).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .box_max import kernel_field
from ..numerics.grid import Grid
from ..boxes import check_action_box
from .kernels import certificate_rows


#: the fields that say how much budget suffices, in the order a table's is picked
BUDGET_FIELDS = ("W_eps", "Q_min")

#: the unit roundoff of binary64, in which the environments integrate and the filter bounds
UNIT_ROUNDOFF = 2.0 ** -53


def action_map(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """The centre and half-width of the model's control box: the environments apply the normalised action ``q``
    as ``mid + half * q`` (binary64), :mod:`softreach.envs.actions`."""
    check_action_box(model)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.control_bounds)
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def exact_normalized(u: np.ndarray, mid: np.ndarray, half: np.ndarray, ulps: int = 4) -> np.ndarray:
    """Normalised actions ``q`` in ``[-1, 1]`` (binary64) that the environments map back to exactly ``u``
    (``mid + half * q == u``), where one lies within ``ulps`` units in the last place of ``(u - mid) / half``;
    elsewhere that quotient (clipped). The filter judges physical actions; what it hands an environment must be
    what it judged, not a neighbour one rounding away."""
    u = np.asarray(u, dtype=np.float64)
    q = np.minimum(np.maximum((u - mid) / half, -1.0), 1.0)
    miss = mid + half * q != u
    if not miss.any():
        return q
    out = q.copy()
    for sign in (np.inf, -np.inf):
        step = q.copy()
        for _ in range(ulps):
            step = np.nextafter(step, sign)
            hit = miss & (np.abs(step) <= 1.0) & (mid + half * step == u)
            out = np.where(hit, step, out)
            miss &= ~hit
    return out


def representable(u: np.ndarray, mid: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The physical actions an environment can apply exactly nearest ``u``: ``u`` itself where a normalised action
    maps to it (:func:`exact_normalized`), else the image of the nearest normalised one. The filter's candidates
    are these, so that the action it proves is the one the environment applies, bit for bit."""
    return mid + half * exact_normalized(u, mid, half)


def rk4_exact(model: Any, h: float, samples: int = 64) -> bool:
    """Whether the environments' RK4 sub-step of ``h`` seconds is exact for the model's held motion, as step
    doubling shows: from ``samples`` states across ``C1`` (the domain where the model has no hard box), with the
    control and the disturbance at the corners and centres of their boxes, one sub-step and two of half its length
    agree to within rounding (``64 u M``, :func:`state_allowance`'s magnitudes). They do for the point mass (its
    motion under held inputs is quadratic in time); RK4's truncation error on a nonlinear model (the glider, Dubins)
    is many orders above that."""
    box = model.hard_box if model.hard_box is not None else model.domain
    lo, hi = (np.asarray(b, dtype=np.float64) for b in box)
    x = np.random.default_rng(0).uniform(lo, hi, (samples, len(lo)))
    M = 2.0 * np.maximum(*(np.abs(np.asarray(b, dtype=np.float64)) for b in model.domain))

    def step(x0: np.ndarray, a: np.ndarray, b: np.ndarray, dt: float) -> np.ndarray:
        def f(y: np.ndarray) -> np.ndarray:
            out = model.f(0.0, list(y.T), list(a.T), list(b.T))
            return np.stack([np.broadcast_to(np.asarray(c, dtype=np.float64), (len(y),)) for c in out], axis=1)
        k1 = f(x0)
        k2 = f(x0 + 0.5 * dt * k1)
        k3 = f(x0 + 0.5 * dt * k2)
        k4 = f(x0 + dt * k3)
        return x0 + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def levels(bounds: Any) -> list[np.ndarray]:
        b_lo, b_hi = (np.asarray(v, dtype=np.float64) for v in bounds)
        return [b_lo, b_hi, 0.5 * (b_lo + b_hi)]

    for a in levels(model.control_bounds):
        for b in levels(model.disturbance_bounds):
            A, B = np.tile(a, (samples, 1)), np.tile(b, (samples, 1))
            one = step(x, A, B, h)
            two = step(step(x, A, B, 0.5 * h), A, B, 0.5 * h)
            if not (np.abs(one - two) <= 64 * UNIT_ROUNDOFF * M).all():
                return False
    return True


def state_allowance(model: Any, checks: int) -> np.ndarray:
    """How far, per state axis, the environment's state after a period may lie from the exact motion that the
    model's enclosure bounds, by rounding alone: every box the filter compares with ``C1``, ``C2``, the target or
    a cell edge is widened by it (the start of a period is the environment's own number, so it is exact).

    Derivation. The environment advances a period by ``checks`` classical RK4 sub-steps in binary64 (unit roundoff
    ``u``). Along axis ``i``, a sub-step forms three stage states ``x + c h k`` (2 roundings each), the weighted sum
    ``k1 + 2 k2 + 2 k3 + k4`` (5), its product with ``h / 6`` (2) and the new state (1): at most 16 roundings,
    each of a number at most ``M_i``, twice the largest ``|x_i|`` of the model's domain (a state the episode goes
    on from lies in ``C1``, inside the domain; a stage state or a sub-step's increment lies within the domain's
    extent of it). The stage states' errors (``2 u M_i`` each) reach the increment through ``f`` times ``h``, with
    ``h L <= 1``: at most ``8 u M_i`` more. So ``24 u M_i`` a sub-step, ``24 checks u M_i`` a period; the
    enclosures' own arithmetic (a few operations on such numbers) adds ``8 u M_i``. The allowance is
    ``(24 checks + 8) u M_i``. It covers rounding only: where the environment's integrator is exact in real
    arithmetic (the point mass's RK4, for its piecewise quadratic motion) it covers the whole difference; the
    truncation error of RK4 on a nonlinear model (the glider) is not covered (``docs/filters.md``).
    """
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.domain)
    M = 2.0 * np.maximum(np.abs(lo), np.abs(hi))
    return (24 * int(checks) + 8) * UNIT_ROUNDOFF * M


def budget_allowance(dt: float, horizon: float, pieces: int, samples: int = 128) -> float:
    """What every budget charge of a period adds for rounding [s], so that the filter's end budget is never above
    the environment's (``z - cost`` in binary64, :mod:`softreach.reach.sim.integrator`).

    Derivation (``u`` the unit roundoff; every rate ``h_eps`` lies in ``[0, 1]``, so every partial sum of a
    period's cost is at most ``dt``, and every budget at most the horizon ``T``): the environment's cost of a
    sub-step is Simpson's sum (8 roundings) or, at a kink, trapezoid sums over ``samples`` cells a level (at most
    ``2 samples + 8`` roundings of numbers at most the sub-step), summed correctly rounded: at most
    ``(2 samples + 8) u dt`` a period. The filter's charge, ``pieces`` products and sums: ``2 pieces u dt``. The
    environment's subtraction ``z - cost``: ``u T``; the filter's own (or the cells' sum of a plan's charges and
    the comparison with a budget cell's edge): ``3 u T``. So ``u ((2 samples + 8 + 2 pieces) dt + 4 T)``: a period
    that may leave ``C2`` is charged that much more. A period whose widened box lies in ``C2`` costs exactly 0 in
    the environment (every rate it reads is 0), and is charged nothing.
    """
    return UNIT_ROUNDOFF * ((2 * samples + 8 + 2 * int(pieces)) * float(dt) + 4.0 * float(horizon))


def surface_fields(values: Any, times: Any, grid: Grid, horizon: float) -> tuple[tuple, tuple]:
    """A budget surface ``Q_min`` as the compiled code reads ``W_eps`` (:func:`~softreach.reach.proof.box_max.
    kernel_field`): over the state and a budget axis with two nodes, ``z = 0`` holding ``Q_min`` and ``z = T`` holding
    ``Q_min - T`` (rounded up to the table's float32). The certificate ``Q~_min(t, x) - min(z, T - t)`` is linear in
    the budget read, so the multilinear interpolant at the budget ``min(z, T - t)`` (:func:`~softreach.reach.proof.
    kernels.usable_budget`) is that certificate, and its maximum over a box of states and budgets is the
    certificate's; the rounding up keeps it at or above ``Q~_min - z``.

    Where no budget suffices (``Q_min`` above the time left, stored at a cap) both nodes hold ``+inf``: no
    interpolant between such a node and a feasible one says where feasibility ends, so every cell with such a
    corner reads ``+inf`` (or NaN, read as ``+inf``, where that corner's weight is 0).

    :return: ``(W, inside)``: the field above, and the same without the infinite nodes, whose finite values say
        where a state lies on the table (:meth:`~softreach.reach.Table.inside`)
    """
    Q = np.asarray(values, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)
    none = Q > (horizon - t).reshape((-1,) + (1,) * grid.ndim) + 1e-9
    top = Q - horizon
    top32 = top.astype(np.float32)
    low = top32.astype(np.float64) < top
    top32[low] = np.nextafter(top32[low], np.float32(np.inf))
    inside = np.stack([Q.astype(np.float32), top32], axis=-1)
    W = np.where(none[..., None], np.float32(np.inf), inside)
    zgrid = Grid(tuple(grid.lo) + (0.0,), tuple(grid.hi) + (float(horizon),), tuple(grid.shape) + (2,),
                 periodic=tuple(grid.periodic) + (False,), names=tuple(grid.names) + ("z",))
    return kernel_field(W, t, zgrid), kernel_field(inside, t, zgrid)


class Lookahead:
    """The one-period test's parameters against a table's certificate (see the module docstring), and the
    certificate at a state (:meth:`certificate`).

    :param fields: ``{"V": (values, times, grid), "W_eps": (...)}`` (``V`` optional; ``Q_min`` for ``W_eps`` on a
        budget surface), values ``(n_t, *grid)``
    :param model: the model the table was solved for
    :param dt: the control period [s]
    :param eps: the ``h_eps`` width with which the environment drains the budget
    :param candidates: ``(J, m)`` physical held actions the filter may fall back on
    :param pieces: sub-intervals of the period for the budget bound (item 2)
    :param target_checks: the instants per period at which the environment checks for landing (its sub-steps);
        it must check at least there (the point-mass env has 10 sub-steps, the glider's 2)
    """

    def __init__(self, fields: dict[str, tuple[Any, np.ndarray, Any]], model: Any, dt: float, eps: float,
                 candidates: Any, pieces: int = 4, target_checks: int = 1):
        self.model, self.dt, self.eps = model, float(dt), float(eps)
        self.pieces = int(pieces)
        if not (isinstance(target_checks, (int, np.integer)) and target_checks >= 1):
            raise ValueError(f"target_checks must be a positive integer, got {target_checks!r}")
        self.target_checks = int(target_checks)
        self.n = model.state_dim
        #: the environment's sub-steps a period: it checks ``C1`` and landing at their ends, the first
        #: :attr:`first_check` after the period's start (:class:`SafetyFilter` passes the environment's count as
        #: ``target_checks``; a bare filter assumes the model's own ``substeps``)
        self.checks = max(self.target_checks, int(getattr(model, "substeps", 1) or 1))
        self.first_check = self.dt / self.checks
        #: the environment's RK4 is exact for the model's motion (:func:`rk4_exact`): then the proof holds for the
        #: environment's own numbers, with the allowances below and candidates it applies exactly. Elsewhere RK4's
        #: truncation error, which no rounding allowance covers, is not covered, the proof is one about the exact
        #: motion, and no allowance is applied (``docs/filters.md``, "Sound to the last bit")
        self.exact_env = rk4_exact(model, self.first_check)
        #: the outward allowances for the environment's rounding (:func:`state_allowance`, per state axis, and
        #: :func:`budget_allowance`, a period's charge); zero where :attr:`exact_env` is not
        self.slack = state_allowance(model, self.checks) if self.exact_env else np.zeros(model.state_dim)
        self.fields = dict(fields)
        #: the field that says how much budget suffices: ``W_eps`` on ``(x, z)``, or the budget surface ``Q_min``
        self.budget_field = next((f for f in BUDGET_FIELDS if f in self.fields), None)
        if self.budget_field is None:
            raise ValueError("the one-period test needs W_eps or Q_min (the classical V alone does not say how much "
                             "budget)")
        b_values, b_times, b_grid = self.fields[self.budget_field]
        self.z_top = b_grid.hi[-1] if self.budget_field == "W_eps" else np.inf
        self.horizon = float(b_times[-1])
        self.budget_slack = budget_allowance(self.dt, self.horizon, self.pieces) if self.exact_env else 0.0
        V = kernel_field(*self.fields.get("V", self.fields[self.budget_field]))
        if self.budget_field == "W_eps":
            W = kernel_field(*self.fields["W_eps"])
            W_read = (W, float(self.z_top), float(b_grid.lo[-1]), np.inf)
            inside = W
        else:
            W, inside = surface_fields(b_values, b_times, b_grid, self.horizon)
            W_read = (W, self.horizon, 0.0, self.horizon)
        #: the table's fields as the compiled certificate and decision read them (:func:`~softreach.reach.proof.
        #: kernels.certificate_row`, :class:`~softreach.filters.compiled_args.TableArgs`):
        #: ``(W, z_top, z_floor, z_left, V, has_V, inside)``
        self.table_args = W_read + (V, "V" in self.fields, inside)
        #: the control box's map (:func:`action_map`), and the candidates as an environment applies them: each
        #: one the image of a normalised action (:func:`representable`)
        self.a_mid, self.a_half = action_map(model)
        self.candidates = np.asarray(candidates, dtype=np.float64)
        if self.exact_env:
            self.candidates = representable(self.candidates, self.a_mid, self.a_half)

    @classmethod
    def from_table(cls, table: Any, model: Any, dt: float, eps: float, target_checks: int = 1) -> "Lookahead":
        """The test against a solved table's ``V`` and ``W_eps``, with the candidates it was solved with."""
        fields = {name: (table.values(name), table.times(name), table.grid(name))
                  for name in ("V", "W_eps", "Q_min", "V_safe") if name in table.header["fields"]}
        budget = next((f for f in BUDGET_FIELDS if f in fields), None)
        if budget is None:
            raise ValueError(f"table {table.path} holds only the classical V; the filter needs W_eps or Q_min")
        held = table.header["fields"][budget].get("held_controls")
        return cls(fields, model, dt, eps, held if held else model.held_candidates(), target_checks=target_checks)

    # ---------------------------------------------------------------- the certificate
    def certificate(self, t: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``D(t, x, z)``: ``+inf`` outside the table (unsafe), at a negative budget or after the horizon."""
        out = np.empty(len(x))
        t = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (len(x),)))
        certificate_rows(*self.table_args[:6], t, np.ascontiguousarray(x, dtype=np.float64),
                         np.ascontiguousarray(np.broadcast_to(np.asarray(z, dtype=np.float64), (len(x),))), out)
        return out
