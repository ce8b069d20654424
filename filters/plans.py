"""Which landing cells (:mod:`softreach.reach.proof.cell_certificate`) a :class:`~softreach.filters.ValueFilter` uses,
and the plans it follows where no single period ends in them: ``info["plan"]`` = (candidate, periods left, owner), valid
only handed back at its own run's next step, whose state lies in the box chain the plan was proven for."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from softreach.reach.backend import is_torch
from softreach.reach.proof.cell_certificate import CellCertificate, cell_key, cached

#: ``info["plan"]`` where none is followed
NO_PLAN = (-1, 0, 0)
#: following a landing cell's plan (the step is certified: the run lands by ``T``)
PLAN_LAND = 1
#: the owner code of a plan that keeps ``C1`` and the budget without landing, which the filter never follows
PLAN_SAFE = 2
#: a start's own plan holds one candidate, or two in sequence
#: (:meth:`~softreach.filters.compiled.CompiledDecision.start_plans`)
START_SEGMENTS = 2
# what advance_plan returns for no plan: one read-only array, not one made at each step
_NO_PLAN = np.array(NO_PLAN, np.int64)
_NO_PLAN.flags.writeable = False


def resolve_cells(vf: Any, cells: Any) -> CellCertificate:
    """The landing cells a filter uses: ``"auto"``: built (or cached) from the model's ``cell_shape``; a
    :class:`CellCertificate`: checked against the filter. Cells read no table."""
    la = vf.lookahead
    if isinstance(cells, str) and cells == "auto":
        return cached(la, vf.model.cell_shape, holds=vf.model.cell_holds)
    if cells is None:
        raise ValueError("landing_cells must be 'auto' or a CellCertificate, got None: the landing cells are the "
                         "filter's certificate, without them it certifies nothing")
    if not isinstance(cells, CellCertificate):
        raise TypeError(f"landing_cells must be 'auto' or a CellCertificate, got {type(cells).__name__}")
    want = cell_key(la, cells.shape, cells.dz, cells.key.get("holds", (1,)), cells.key.get("span_cap", 32))
    if json.dumps(cells.key, sort_keys=True) != json.dumps(want, sort_keys=True):
        raise ValueError(f"landing_cells built for {cells.key}, not for this filter's {want}")
    return cells


def check_plans(plan: Any, N: int) -> np.ndarray | None:
    """``plan`` as an ``(N, 3)`` int64 array, not copied (the filter only reads it); ``None`` stays ``None``.

    :raises ValueError: not the integer ``(N, 3)`` ``info["plan"]`` of a previous step"""
    if plan is None:
        return None
    arr = np.asarray(plan.detach().cpu().numpy() if is_torch(plan) else plan)
    arr = arr.reshape(N, 3) if arr.size == 3 * N else arr
    if arr.shape != (N, 3) or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"plan must be the integer (N, 3) info['plan'] of the previous step, got {plan!r}")
    return arr.astype(np.int64, copy=False)


def advance_plan(plan: np.ndarray, queued: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The next step's plan and what stays queued, from a step's ``info["plan"]`` and the queued start segment: a
    finished first segment (0 periods left) hands over to the queued one; a dropped plan (:data:`NO_PLAN`) drops it."""
    plan = np.asarray(plan, np.int64).reshape(3)
    if plan[0] < 0:
        return plan, _NO_PLAN
    queued = np.asarray(queued, np.int64).reshape(3)
    if plan[1] == 0 and queued[0] >= 0:
        return queued, _NO_PLAN
    return plan, queued
