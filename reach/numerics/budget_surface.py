"""The budget surface ``Q_min(t, x)``, solved on the state grid: no budget axis.

``z`` is a monotone integrator (``z' = -h_eps(t, x)``, no player enters it), so the whole ``W_eps`` table carries
one surface: ``RA~_Q = {x : Q_min(t, x) <= Q}`` (paper, eq. Q_min). That surface is itself the value of a game on
``x`` alone, a reach-avoid game with a running cost:

    Q_min(t, x) = inf_a sup_b  int_t^tau h_eps(s, x(s)) ds,

over the strategies that reach the target inside ``C2`` at some ``tau <= T`` and stay in ``C1`` on ``[t, tau]``
(``+inf`` where none does). Dynamic programming gives the variational inequality

    0 = max{ c_Q - Q,  min[ l_Q - Q,  Q_t + min_a max_b grad Q . f + h_eps ] },   Q(T) = max(c_Q, l_Q),

with ``l_Q = 0`` on the target inside ``C2`` (stopping there costs nothing more) and ``+inf`` elsewhere, and
``c_Q = +inf`` outside ``C1`` (``0`` inside: a budget is never negative). It is the ``W_eps`` equation read along
its zero level set: where ``W_eps(t, x, Q_min(t, x)) = 0`` with ``dW/dz < 0``, ``Q_x = -W_x / W_z`` and
``Q_t = -W_t / W_z``, and dividing ``W_t + min_a max_b (W_x . f) - W_z h_eps = 0`` by ``-W_z > 0`` gives the
equation above. The ``eps`` of ``h_eps`` enters exactly as in ``W_eps``: the running cost is ``h_eps``, not the
indicator of ``x`` outside ``C2``, so ``Q_min`` is at most the exact (``eps -> 0``) one by about the time spent in
the ``eps`` band.

**Bounded transform.** ``+inf`` is replaced by ``cap = 2 T`` (more than any budget can be used: ``h_eps <= 1``
over at most ``T``), so ``Q_min > T - t`` reads as "no budget suffices". The obstacles are then indicator
functions on the nodes, exact there: a node outside ``C1`` holds ``cap``, a node on the target inside ``C2`` at
most ``0``. The schemes see a jump of ``cap`` at the edge of the feasible set; WENO reconstructs it without
oscillation and the monotone Lax-Friedrichs flux smears it over about a cell, which blurs the sets' edges by a
cell, as the ``W_eps`` solve does (``benchmarks/grade_pointmass.py`` measures both against the exact sets).

**The feasible set, solved beside it.** Where no budget suffices is itself a reach-avoid set with no running cost:
reach the target inside ``C2`` while staying in ``C1`` (:class:`FeasibilityProblem`), whose value ``V_feas`` is
continuous, so its scheme has no jump to smear. :func:`solve_budget_surface` marches it beside ``Q_min`` (the same
steps) and stores ``max(Q, time left + 0.001 s + V_feas)`` in every snapshot of ``Q_min`` wherever ``V_feas > 0``:
above the time left,
which reads as "no budget suffices", so the smeared jump can no longer pull ``Q_min`` below it outside the feasible
set, which is where the unmasked solve claimed infeasible states; ``V_feas``'s slope gives the feedback there the
direction back towards the feasible set. Between snapshots the march runs unmasked, and it goes on from the stored
snapshot, so a resumed solve continues as an unbroken one does. Raising those nodes only to just above the time
left, not to ``cap + V_feas``, keeps small the jump that the scheme then smears back into the feasible set: at
``300 x 300`` the sets for ``Q > 0`` were 0.1-0.9 points closer to the exact ones (masking every stage was
measured looser still, ``docs/budget_surface.md``).

**The classical ``RA`` as the zero set, marched in lockstep.** ``Q_min(t, x) = 0`` exactly where ``x`` lands without
leaving ``C2``, in the classical ``RA(t) = {V(t) <= 0}`` (paper, Prop. 3), not only on the target. So every step of
the ``Q_min`` march takes ``l_Q = 0`` on ``{V <= 0}``, with ``V`` marched beside it by the same steps and read at the
step's later end (the ``RA`` of less time left, a subset of the exact one when ``V`` is sound). Without it, the
zero set of ``Q_min`` grows only from the target, through the thin band of states that brake into the touchdown
speeds on time, and the schemes' smearing across that band's walls, where ``Q_min`` jumps from about 0 to ``cap``,
raised ``Q_min`` everywhere upstream: 0.32 s at ``(v, y) = (0, 8.5)`` on ``101 x 101``, where the exact value is 0.
``RA`` is a thick set with a continuous value, and with it the symmetric difference to the exact sets at
``300 x 300`` fell from 5.1-8.4 % to 3.2-5.2 % for ``Q > 0`` (``docs/budget_surface.md``).

Costs: one state-grid solve instead of ``n_z`` (111 to 200) times that, so the same memory buys a far finer state
grid; the feasible set and the ``V`` in lockstep add two more.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

from .. import backend as B
from ..dynamics import Components, Dynamics
from .grid import Grid
from ..problem import Array, Model, ReachAvoidProblem, classical_problem
from .solver import HamiltonianOperator, SnapshotSink, SolverSettings, Stepper, initial_value, output_times


class RunningCost(Dynamics):
    """A model's dynamics with the running cost ``h_eps`` in the Hamiltonian: ``H(t, x, p) + h_eps(t, x)``.

    ``h_eps`` depends on neither player, so the optimal inputs and the dissipation are the model's.
    """

    def __init__(self, model: Model, eps: float):
        self.model = model
        self.eps = float(eps)
        self.name = f"{model.name}+running-cost"
        self.state_names = tuple(model.state_names)
        self.state_units = tuple(model.state_units)
        self.control_bounds = model.control_bounds
        self.disturbance_bounds = model.disturbance_bounds

    def f(self, t, x, a, b):
        return self.model.f(t, x, a, b)

    def running_cost(self, t, x):
        return self.model.violation_rate(t, x, self.eps)

    def hamiltonian(self, t, x, p):
        return self.model.hamiltonian(t, x, p) + self.running_cost(t, x)

    def optimal_control(self, t, x, p):
        return self.model.optimal_control(t, x, p)

    def worst_disturbance(self, t, x, p):
        return self.model.worst_disturbance(t, x, p)

    def dissipation(self, t, x, p_lo=None, p_hi=None):
        return self.model.dissipation(t, x, p_lo, p_hi)


@dataclass(frozen=True)
class BudgetSurfaceProblem(ReachAvoidProblem):
    """The game of ``Q_min`` (module docstring) in the solver's form ``max(c, min(l, .))``."""

    cap: float = 2.0

    def target_function(self, t: float, x: Components) -> Array:
        """``l_Q``: ``0`` on the target inside ``C2``, ``cap`` elsewhere."""
        inside = B.maximum(self.model.target(t, x), self.model.soft_constraint(t, x))
        return B.where(inside <= 0, 0.0, self.cap)

    def constraint_function(self, t: float, x: Components) -> Array:
        """``c_Q``: ``cap`` outside ``C1``, ``0`` inside (a budget is never negative)."""
        return B.where(self.model.hard_constraint(t, x) > 0, self.cap, 0.0)

    def floor_function(self, t: float, x: Components) -> Array | None:
        return None

    def metadata(self) -> dict[str, Any]:
        return {**super().metadata(), "cap": self.cap}


