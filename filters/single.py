"""One plain row of :meth:`~softreach.filters.ValueFilter.filter` (an environment's step) on Python numbers, into
the one-row buffers of :meth:`~softreach.filters.compiled.CompiledDecision.one`, without numpy's per-call costs:
the batched path's outputs bit for bit; other inputs and all error messages stay there (docs/filters.md, 'One row')."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from softreach.reach.proof.blocks import check_threads

from .reasons import AFTER_HORIZON, PASS

_SCALARS = (float, int, np.floating, np.integer)
#: the reason after the horizon as the batched path returns it (a numpy integer)
_AFTER_CODE = np.int64(AFTER_HORIZON)
_ZERO = np.float64(0.0)


def filter_one(vf: Any, t: Any, x: Any, z: Any, action: Any, normalized: bool, plan: Any,
               diagnostics: bool) -> tuple[np.ndarray, dict[str, Any]] | None:
    """``vf.filter(t, x, z, action, normalized=normalized, plan=plan, diagnostics=diagnostics)`` of one plain, finite
    row, or ``None`` for the batched path to decide; ``ValueError`` where ``vf.threads`` is below 1. Plain: numpy
    float ``x`` and ``action`` of one row, real scalar ``t`` and ``z``, no plan or a ``(3,)`` integer one."""
    if not (type(x) is np.ndarray and type(action) is np.ndarray and x.shape == (vf.n,) and action.shape == (vf.m,)
            and x.dtype.kind == "f" and action.dtype.kind == "f" and isinstance(t, _SCALARS)
            and isinstance(z, _SCALARS)
            and (plan is None or (type(plan) is np.ndarray and plan.shape == (3,) and plan.dtype.kind in "iu"))):
        return None
    t, z = float(t), float(z)
    # an infinity or NaN anywhere makes the sum non-finite (a finite row whose sum overflows goes to the batched path)
    if not math.isfinite(t + z + sum(x.tolist()) + sum(action.tolist())):
        return None
    threads = vf.threads
    if type(threads) is not int or threads < 1:
        # one row uses no other thread, but an invalid number is refused as for a batch (after the inputs, as there)
        check_threads(threads)
    row = vf.compiled.one(t, x, z, action, normalized, plan, diagnostics)
    _, reason, value, nxt, ok, _, blend, _ = row.outs
    after = t >= vf.lookahead.horizon - 1e-9
    code = _AFTER_CODE if after else reason[0]
    active = after or code != PASS
    # a passing normalised action as the policy gave it
    out = row.applied0.copy() if active or not normalized else action.astype(np.float64)
    chosen_out = row.chosen0.copy()
    margin = vf.constant_margin
    info = {"value": value[0], "margin": np.float64(margin) if margin else _ZERO,
            "active": np.True_ if active else np.False_, "reason": code, "optimal_action": chosen_out,
            "blend": blend[0], "lookahead": nxt[0], "certified": np.True_ if ok[0] and not after else np.False_,
            "plan": row.new_plan0.copy()}
    return out, info

