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

from .compute import SolveConfig, solve_table
from .grid import Grid, budget_axis
from .models import get_model
from .problem import Model, ReachAvoidProblem, classical_problem, soft_problem
from .query import Table, load_table
from .solver import SolverSettings, solve
from .table import TableError

__all__ = ["Grid", "Model", "ReachAvoidProblem", "SolveConfig", "SolverSettings", "Table", "TableError", "budget_axis",
           "classical_problem", "get_model", "load_table", "soft_problem", "solve", "solve_table"]
