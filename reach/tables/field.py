"""``TableField``: batched ``W~`` and its gradient along the states from a table's ``W_eps`` block, with the node-wise
differences precomputed (the table-optimal ``a*`` feedback of :mod:`softreach.agents` reads it)."""

from __future__ import annotations

import numpy as np

from .interpolation import Interpolant
from .query import Table
from .table import TableError


class TableField(Interpolant):
    """:class:`~softreach.reach.tables.interpolation.Interpolant` of a table's ``W_eps`` with the gradient along the ``n``
    state axes, kept in the layout that is fastest to query.

    The arithmetic is the engine's, so the numbers are :meth:`Table.value` and :meth:`Table.gradient`'s (state
    part) up to the order of the sums, conventions included: ``+inf`` outside the grid or the time span or below
    the budget grid, a budget above the grid taken at its top, the gradient at the query clamped to the grid.
    Two layouts:

    * ``"stacked"`` (default when it fits ``max_bytes``): the node-wise differences are computed once and stored
      next to the values (float64, ``1 + n`` numbers per node), and a query gathers ``2^D`` rows per snapshot;
    * ``"stencil"``: nothing is precomputed; a query gathers each corner's value and its ``2n`` difference
      partners straight from the (memory-mapped) table. For tables too big to copy.

    :param table: a table with a ``W_eps`` field
    :param layout: ``"stacked"``, ``"stencil"`` or ``None`` (stacked if it fits ``max_bytes``)
    :param max_bytes: memory budget of the stacked copy
    """

    def __init__(self, table: Table, layout: str | None = None, max_bytes: int = 1024 * 2**20):
        if not table.has_budget:
            raise TableError(f"table {table.path} holds only the classical V; the filter needs W_eps (solve it "
                             f"without classical_only)")
        if layout not in (None, "stacked", "stencil"):
            raise ValueError(f"layout must be 'stacked', 'stencil' or None, got {layout!r}")
        grid = table.grid("W_eps")
        times = table.times("W_eps")
        if len(times) < 2:
            raise TableError(f"table {table.path} has a single snapshot; the filter needs W_eps over time")
        self.table = table
        self.n = n = len(table.model_metadata["state_names"])  # state axes; the last grid axis is the budget z
        self.dim = grid.ndim
        self.horizon = float(times[-1])
        if layout is None:
            layout = "stacked" if len(times) * int(np.prod(grid.shape)) * (1 + n) * 8 <= max_bytes else "stencil"
        self.layout = layout
        super().__init__(table.values("W_eps"), times, grid, budget_last=True, gradient_axes=range(n),
                         stacked=layout == "stacked")
