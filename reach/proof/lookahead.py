"""The one-period look-ahead: does holding an action for one control period provably keep the state certified?

:class:`Lookahead` holds the test's parameters; the bounds run compiled (:mod:`softreach.reach.proof.period`). A held
action passes when every run surely lands inside the period (:func:`softreach.reach.proof.period.lands`), or when for
every disturbance signal in its box (``docs/filters.md``, "What the user runs, and what is guaranteed"):

1. ``max_T c1 <= 0`` over a box ``T`` holding the period's motion (``c1`` is convex: its maximum is at a corner);
2. ``z' = z - sum_j (dt / P) max_{T_j} h_eps >= 0``, ``T_j`` holding the ``j``-th of ``P`` pieces of the period
   (``h_eps`` grows with ``c2``, also convex: each maximum is at a corner);
3. ``E x [z', z]``, ``E`` the end box, lies in the landing cells at the next sample time
   (:mod:`softreach.reach.proof.cell_certificate`).

The table only ranks: ``D = min(V~, W~)`` at the end box's centre (``Q~_min - min(z, T - t)`` for ``W~`` on a budget
surface, :func:`surface_fields`). Boxes are widened by
:func:`state_allowance`, charges raised by :func:`budget_allowance`; candidates are :func:`representable`."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from ..boxes import check_action_box, model_label
from ..numerics.grid import Grid
from ..sim.budget_quadrature import KINK_SAMPLES
from ..tables.interpolation import geometry
from .kernels import certificate_rows, frozen

#: the fields that say how much budget suffices, in order of preference
BUDGET_FIELDS = ("W_eps", "Q_min")

#: the unit roundoff of binary64
UNIT_ROUNDOFF = 2.0 ** -53


def action_map(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """The centre and half-width of the control box: environments apply ``q`` as ``mid + half * q``
    (:mod:`softreach.envs.actions`)."""
    check_action_box(model)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.control_bounds)
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def exact_normalized(u: np.ndarray, mid: np.ndarray, half: np.ndarray, ulps: int = 4) -> np.ndarray:
    """Normalised actions ``q`` in ``[-1, 1]`` with ``mid + half * q == u`` exactly, where one lies within ``ulps``
    units in the last place of ``(u - mid) / half``, else that quotient clipped: the environment must apply the
    action that was judged, not a neighbour one rounding away."""
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
    """The physical actions nearest ``u`` that an environment applies exactly (:func:`exact_normalized`): the
    filter's candidates, so that the action it proves is the one applied, bit for bit."""
    return mid + half * exact_normalized(u, mid, half)


def _declared(model: Any, name: str, h: float) -> np.ndarray | None:
    """The model's bound ``name(h)`` per state axis (:class:`~softreach.reach.model_filter.FilterPart`), or ``None``.

    :raises ValueError: it is not one finite number >= 0 per axis
    """
    bound = getattr(model, name, None)
    error = None if bound is None else bound(h)
    if error is None:
        return None
    error = np.asarray(error, dtype=np.float64)
    if error.shape != (model.state_dim,) or not (np.isfinite(error) & (error >= 0)).all():
        raise ValueError(f"{model.name}.{name}({h!r}) must give {model.state_dim} finite numbers >= 0, got {error!r}")
    return error


def env_error(model: Any, h: float) -> np.ndarray | None:
    """How far, per state axis, one of the environments' RK4 sub-steps of ``h`` seconds may end from an exact motion,
    rounding aside: the model's own bound (:meth:`~softreach.reach.model_filter.FilterPart.rk4_error`, zero where
    RK4 is exact for its motion), ``None`` where it gives none. Never inferred from samples: a sampled agreement
    proves nothing about the states between the samples."""
    return _declared(model, "rk4_error", h)


def env_slack(model: Any, dt: float, checks: int) -> tuple[np.ndarray, np.ndarray] | None:
    """How far, per state axis, the environment's numbers over a period of ``dt`` seconds in ``checks`` RK4
    sub-steps may lie from an exact motion, ``(states, stages)``: its states, every sub-step's error
    (:func:`env_error`) and the rounding (:func:`state_allowance`); the stage states where it reads the budget's
    rate, that and the model's :meth:`~softreach.reach.model_filter.FilterPart.rk4_stage_error`. ``None`` where
    either error is not known; a warning names the missing one where the model states only the other."""
    error, stage = env_error(model, dt / checks), _declared(model, "rk4_stage_error", dt / checks)
    if error is None or stage is None:
        if (error is None) != (stage is None):
            given, missing = ("rk4_stage_error", "rk4_error") if error is None else ("rk4_error", "rk4_stage_error")
            warnings.warn(f"{model_label(model)} states {given} but not {missing}: the safety filter proves the "
                          f"exact motion only, not the environment's numbers. Add {missing}(h) (rk4_error: zero where "
                          f"RK4 is exact for the motion, as for a motion polynomial in time of degree at most 4; "
                          f"docs/models.md)", stacklevel=2)
        return None
    states = state_allowance(model, checks) + checks * error
    return states, states + stage