def budget_problem(model: Model, eps: float = 1e-3) -> BudgetSurfaceProblem:
    """The ``Q_min`` game of ``model`` with the running cost ``h_eps`` of width ``eps``."""
    if not eps > 0:
        raise ValueError(f"eps must be a finite positive number, got {eps!r}")
    return BudgetSurfaceProblem(dynamics=RunningCost(model, eps), model=model, kind="budget", eps=float(eps),
                                cap=2.0 * float(model.horizon))


def no_budget_suffices(q: Any, time_left: Any) -> Any:
    """Where a solved ``Q_min`` says that no budget suffices: above the time left (the capped values)."""
    return q > time_left + 1e-9


@dataclass(frozen=True)
class FeasibilityProblem(ReachAvoidProblem):
    """Whether any budget suffices: reach the target inside ``C2`` at some ``tau <= T``, staying in ``C1``.

    ``{V_feas <= 0}`` is ``{Q_min < inf}``: a run that does this spends at most the time left, and every finite
    ``Q_min`` comes from such a run.
    """

    def target_function(self, t: float, x: Components) -> Array:
        return B.maximum(self.model.target(t, x), self.model.soft_constraint(t, x))

    def constraint_function(self, t: float, x: Components) -> Array:
        return self.model.hard_constraint(t, x)

    def floor_function(self, t: float, x: Components) -> Array | None:
        return None


