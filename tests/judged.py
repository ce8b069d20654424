"""Every candidate held action judged from each state by the filter's own compiled one-period test
(:func:`softreach.filters.judge.judge`), for tests that ask what a candidate does rather than what the filter
chooses: whether it passes (its end in the landing cells, or every run surely lands at a check instant) and whether
it surely lands."""

from __future__ import annotations

import numpy as np


def candidate_verdicts(vf, t, x, z) -> tuple[np.ndarray, np.ndarray]:
    """``(passes, lands)``, each ``(N, J)``, of every candidate of ``vf`` (a filter with landing cells) from each
    row's state ``x`` at time ``t`` and budget ``z`` (scalars or ``(N,)``)."""
    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import judge

    assert vf.landing_cells is not None, "without cells the table decides whether a candidate passes"
    fast = vf.compiled
    x = np.ascontiguousarray(np.atleast_2d(np.asarray(x, dtype=np.float64)))
    N, J = len(x), len(fast.cands)
    t, z = (np.broadcast_to(np.asarray(v, dtype=np.float64), (N,)) for v in (t, z))
    work = decision_space(vf.n, vf.m, J)[0].work
    lo, hi = np.empty(vf.n), np.empty(vf.n)
    passes, lands = np.zeros((N, J), bool), np.zeros((N, J), bool)
    for r in range(N):
        for j in range(J):
            v = judge(fast.enclose, fast.M, fast.C, float(t[r]), x[r], x[r], float(z[r]), fast.cands[j], lo, hi, work)
            passes[r, j], lands[r, j] = v.ok or v.lands, v.lands
    return passes, lands


def verdict(vf, t, x, z, a):
    """The compiled one-period test's :class:`~softreach.filters.compiled_args.Verdict` of holding ``a`` (``(m,)``,
    physical) from the state ``x`` at time ``t`` and budget ``z``."""
    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import judge

    fast = vf.compiled
    x = np.ascontiguousarray(x, dtype=np.float64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    work = decision_space(vf.n, vf.m, len(fast.cands))[0].work
    lo, hi = np.empty(vf.n), np.empty(vf.n)
    return judge(fast.enclose, fast.M, fast.C, float(t), x, x, float(z), a, lo, hi, work)
