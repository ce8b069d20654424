"""The filter's use of the cell certificates (:mod:`softreach.reach.proof.cell_certificate`): which cells a
:class:`~softreach.filters.ValueFilter` uses, and the multi-period plans it follows where no single period ends
in them.

A plan travels with its run as ``info["plan"]``: the candidate index, the periods it is still to be held, and
whose plan it is (:data:`PLAN_LAND` or :data:`PLAN_SAFE`). It is valid only for the run it came from, handed back
at the next step: the state is then inside the box chain the plan was proven for.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from softreach.reach.proof.cell_certificate import CellCertificate, cell_key, cached

try:  # torch is a base dependency, but keep numpy-only use possible
    import torch
except ImportError:  # pragma: no cover - exercised only without torch
    torch = None  # type: ignore[assignment]

#: ``info["plan"]`` where none is followed
NO_PLAN = (-1, 0, 0)
#: following a landing cell's plan (the step is certified: the run lands by ``T``)
PLAN_LAND = 1
#: following a safe cell's plan (``C1`` and the budget are kept; landing is not certified)
PLAN_SAFE = 2


def resolve_cells(vf: Any, cells: Any, game: str) -> CellCertificate | None:
    """The cells a filter uses for ``game``: ``"auto"`` builds them (or reads the cache) from the model's
    ``cell_shape``; ``None`` none (safe cells only: the landing cells are the certificate); a
    :class:`CellCertificate` is checked against the filter (model, period, ``h_eps``, candidates, checks). The cells
    read no table: one solved in continuous time serves as well as one of the sampled-data game."""
    name = "safe_cells" if game == "safe" else "landing_cells"
    la = vf.lookahead
    if isinstance(cells, str) and cells == "auto":
        return cached(la, vf.model.cell_shape, game=game, holds=vf.model.cell_holds)
    if cells is None and game == "safe":
        return None
    if cells is None:
        raise ValueError("landing_cells must be 'auto' or a CellCertificate, got None: the landing cells are the "
                         "filter's certificate, without them it certifies nothing")
    if not isinstance(cells, CellCertificate):
        raise TypeError(f"{name} must be 'auto'{', None' if game == 'safe' else ''} or a CellCertificate, got "
                        f"{type(cells).__name__}")
    if cells.game != game:
        raise ValueError(f"{name} must be cells of the {game!r} game, got {cells.game!r}")
    want = cell_key(la, cells.shape, cells.dz, game, cells.key.get("holds", (1,)), cells.key.get("span_cap", 32))
    if json.dumps(cells.key, sort_keys=True) != json.dumps(want, sort_keys=True):
        raise ValueError(f"{name} built for {cells.key}, not for this filter's {want}")
    return cells


def check_plans(plan: Any, N: int) -> np.ndarray | None:
    """``plan`` as an ``(N, 3)`` int64 array (``None`` stays ``None``).

    :raises ValueError: not the integer ``(N, 3)`` ``info["plan"]`` of a previous step
    """
    if plan is None:
        return None
    arr = np.asarray(plan.detach().cpu().numpy() if torch is not None and isinstance(plan, torch.Tensor) else plan)
    arr = arr.reshape(N, 3) if arr.size == 3 * N else arr
    if arr.shape != (N, 3) or not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"plan must be the integer (N, 3) info['plan'] of the previous step, got {plan!r}")
    # the filter only reads it: a previous step's int64 plan is not copied
    return arr.astype(np.int64, copy=False)


#: a start's own plan holds one candidate, or two in sequence (:func:`start_plans`)
START_SEGMENTS = 2


def start_plans(vf: Any, t: np.ndarray, x: np.ndarray, z: np.ndarray, periods: int,
                second: np.ndarray | None = None) -> np.ndarray:
    """Plans from a start state itself, for starts that neither one period nor their own cell certifies (compiled,
    :mod:`softreach.filters.compiled_starts`): one candidate held for ``K = 2 .. periods`` periods from the state,
    each period keeping ``C1`` and the budget from the box of every state the periods before may have reached and
    the last passing from its whole box, so that the run ends in the landing cells (or has landed); where there is
    none and ``second`` asks for it, two in sequence, at most ``periods`` in all: the first held ``K1`` periods that
    keep ``C1`` and the budget, the second such a one-candidate run from the box of every state the first may have
    reached. The cells' own plans start from a whole cell; these start from the state, and keep what rounding it
    out to its cell loses. A plan is valid only as the first ``plan`` of a run from this state, its second segment
    handed over as the first ends (:func:`advance_plan`).

    :param second: per row, whether to search two segments where one does not do (default: no row)
    :return: ``(N, START_SEGMENTS, 3)``, each segment ``(candidate, periods, PLAN_LAND)`` or :data:`NO_PLAN`: the
        shortest one-segment plan; else the two-segment plan of the shortest first segment, the first candidate among
        those, and the shortest second segment from its box
    """
    N = len(x)
    second = np.zeros(N, bool) if second is None else np.asarray(second, bool)
    if vf.landing_cells is None or periods < 2 or N == 0:
        return np.tile(np.array(NO_PLAN, np.int64), (N, START_SEGMENTS, 1))
    return vf.compiled.start_plans(t, x, z, periods, second, START_SEGMENTS)


def advance_plan(plan: np.ndarray, queued: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The plan to hand to the next step, and what stays queued, from the plan a step returned (``info["plan"]``)
    and the start plan's segment still queued: a first segment that ran its course (its periods left 0) hands
    over to the queued one; a plan the filter dropped (an action passed, :data:`NO_PLAN`) drops it too."""
    plan = np.asarray(plan, np.int64).reshape(3)
    if plan[0] < 0:
        return plan, _NO_PLAN
    queued = np.asarray(queued, np.int64).reshape(3)
    if plan[1] == 0 and queued[0] >= 0:
        return queued, _NO_PLAN
    return plan, queued


# what advance_plan returns for no plan: one read-only array, not one made at each step
_NO_PLAN = np.array(NO_PLAN, np.int64)
_NO_PLAN.flags.writeable = False
