"""Reach-avoid problems: the classical one (value ``V``) and the soft-constrained one (value ``W_eps``).

Names from the paper, used across softreach:

* ``target`` ``g`` — the set to reach (touchdown), ``{g <= 0}``;
* ``hard_constraint`` ``c1`` — never to be left (``C1 = {c1 <= 0}``);
* ``soft_constraint`` ``c2`` — may be left for a bounded total time (``C2 = {c2 <= 0}``);
* ``budget`` ``z`` — the violation time still allowed; ``z' = -h_eps(t, x)`` with
  ``h_eps = min(1, max(0, c2 / eps))``, a Lipschitz stand-in for the indicator of ``x`` outside ``C2``;
* ``W_eps(t, x, z)`` — the soft-constrained value (Thm. 3): a classical reach-avoid value on the augmented state
  ``(x, z)`` with target function ``l = max(c2, -kappa z, g)`` and constraint ``c1``. Its zero sublevel set at
  ``z = Q`` is ``RA~_Q``, the states that can land spending at most ``Q`` seconds outside ``C2``.
* ``V(t, x)`` — the classical value (Prop. 2): target ``g``, constraint ``max(c1, c2)``. ``{V <= 0} = RA~_0``.
* ``V_safe(t, x)`` — the value of staying in ``C1`` until ``T`` (no target, no budget), :func:`avoid_problem`.
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import Any, Sequence

import math

import numpy as np

from . import backend as B
from .boxes import box_check, check_horizon
from .dynamics import Components, Dynamics
from .model_env import EnvPart
from .model_filter import FilterPart
from .model_report import ReportPart

Array = B.Array


class Model(Dynamics, FilterPart, EnvPart, ReportPart):
    """Dynamics plus the sets and horizon of a reach task: the public model API (``docs/models.md``).

    Subclasses implement :meth:`target`, :meth:`hard_constraint` and :meth:`soft_constraint` (implicit
    functions, ``<= 0`` inside) and set ``horizon`` and ``domain`` (the default grid box); the solver reads these and
    the :class:`~softreach.reach.dynamics.Dynamics`. What each other reader needs is a group of its own, declared
    on the model all the same: the safety filter's (:class:`~softreach.reach.model_filter.FilterPart`: the held
    candidates, the motion bound, the sets over boxes, the cells), the environment's
    (:class:`~softreach.reach.model_env.EnvPart`: control period, sub-steps, starts; "reached" is :meth:`landed`),
    and the reports' (:class:`~softreach.reach.model_report.ReportPart`: words, budgets shown, units). So every fact
    that code elsewhere would otherwise look up by the model's name lives on the model. :meth:`parameters` returns
    the constructor's keyword arguments, from which a table rebuilds the model.
    """

    horizon: float = 1.0
    #: default grid box ``(lo, hi)`` over the physical state
    domain: tuple[tuple[float, ...], tuple[float, ...]] = ((), ())
    #: bounding box of the hard-constraint set ``C1``; a grid must contain it (``None``: unbounded, unchecked)
    hard_box: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: default state grid and number of budget nodes for ``softreach solve``
    default_shape: tuple[int, ...] = ()
    default_budget_points: int = 101
    default_snapshots: int = 21
    #: default ``kappa`` in ``l = max(c2, -kappa z, g)``, in units of ``c2`` per second. The zero sublevel set does
    #: not depend on it, the numerics do: outside ``C2`` at zero budget ``W`` grows like ``kappa`` times the time
    #: needed to get back, while the classical ``V`` grows like ``c2``. Matching the two (``kappa`` about the rate
    #: at which the controls can change ``c2``) keeps the budget slices as well resolved as ``V``.
    budget_scale: float = 1.0
    #: ``f``, the sets and the target do not depend on ``t`` (the solver then evaluates the sets once)
    time_invariant: bool = True
    #: per state axis, whether it is periodic (an angle): its period is the ``domain`` along it, ``[lo, hi)``.
    #: The solver's grid wraps there (no boundary), table queries wrap the coordinate, the environment wraps the
    #: state. Empty: no periodic axis.
    periodic: tuple[bool, ...] = ()

    #: the declared boxes and ranges, checked where they are set (:class:`~softreach.reach.dynamics.Dynamics`):
    #: a grid spans ``domain`` and cells tile ``hard_box``, so both need width on every axis; the empty ``domain``
    #: ``((), ())`` means none declared; each part adds the checks of its own
    _CHECKS = {
        **Dynamics._CHECKS,
        **FilterPart._CHECKS,
        **EnvPart._CHECKS,
        "domain": box_check("domain", states=True, strict=True),
        "hard_box": box_check("hard_box", states=True, strict=True, optional=True),
        "horizon": check_horizon,
    }

    @abstractmethod
    def target(self, t: float, x: Components) -> Array:
        """``g``: ``<= 0`` on the target set."""

    @abstractmethod
    def hard_constraint(self, t: float, x: Components) -> Array:
        """``c1``: ``<= 0`` on the hard-constraint set ``C1``."""

    @abstractmethod
    def soft_constraint(self, t: float, x: Components) -> Array:
        """``c2``: ``<= 0`` on the soft-constraint set ``C2``."""

    def validate_state(self, x: Sequence[Any]) -> None:
        """Raise ``ValueError`` naming a state the model cannot take (beyond the domain box the env checks);
        the default accepts every state."""

    def periodic_axes(self) -> tuple[bool, ...]:
        """:attr:`periodic` with one entry per state axis (``False`` where not given).

        :raises ValueError: a :attr:`periodic` of the wrong length
        """
        if not self.periodic:
            return (False,) * self.state_dim
        if len(self.periodic) != self.state_dim:
            raise ValueError(f"{self.name}: periodic needs one flag per state {self.state_names}, got {self.periodic!r}")
        return tuple(bool(p) for p in self.periodic)

    def wrap_state(self, x: Sequence[float]) -> list[float]:
        """The state with each periodic coordinate moved into its period ``[lo, hi)`` of :attr:`domain`.

        :param x: one state, a number per component
        """
        out = [float(v) for v in x]
        for i, per in enumerate(self.periodic_axes()):
            if per:
                lo, hi = float(self.domain[0][i]), float(self.domain[1][i])
                out[i] = lo + (out[i] - lo) % (hi - lo)
        return out

    def landed(self, t: float, x: Components) -> Array:
        """In the target, inside ``C2`` and ``C1``: where an episode ends landed (no action is needed there)."""
        return (self.target(t, x) <= 0) & (self.soft_constraint(t, x) <= 0) & (self.hard_constraint(t, x) <= 0)

    def violation_rate(self, t: float, x: Components, eps: float) -> Array:
        """``h_eps(t, x) = min(1, max(0, c2 / eps))``: the rate at which the budget drains."""
        return B.clip(self.soft_constraint(t, x) / eps, 0.0, 1.0)

    def metadata(self) -> dict[str, Any]:
        """What a table records to refuse being used with another model, and to rebuild it: its name, its
        :meth:`parameters` (the constructor's keyword arguments) and, for a model without a registered short
        name, the ``"module:Class"`` path to import it from."""
        from .registry import is_class_path, spec_of

        out = {"name": self.name, "parameters": self.parameters(), "state_names": list(self.state_names)}
        spec = spec_of(self)
        if is_class_path(spec):
            out["class"] = spec
        return out


class BudgetAugmented(Dynamics):
    """The augmented dynamics ``(x, z)' = (f(t, x, a, b), -h_eps(t, x))`` of a :class:`Model`.

    ``z'`` depends on neither player, so the Hamiltonian is ``H(t, x, p_x) - p_z h_eps`` and the dissipation
    along ``z`` is exactly ``h_eps``: the Lax-Friedrichs scheme then reduces to the exact upwind scheme along
    ``z`` and adds no numerical diffusion there (spec §4 explains why that matters).
    """

    def __init__(self, model: Model, eps: float):
        if not (math.isfinite(eps) and eps > 0):
            raise ValueError(f"eps must be a finite positive number, got {eps!r}")
        self.model = model
        self.eps = float(eps)
        self.name = f"{model.name}+budget"
        self.state_names = tuple(model.state_names) + ("z",)
        self.state_units = tuple(model.state_units) + ("s",)
        self.control_bounds = model.control_bounds
        self.disturbance_bounds = model.disturbance_bounds

    def f(self, t, x, a, b):
        return list(self.model.f(t, x[:-1], a, b)) + [-self.model.violation_rate(t, x[:-1], self.eps)]

    def hamiltonian(self, t, x, p):
        return self.model.hamiltonian(t, x[:-1], p[:-1]) - p[-1] * self.model.violation_rate(t, x[:-1], self.eps)

    def optimal_control(self, t, x, p):
        return self.model.optimal_control(t, x[:-1], p[:-1])

    def worst_disturbance(self, t, x, p):
        return self.model.worst_disturbance(t, x[:-1], p[:-1])

    def dissipation(self, t, x, p_lo=None, p_hi=None):
        inner = self.model.dissipation(t, x[:-1], None if p_lo is None else p_lo[:-1], None if p_hi is None else p_hi[:-1])
        return list(inner) + [self.model.violation_rate(t, x[:-1], self.eps)]


@dataclass(frozen=True)
class ReachAvoidProblem:
    """A reach-avoid game as the solver sees it: dynamics, target function ``l`` and constraint ``c``.

    The value solves ``0 = max{c - W, min[l - W, W_t + H]}`` with ``W(T) = max(c, l)``.
    """

    dynamics: Dynamics
    model: Model
    kind: str  # "classical", "soft", "avoid" or "budget" (:mod:`softreach.reach.numerics.budget_surface`)
    eps: float | None = None
    budget_scale: float = 1.0

    def target_function(self, t: float, x: Components) -> Array:
        """``l``: ``g`` (classical), ``max(c2, -kappa z, g)`` (soft), ``+inf`` (avoid: nothing to reach)."""
        if self.kind == "avoid":
            return self.model.hard_constraint(t, x) * 0 + math.inf
        if self.kind == "classical":
            return self.model.target(t, x)
        xs, z = x[:-1], x[-1]
        out = B.maximum(self.model.soft_constraint(t, xs), self.model.target(t, xs))
        return B.maximum(out, -self.budget_scale * z) if hasattr(z, "shape") else B.maximum(out, -self.budget_scale * z + 0 * out)

    def floor_function(self, t: float, x: Components) -> Array | None:
        """A lower bound the exact value always satisfies, or ``None``.

        For the soft problem ``W >= -kappa z``: the budget never increases, so every term ``-kappa z(tau)`` that
        ``l`` can take along a trajectory is at least ``-kappa z``. Enforcing it keeps high-order schemes from
        undershooting into spurious safety (it matters most at ``z = 0``, where the exact ``W`` is ``>= 0``).
        """
        if self.kind != "soft":
            return None
        return -self.budget_scale * x[-1]

    def constraint_function(self, t: float, x: Components) -> Array:
        """``c``: ``max(c1, c2)`` (classical) or ``c1`` (soft, avoid)."""
        if self.kind == "avoid":
            return self.model.hard_constraint(t, x)
        if self.kind == "classical":
            return B.maximum(self.model.hard_constraint(t, x), self.model.soft_constraint(t, x))
        return self.model.hard_constraint(t, x[:-1])

    @property
    def has_target(self) -> bool:
        """Whether the game ends on reaching a target (reach-avoid) or only asks to stay (avoid): the terminal
        value is ``max(c, l)`` in the first case, ``c`` in the second."""
        return self.kind != "avoid"

    def boundaries(self, periodic: Sequence[bool], rule: str) -> list[Any]:
        """The ghost-node rule of each grid axis (:func:`softreach.reach.numerics.derivatives.pad`): periodic axes wrap,
        the others take ``rule`` (the settings' ``"extrapolate_away"``: conservative where the edge value is
        positive, which :func:`check_edges` asks of every state axis).

        The budget axis ``z`` of the soft problem is settled here. Budget only decreases, so information enters
        ``z`` from below: there the nodes lie under ``z = 0``, where the floor ``W >= -kappa z > 0`` holds every
        value positive, so ghosts extrapolated away from zero are conservative. The top of the axis is the
        horizon ``T``, and no run spends more than the time left, so ``W_eps`` is constant in ``z`` above it: the
        edge value itself is the exact ghost.
        """
        out: list[Any] = ["periodic" if p else rule for p in periodic]
        if self.kind == "soft":
            out[-1] = (rule, "constant")
        return out

    def metadata(self) -> dict[str, Any]:
        return {"kind": self.kind, "eps": self.eps, "budget_scale": self.budget_scale, "model": self.model.metadata()}


def check_edges(name: str, values: Any, periodic: Sequence[bool], axis_names: Sequence[str], n_states: int) -> None:
    """Raise where a value ``<= 0`` lies on a non-periodic edge of a state axis: the set reaches the grid's edge,
    where the ghost nodes (extrapolated away from zero) are no longer provably conservative.

    :param name: the field (``"V"``, ``"W_eps"``, ...; ``Q_min`` is ``>= 0`` everywhere and not checked)
    :param values: one snapshot on the field's grid
    :param n_states: the leading axes that are states (the budget axis after them is settled by
        :meth:`ReachAvoidProblem.boundaries`)
    """
    u = np.asarray(values)
    for a in range(n_states):
        if periodic[a]:
            continue
        for side, index in (("low", 0), ("high", -1)):
            edge = np.take(u, index, axis=a)
            bad = int((edge <= 0).sum())
            if bad:
                raise ValueError(f"{name}: {bad} node(s) at the {side} edge of axis {axis_names[a]!r} are inside the "
                                 f"set ({name} <= 0): the set reaches the grid's edge, where the boundary rule is "
                                 f"not provably conservative. Enlarge the domain along {axis_names[a]!r}")


def classical_problem(model: Model) -> ReachAvoidProblem:
    """The classical reach-avoid problem of Prop. 2 (value ``V``)."""
    return ReachAvoidProblem(dynamics=model, model=model, kind="classical")


def avoid_problem(model: Model) -> ReachAvoidProblem:
    """Stay in ``C1`` until ``T`` (value ``V_safe``): no target, no soft constraint."""
    return ReachAvoidProblem(dynamics=model, model=model, kind="avoid")


def soft_problem(model: Model, eps: float = 1e-3, budget_scale: float = 1.0) -> ReachAvoidProblem:
    """The soft-constrained problem of Thm. 3 (value ``W_eps``) on the budget-augmented state.

    :param eps: width of the Lipschitz regularisation ``h_eps`` (units of ``c2``)
    :param budget_scale: ``kappa`` in ``l = max(c2, -kappa z, g)``; the zero sublevel set does not depend on it
    """
    if not (math.isfinite(budget_scale) and budget_scale > 0):
        raise ValueError(f"budget_scale must be a finite positive number, got {budget_scale!r}")
    return ReachAvoidProblem(dynamics=BudgetAugmented(model, eps), model=model, kind="soft", eps=float(eps), budget_scale=float(budget_scale))