def state_allowance(model: Any, checks: int) -> np.ndarray:
    """How far, per state axis, the environment's state after a period may lie from the exact motion by rounding
    alone, ``(24 checks + 8) u M_i``, ``M_i`` twice the largest ``|x_i|`` of the domain, and ``4 u M_i`` more along a
    periodic axis: every box compared with ``C1``, ``C2``, the target or a cell edge is widened by it. An RK4 sub-step
    makes at most 16 roundings of numbers up to ``M_i`` along an axis, and its stage states' errors reach the update
    through ``h L <= 1``: ``24 u M_i`` a sub-step; the enclosure's arithmetic adds ``8 u M_i``. Along a periodic axis
    the environment wraps the state into its period once a period (:meth:`~softreach.reach.problem.Model.wrap_state`;
    the state moves less than a period in one): three roundings, and the float period's difference from the motion's,
    ``3.5 u M_i``, which a plan held over several periods meets between them (``docs/filters.md``, "Sound to the last
    bit")."""
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.domain)
    M = 2.0 * np.maximum(np.abs(lo), np.abs(hi))
    wrap = np.where(np.asarray(model.periodic_axes(), dtype=bool), 4, 0)
    return (24 * int(checks) + 8 + wrap) * UNIT_ROUNDOFF * M


def budget_allowance(dt: float, horizon: float, pieces: int, samples: int = KINK_SAMPLES) -> float:
    """What a period's positive budget charge adds for rounding [s], ``u ((2 samples + 8 + 2 pieces) dt + 4 T)``, so
    that the filter's end budget is never above the environment's (:mod:`softreach.reach.sim.integrator`). Every rate
    lies in ``[0, 1]``: the environment's cost rounds by at most ``(2 samples + 8) u dt`` a period, the filter's charge
    by ``2 pieces u dt``, ``z - cost`` by ``u T`` and the filter's or cells' sums and comparisons by ``3 u T``
    (``docs/filters.md``, "Sound to the last bit")."""
    return UNIT_ROUNDOFF * ((2 * samples + 8 + 2 * int(pieces)) * float(dt) + 4.0 * float(horizon))


def kernel_field(values: Any, times: Any, grid: Grid) -> tuple:
    """A field as the compiled loops read it: values ``(n_times, size)`` (a memory map stays mapped), times, grid."""
    g = geometry(grid)
    return (frozen(np.asarray(values).reshape(len(times), -1)), frozen(np.asarray(times, dtype=np.float64)), g.shape,
            g.lo, g.hi, g.h, g.inv_h, g.periodic)


