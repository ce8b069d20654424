"""softreach.reach: the soft-constrained Hamilton-Jacobi solver and ``W_eps`` tables.

Quick use::

    from softreach.reach import load_table
    table = load_table("pointmass.srt")
    table.value(0.0, [[0.0, 5.0]], z=[0.3])          # W_eps(t, x, z)
    table.optimal_control(0.0, [[0.0, 5.0]], z=[0.3])  # a*(t, x, z)
    table.set_mask(0.0, budget=0.3)                    # RA~_0.3 on the state grid

See :mod:`softreach.reach.problem` for the names (``target``, ``hard_constraint``, ``soft_constraint``, ``budget``,
``W_eps``) used throughout.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from softreach import lazy_exports

#: public name -> the submodule that defines it; each loads on first use (PEP 562), so that importing one
#: submodule (``softreach.reach.problem`` for the envs) does not import the solver and torch with it
_EXPORTS = {
    "SolveConfig": ".numerics.compute", "solve_table": ".numerics.compute",
    "Grid": ".numerics.grid", "budget_axis": ".numerics.grid",
    "get_model": ".models",
    "Model": ".problem", "ReachAvoidProblem": ".problem", "classical_problem": ".problem", "soft_problem": ".problem",
    "Table": ".tables.query", "load_table": ".tables.query",
    "SolverSettings": ".numerics.solver", "solve": ".numerics.solver",
    "TableError": ".tables.table",
}

__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:  # static readers see the names without the lazy indirection
    from .numerics.compute import SolveConfig, solve_table
    from .numerics.grid import Grid, budget_axis
    from .models import get_model
    from .problem import Model, ReachAvoidProblem, classical_problem, soft_problem
    from .tables.query import Table, load_table
    from .numerics.solver import SolverSettings, solve
    from .tables.table import TableError


__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