def feasibility_problem(model: Model) -> FeasibilityProblem:
    return FeasibilityProblem(dynamics=model, model=model, kind="feasibility")


def solve_budget_surface(problem: BudgetSurfaceProblem, grid: Grid, times: Sequence[float],
                         settings: SolverSettings | None = None, *, sink: SnapshotSink | None = None,
                         start: tuple[int, Array] | None = None, progress: Any = None,
                         classical: Any = None) -> Array:
    """:func:`softreach.reach.numerics.solver.solve` for ``Q_min``, marched in lockstep with the classical ``V``, whose
    ``{V <= 0}`` is ``Q_min``'s zero set, and with the feasible set's ``V_feas``, which says where no budget
    suffices (module docstring). Arguments as there, and:

    :param classical: ``k -> V`` at ``times[k]``, the classical value a table stores beside ``Q_min``: where it is
        positive the stored ``Q_min`` is at least ``1e-6`` s, so that ``{Q_min <= 0}`` lies in that ``V``'s ``RA``
        (Prop. 3: ``Q_min = 0`` only there) whatever the steps of the ``V`` marched here or an undershoot of the
        scheme next to ``RA``
    """
    settings = settings or SolverSettings()
    times = output_times(times)
    model = problem.model
    ra = HamiltonianOperator(classical_problem(model), grid, settings)
    feasible = HamiltonianOperator(feasibility_problem(model), grid, settings)
    op = HamiltonianOperator(problem, grid, settings)
    steppers = [Stepper(ra, settings), Stepper(feasible, settings), Stepper(op, settings)]
    # l_Q on its own; op.l is overwritten in place below, so compiled steps read the new values
    l_q = op.l * 1

    def from_ra(v: Array) -> None:
        # the RA of a step's later end (less time left: a subset of the exact one), from where no budget is needed
        _overwrite(op.l, B.where(v <= 0, 0 * l_q, l_q))

    def masked(f: Array, k: int, u: Array) -> Array:
        # idempotent, so that a resumed solve may apply it again to the snapshot it starts from
        u = B.where(f > 0, B.maximum(u, f + (times[-1] - times[k] + 1e-3)), u)
        if classical is not None:
            v_k = B.asarray(classical(k), settings.backend, settings.dtype, settings.device)
            u = B.where(v_k > 0, B.maximum(u, 0 * u + 1e-6), u)
        return u

    v, f = ra.terminal(times[-1]), feasible.terminal(times[-1])
    k0, u = initial_value(op, times, start, None)
    for k in range(len(times) - 2, k0 - 1, -1):  # a resumed solve: V and V_feas up to where Q_min resumes
        v, f = _lockstep(steppers[:2], [v, f], times[k + 1], times[k], from_ra, None)
    u = masked(f, k0, u)
    if start is None and sink is not None:
        sink(k0, times[k0], u)
    for k in range(k0 - 1, -1, -1):
        v, f, u = _lockstep(steppers, [v, f, u], times[k + 1], times[k], from_ra, progress)
        # the march goes on from what the table stores, so that a resumed solve continues as an unbroken one
        u = masked(f, k, u)
        if sink is not None:
            sink(k, times[k], u)
    return u


def _lockstep(steppers: list[Stepper], values: list[Array], t: float, stop: float, before_step: Any,
              progress: Any) -> list[Array]:
    """March every value back from ``t`` to ``stop`` with the same steps (the smallest any of them needs); before
    each step ``before_step(values[0])`` sets targets from the first value at the step's later end."""
    cfl = steppers[0].settings.cfl
    while t - stop > 1e-12 * max(1.0, abs(stop)):
        rates = [s.rate(t, u) for s, u in zip(steppers, values)]
        speed = max(r[1] for r in rates)
        if not math.isfinite(speed):
            raise FloatingPointError(f"the dissipation speed is {speed} at t = {t:.6g}: a NaN in V, V_feas or Q_min")
        remaining = t - stop
        steps = max(1, math.ceil(remaining / (cfl / speed) - 1e-9)) if speed > 0 else 1
        dt = remaining / steps
        before_step(values[0])
        values = [s.step(t, u, r[0], dt) for s, u, r in zip(steppers, values, rates)]
        t -= dt
        if progress is not None:
            progress.update(max(0.0, min(dt, (progress.total or math.inf) - progress.n)))
    return values


def _overwrite(dst: Array, src: Array) -> None:
    if hasattr(dst, "copy_"):
        dst.copy_(src)
    else:
        dst[...] = src