def surface_fields(values: Any, times: Any, grid: Grid, horizon: float) -> tuple[tuple, tuple]:
    """A budget surface ``Q_min`` as the compiled code reads ``W_eps``: a budget axis with nodes ``z = 0``
    (``Q_min``) and ``z = T`` (``Q_min - T``, rounded up in float32, so at or above ``Q~_min - z``). Linear in the
    budget, so the interpolant at ``min(z, T - t)`` (:func:`~softreach.reach.proof.kernels.usable_budget`) is the
    certificate ``Q~_min - min(z, T - t)``. Where no budget suffices both nodes hold ``+inf``,
    so every cell with such a corner reads ``+inf`` (NaN read as ``+inf``): nothing says where feasibility ends.

    :return: ``(W, inside)``: the field, and without its infinite nodes (:meth:`~softreach.reach.Table.inside`)
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
    """The one-period test's parameters against a table's certificate, and the certificate at a state.

    :param fields: ``{"V": (values, times, grid), "W_eps": (...)}``, ``V`` optional, ``Q_min`` for a budget surface
    :param model: the model the table was solved for
    :param dt: the control period [s]
    :param eps: the ``h_eps`` width with which the environment drains the budget
    :param candidates: ``(J, m)`` physical held actions the filter may fall back on
    :param pieces: pieces of the period for the budget bound
    :param target_checks: the instants a period at which the environment checks for landing (its sub-steps)
    """

    def __init__(self, fields: dict[str, tuple[Any, np.ndarray, Any]], model: Any, dt: float, eps: float,
                 candidates: Any, pieces: int = 4, target_checks: int = 1):
        self.model, self.dt, self.eps, self.pieces = model, float(dt), float(eps), int(pieces)
        if not (isinstance(target_checks, (int, np.integer)) and target_checks >= 1):
            raise ValueError(f"target_checks must be a positive integer, got {target_checks!r}")
        self.target_checks = int(target_checks)
        self.n = model.state_dim
        #: the environment's sub-steps a period, at whose ends it checks ``C1`` and landing (at least ``substeps``)
        self.checks = max(self.target_checks, int(getattr(model, "substeps", 1) or 1))
        self.first_check = self.dt / self.checks
        slacks = env_slack(model, self.dt, self.checks)
        #: the proof covers the env's numbers (RK4's error and its stages' bounded: :func:`env_slack`), else only
        #: the exact motion
        self.env_covered = slacks is not None
        #: how far the env's states, and the stage states where it reads the budget's rate, may lie from the
        #: motion's boxes (:func:`env_slack`); zero unless :attr:`env_covered`
        self.slack, self.stage_slack = slacks if self.env_covered else (np.zeros(model.state_dim),) * 2
        self.fields = dict(fields)
        #: ``W_eps`` or the budget surface ``Q_min``
        self.budget_field = next((f for f in BUDGET_FIELDS if f in self.fields), None)
        if self.budget_field is None:
            raise ValueError("the one-period test needs W_eps or Q_min (the classical V alone does not say how much "
                             "budget)")
        b_values, b_times, b_grid = self.fields[self.budget_field]
        self.z_top = b_grid.hi[-1] if self.budget_field == "W_eps" else np.inf
        self.horizon = float(b_times[-1])
        #: the budget's (:func:`budget_allowance`), for every model: the env sums the budget in floating point
        #: whatever its motion, and a period spent wholly outside ``C2`` costs ``dt``, onto a budget cell's edge
        self.budget_slack = budget_allowance(self.dt, self.horizon, self.pieces)
        V = kernel_field(*self.fields.get("V", self.fields[self.budget_field]))
        if self.budget_field == "W_eps":
            W = inside = kernel_field(*self.fields["W_eps"])
            W_read = (W, float(self.z_top), float(b_grid.lo[-1]), np.inf)
        else:
            W, inside = surface_fields(b_values, b_times, b_grid, self.horizon)
            W_read = (W, self.horizon, 0.0, self.horizon)
        #: ``(W, z_top, z_floor, z_left, V, has_V, inside)``, as :class:`~softreach.filters.compiled_args.TableArgs`
        self.table_args = W_read + (V, "V" in self.fields, inside)
        #: the control box's map (:func:`action_map`); candidates are made :func:`representable`
        self.a_mid, self.a_half = action_map(model)
        self.candidates = np.asarray(candidates, dtype=np.float64)
        if self.env_covered:
            self.candidates = representable(self.candidates, self.a_mid, self.a_half)

    @classmethod
    def from_table(cls, table: Any, model: Any, dt: float, eps: float, target_checks: int = 1) -> "Lookahead":
        """The test against a solved table's ``V`` and ``W_eps``, with the candidates it was solved with."""
        fields = {name: (table.values(name), table.times(name), table.grid(name))
                  for name in ("V", "W_eps", "Q_min") if name in table.header["fields"]}
        # the budget field's candidates (a table with neither field is refused by the constructor)
        held = next((table.header["fields"][f].get("held_controls") for f in BUDGET_FIELDS if f in fields), None)
        return cls(fields, model, dt, eps, held if held else model.held_candidates(), target_checks=target_checks)

    def certificate(self, t: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        """``D(t, x, z)``: ``+inf`` outside the table (unsafe), at a negative budget or after the horizon."""
        out = np.empty(len(x))
        t = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (len(x),)))
        certificate_rows(*self.table_args[:6], t, np.ascontiguousarray(x, dtype=np.float64),
                         np.ascontiguousarray(np.broadcast_to(np.asarray(z, dtype=np.float64), (len(x),))), out)
        return out
