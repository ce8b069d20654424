"""Start states picked from a table's reach-avoid sets, one picker for the plots (``softreach plot --paper-starts``)
and the evaluations (``softreach evaluate --starts paper|inside``).

Membership is the table's one rule: :meth:`~softreach.reach.tables.query.Table.set_mask` at the grid's nodes and
:meth:`~softreach.reach.tables.query.Table.contains` between them (``W_eps(t, x, max(Q, r)) <= 0``, ``r`` half a budget
cell, no margin), so a start drawn here is inside the set that the figures draw.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

#: how deep a representative start lies in its set: among the candidate nodes, those whose ``W_eps`` is at most
#: this fraction of the deepest value (``W`` is negative inside), the highest of them. The glider bounds it from
#: below: the top of its sets is where the 10 s horizon binds, and there the value's margins (speed and
#: flight-path distances) say nothing about time to spare; at 0.7 the default table's ``Q = 10`` start does not
#: land by the horizon under the gradient control, at 0.8-1.0 every start lands (91 x 29 x 31 x 31, very_high).
#: Deeper picks (0.9) put the point mass's starts near the ground, where its deepest values lie.
START_DEPTH = 0.8


def paper_starts(table: Any, budgets: Sequence[float], t: float = 0.0, depth: float = START_DEPTH,
                 panel_axes: Sequence[int] | None = None) -> list[tuple[np.ndarray, float]]:
    """The paper's representative starts (Fig. 1, 5, 6-9): one per budget ``Q``, high up in ``RA~_Q``.

    For each ``Q`` (in increasing order), the candidates are the nodes of ``RA~_Q`` that need that budget: outside
    the previous budget's set as the figure shows it (its projection onto ``panel_axes``, the model's
    :attr:`~softreach.reach.problem.Model.plot_axes` by default, for more than two states), else outside that set,
    else the whole set. Of those, the ones at least ``depth`` times as deep as the deepest (this keeps the start off
    the set's jagged grid boundary), then the largest
    :meth:`~softreach.reach.problem.Model.start_difficulty` (the altitude for the landings), then the deepest.
    The paper picks its points on the sets' boundaries and does not print them; these are comparable and
    reproducible. The start's budget is ``Q`` itself.

    :return: ``[(x, Q), ...]`` for the budgets whose set is not empty
    """
    if not table.has_budget:
        raise ValueError(f"table {table.path} has no W_eps; representative starts need it")
    model = table.model
    axes = table.state_axes("W_eps")
    n = len(axes)
    grids = np.meshgrid(*axes, indexing="ij")
    difficulty = np.broadcast_to(np.asarray(model.start_difficulty(grids), dtype=np.float64), grids[0].shape)
    shown = tuple(panel_axes if panel_axes is not None else model.plot_axes) if n > 2 else tuple(range(n))
    hidden = tuple(i for i in range(n) if i not in shown)
    out = []
    prev = None
    for q in sorted(float(b) for b in budgets):
        mask = table.set_mask(t, q)
        if not mask.any():
            prev = mask
            continue
        cand = mask
        if prev is not None:
            for needs in (mask & ~prev.any(axis=hidden, keepdims=True), mask & ~prev):
                if needs.any():
                    cand = needs
                    break
        w = table.slice("W_eps", t, max(q, table.budget_resolution))
        floor = float(np.where(cand, w, np.inf).min())
        deep = cand & (w <= depth * floor) if floor < 0 else cand
        idx = np.argwhere(deep)
        score = difficulty[tuple(idx.T)]
        idx = idx[score == score.max()]
        best = idx[np.argmin(w[tuple(idx.T)])]
        out.append((np.array([axes[d][best[d]] for d in range(n)]), q))
        prev = mask
    return out


def sample_inside(table: Any, q: float, rng: np.random.Generator, t: float = 0.0, tries: int = 100) -> np.ndarray:
    """A random state of ``RA~_Q`` at time ``t``.

    A node of :meth:`Table.set_mask` is drawn uniformly and moved uniformly within half a grid cell; the move is
    kept if the state is still in the set (:meth:`Table.contains`), else another draw is made (after ``tries``
    rejections the node itself, which is in the set by definition).

    :raises ValueError: when ``RA~_Q`` is empty on the table's grid
    """
    mask = table.set_mask(t, float(q))
    nodes = np.argwhere(mask)
    if len(nodes) == 0:
        raise ValueError(f"RA~_Q is empty for Q={q:g} at t={t:g} in table {table.path}; no 'inside' start exists")
    axes = table.state_axes("W_eps")
    h = np.array([a[1] - a[0] for a in axes])
    node = None
    for _ in range(tries):
        idx = nodes[rng.integers(len(nodes))]
        node = np.array([axes[d][idx[d]] for d in range(len(axes))])
        x = node + rng.uniform(-0.5, 0.5, size=len(h)) * h
        if bool(table.contains(t, x, float(q))[0]):
            return x
    return node
