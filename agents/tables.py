"""What the agents read from a ``W_eps`` table: fast per-step ``a*``/``b*``, shared safety filters, start states.

* :class:`TableOracle` answers ``W~``, ``a*(t, x, z)`` and ``b*(t, x, z)`` for one state at a time through the
  table's :class:`~softreach.reach.tables.field.TableField` (the same interpolant and central-difference gradient as
  :meth:`softreach.reach.Table.optimal_control`, several times faster for single queries). It is what the
  ``optimal`` policy plays and what ``wind="adversarial"`` blows: an environment accepts it as ``wind_table``.
* :func:`safety_filter` wraps an environment in :class:`~softreach.filters.SafetyFilter`, computing the
  filter's margin field once per table and sharing it between environments (one margin field is several
  seconds of work and up to a few hundred MB; a vectorised training run holds many environments).
* :func:`sample_inside`, :func:`paper_starts` (:mod:`softreach.reach.tables.starts`, the pickers the plots use too),
  :func:`sample_uniform`: the start distributions of ``softreach evaluate --starts inside|paper|uniform``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from softreach.reach import Table, load_table
from softreach.reach.tables.starts import paper_starts, sample_inside  # noqa: F401  (the start distributions, re-exported)

def as_table(table: Table | str | Any) -> Table:
    """A loaded :class:`Table` (``table`` itself, or the file it names)."""
    return table if isinstance(table, Table) else load_table(table)


class TableOracle:
    """``W~``, ``a*`` and ``b*`` of a ``W_eps`` table, one state at a time.

    ``a*`` and ``b*`` are read at the budget ``max(z, r)``, ``r`` the table's :attr:`~Table.budget_resolution`
    (half a budget cell): the convention of :meth:`softreach.reach.Table.optimal_control` and of the filter. At
    ``z = 0`` the exact ``W_eps`` is flat (``>= 0`` everywhere, ``= 0`` on ``RA~_0``) and its gradient says
    nothing; once the budget is spent the best the table knows is the feedback of the smallest budget.
    :meth:`value` is read at ``max(z, 0)``.

    :param table: a table with ``W_eps`` (or its path)
    """

    def __init__(self, table: Table | str):
        from softreach.reach.tables.field import TableField

        self.table = as_table(table)
        self.model = self.table.model
        self.field = TableField(self.table)
        self.n = self.model.state_dim
        grid = self.table.grid("W_eps")
        self._z_hi = float(grid.hi[-1])
        self._z_lo = float(self.table.budget_resolution)
        # what an environment checks before it accepts us as wind_table=
        self.model_metadata = self.table.model_metadata
        self.eps = self.table.eps
        self.path = self.table.path

    def _value_grad(self, t: float, x: Sequence[float], z: float, floor: float | None = None) -> tuple[float, list[float]]:
        zq = min(max(float(z), self._z_lo if floor is None else floor), self._z_hi)
        c = [float(v) for v in x] + [zq]
        found = self.field.single(float(t), c)
        if found is None:  # grid edge cells: the batch path (same numbers)
            val, grad, _ = self.field.value_and_gradient(np.array([float(t)]), np.array([c]))
            return float(val[0]), grad[0].tolist()
        return float(found[0]), list(found[1])

    def value(self, t: float, x: Sequence[float], z: float) -> float:
        """``W~(t, x, max(z, 0))`` (``+inf`` outside the table)."""
        return self._value_grad(t, x, z, floor=0.0)[0]

    def optimal_control(self, t: float, x: Sequence[float], z: float) -> np.ndarray:
        """``a*(t, x, z)``, physical units, shape ``(m,)``, clipped to the control box."""
        _, grad = self._value_grad(t, x, z)
        a = np.array([float(np.asarray(v)) for v in self.model.optimal_control(float(t), [float(v) for v in x], grad)])
        lo, hi = self.model.control_bounds
        return np.clip(a, lo, hi)

    def _worst_one(self, t: float, x: Sequence[float], z: float) -> np.ndarray:
        _, grad = self._value_grad(t, x, z)
        return np.array([float(np.asarray(v)) for v in self.model.worst_disturbance(float(t), [float(v) for v in x], grad)])

    def worst_disturbance(self, t: float, x: Any, z: Any) -> np.ndarray:
        """``b*(t, x, z)`` for ``x`` of shape ``(N, n)`` (or ``(n,)``) and ``z`` scalar or ``(N,)``: ``(N, k)``.

        The signature of :meth:`softreach.reach.Table.worst_disturbance`, so an environment takes the oracle as
        ``wind_table``.
        """
        xs = np.asarray(x, dtype=np.float64).reshape(-1, self.n)
        zs = np.broadcast_to(np.asarray(z, dtype=np.float64).reshape(-1), (len(xs),))
        return np.stack([self._worst_one(t, xs[i].tolist(), float(zs[i])) for i in range(len(xs))])


# --------------------------------------------------------------------------------------------- filters

_FILTER_CACHE: dict[tuple, Any] = {}


def safety_filter(env: Any, table: Table | str, rule: str = "switch", margin: float | None = None) -> Any:
    """``SafetyFilter(env, table, margin, rule)``, with the filter's core shared between calls.

    The first call for a table file, control period, rule, margin and number of landing checks builds the
    :class:`~softreach.filters.ValueFilter` (and its margin field); later calls pass it as ``value_filter=``. Each
    wrapper keeps its own episode statistics; the shared core holds only the table and the margin field.

    The core checks landing at the environment's ``n_substeps`` instants per period, as the core
    :class:`~softreach.filters.SafetyFilter` builds for itself: the same decisions, and the cells the package
    ships (the glider's are for its 2 checks; with 1 they would be built first, minutes and gigabytes).
    """
    from softreach.filters import SafetyFilter, ValueFilter

    table = as_table(table)
    dt = float(env.unwrapped.dt)
    checks = int(getattr(env.unwrapped, "n_substeps", 1))
    key = (str(Path(table.path).resolve()), dt, rule, margin, checks)
    core = _FILTER_CACHE.get(key)
    if core is None:
        core = ValueFilter(table, dt, margin=margin, rule=rule, model=env.unwrapped.model, target_checks=checks)
        if len(_FILTER_CACHE) >= 4:  # keep at most a few margin fields alive
            _FILTER_CACHE.pop(next(iter(_FILTER_CACHE)))
        _FILTER_CACHE[key] = core
    return SafetyFilter(env, value_filter=core)


def clear_filter_cache() -> None:
    """Forget the shared filter cores (frees their margin fields)."""
    _FILTER_CACHE.clear()


# --------------------------------------------------------------------------------------------- starts

def in_set(table: Table, x: Sequence[float], q: float, t: float = 0.0) -> bool:
    """Whether ``x`` lies in ``RA~_Q`` at time ``t``: :meth:`Table.contains`, the rule of :meth:`Table.set_mask`
    evaluated at ``x`` itself."""
    return bool(table.contains(t, np.asarray(x, dtype=np.float64), float(q))[0])


def start_value(table: Table, x: Sequence[float], q: float, t: float = 0.0) -> float:
    """``W_eps(t, x, max(Q, r))`` at a start (``+inf`` outside the table)."""
    z = max(float(q), table.budget_resolution)
    return float(table.value(t, np.asarray(x, dtype=np.float64)[None, :], np.array([z]))[0])


def uniform_box(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """The box of ``--starts uniform``: the hard-constraint box ``C1`` clipped to the model's domain (a start
    outside ``C1`` has failed before it begins); the whole domain where the model has no box."""
    lo, hi = (np.array(v, dtype=np.float64) for v in model.domain)
    box = model.hard_box
    if box is not None:
        lo = np.maximum(lo, np.array(box[0], dtype=np.float64))
        hi = np.minimum(hi, np.array(box[1], dtype=np.float64))
    lo = np.where(np.isfinite(lo), lo, np.array(model.domain[0], dtype=np.float64))
    hi = np.where(np.isfinite(hi), hi, np.array(model.domain[1], dtype=np.float64))
    return lo, hi


def sample_uniform(model: Any, rng: np.random.Generator) -> np.ndarray:
    """A state drawn uniformly from :func:`uniform_box`."""
    lo, hi = uniform_box(model)
    return rng.uniform(lo, hi)


def sink_rate(model: Any, x: Sequence[float]) -> float:
    """The model's touchdown speed at state ``x`` [m/s] (:meth:`~softreach.reach.problem.Model.sink_rate`: point
    mass ``-v``, glider ``-V sin(gamma)``; ``nan`` for a model without one)."""
    return float(model.sink_rate([float(v) for v in x]))


#: draws of ``RA~_Q`` tried per certified start before giving up (the set has no certified part)
CERTIFIED_TRIES = 200


def sample_certified(table, vf, q: float, rng: np.random.Generator) -> np.ndarray:
    """A random start of ``RA~_Q`` (:func:`sample_inside`) that the filter certifies at ``t = 0``.

    :param vf: the :class:`~softreach.filters.ValueFilter` that certifies (a table of the sampled-data game)
    :raises ValueError: none of :data:`CERTIFIED_TRIES` draws was certified
    """
    for _ in range(CERTIFIED_TRIES):
        x = np.asarray(sample_inside(table, q, rng), dtype=np.float64)
        if bool(vf.certify(0.0, x, q)[0]):
            return x
    raise ValueError(f"no certified start in {CERTIFIED_TRIES} draws of RA~_Q (Q={q:g}) from table {table.path}")


__all__ = ["CERTIFIED_TRIES", "TableOracle", "as_table", "clear_filter_cache", "in_set", "paper_starts",
           "safety_filter", "sample_certified", "sample_inside", "sample_uniform", "sink_rate", "start_value",
           "uniform_box"]
