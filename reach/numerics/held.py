"""The sampled-data game: the control is held for a control period, the disturbance may change at any instant.

A controller that runs at a control period ``dt`` picks an action at ``t_k = k dt`` and holds it until ``t_k+1``;
the wind answers at every instant, knowing the held action. The value of that game at the sample times is

    W_k(x) = min over held actions a of  W^a_k(x),

where ``W^a_k`` solves, over ``[t_k, t_k+1]``, the reach-avoid variational inequality of the *disturbance-only*
game with ``a`` fixed (Hamiltonian ``max_b p . f(t, x, a, b)``), from the terminal value ``W_k+1``. Its zero
sublevel set is what a held-action controller can guarantee; it lies inside the continuous-time set (the control
commits first and cannot react inside a period). The minimum runs over a finite set of candidate actions
(:meth:`Dynamics.held_candidates`), so ``W_k`` is an upper bound of the value over all held actions: a state it
certifies is certified by one of those candidates.

Every sub-solve uses the same schemes, dissipation and projection as the continuous solve
(:func:`softreach.reach.numerics.solver.march`); only the Hamiltonian changes. The candidate action is an input of
the compiled step (:meth:`HeldControl.kernel_parameters`), or lives in 0-d tensors overwritten in place for
``torch.compile``, so one compiled step serves every candidate and every period.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from .. import backend as B
from ..dynamics import Dynamics
from .grid import Grid
from ..problem import ReachAvoidProblem
from .solver import HamiltonianOperator, SnapshotSink, SolverSettings, Stepper, initial_value, march, output_times


def best_candidate(la: Any, t: np.ndarray, x: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The filter's own compiled one-period test from each state (:func:`softreach.filters.compiled.
    best_candidate`): ``(the best candidate passes, its worst next certificate)``."""
    from softreach.filters.compiled import best_candidate as compiled_best

    return compiled_best(la, t, x, z)


class HeldControl(Dynamics):
    """``x' = f(t, x, a, b)`` with the control ``a`` fixed: the one-player game of the disturbance.

    Needs ``f`` affine in ``b`` (both built-in models are: the wind adds a force), so that
    ``max_b p . f = p . f(b_c) + sum_k |p . E_k| r_k`` with ``b_c`` the disturbance box's centre, ``r_k`` its
    half-widths and ``E_k = (f(b_c + r_k e_k) - f(b_c)) / r_k`` its columns, all from ``f`` itself.

    :param dynamics: the game's dynamics (a model, or a model augmented with the budget)
    """

    def __init__(self, dynamics: Dynamics):
        self.inner = dynamics
        self.name = f"{dynamics.name}|held"
        self.state_names = dynamics.state_names
        self.state_units = getattr(dynamics, "state_units", ())
        self.control_bounds = dynamics.control_bounds
        self.disturbance_bounds = dynamics.disturbance_bounds
        lo, hi = (np.asarray(v, dtype=np.float64) for v in dynamics.disturbance_bounds)
        self._b_mid, self._b_rad = 0.5 * (lo + hi), 0.5 * (hi - lo)
        self._a: list[Any] = [float(v) for v in np.asarray(dynamics.control_bounds[0])]

    def bind(self, like: Any) -> None:
        """Keep the held action in 0-d tensors on ``like``'s device (torch), so that compiled steps read it."""
        if B.torch is not None and isinstance(like, B.torch.Tensor):
            self._a = [B.torch.tensor(float(v), dtype=like.dtype, device=like.device) for v in self._a]

    def set_control(self, a: Sequence[float]) -> None:
        """Hold ``a`` (physical units) from now on; tensors are overwritten in place (no recompilation)."""
        if len(a) != len(self._a):
            raise ValueError(f"a held control has {len(self._a)} components, got {list(a)!r}")
        for i, v in enumerate(a):
            if hasattr(self._a[i], "fill_"):
                self._a[i].fill_(float(v))
            else:
                self._a[i] = float(v)

    def kernel_parameters(self) -> list[float]:
        """The held action: compiled steps (:mod:`softreach.reach.numerics.fused`,
        :mod:`softreach.reach.numerics.gpu`) read it at every call, so that one compiled step serves every candidate."""
        return [float(v) for v in self._a]

    @contextlib.contextmanager
    def parameters_as(self, values: Sequence[Any]):
        """Hold ``values`` (the compiled step's placeholders for :meth:`kernel_parameters`) while its code is
        recorded."""
        saved, self._a = self._a, list(values)
        try:
            yield
        finally:
            self._a = saved

    def _columns(self, t, x):
        b = [float(v) for v in self._b_mid]
        fc = self.inner.f(t, x, self._a, b)
        cols = []
        for k, r in enumerate(self._b_rad):
            if r == 0:
                continue
            bk = list(b)
            bk[k] = b[k] + float(r)
            fk = self.inner.f(t, x, self._a, bk)
            cols.append([(fi - ci) for fi, ci in zip(fk, fc)])  # E_k r_k
        return fc, cols

    def f(self, t, x, a, b):
        return self.inner.f(t, x, self._a, b)

    def running_cost(self, t, x):
        return self.inner.running_cost(t, x)

    def hamiltonian(self, t, x, p):
        fc, cols = self._columns(t, x)
        h: Any = sum(pi * fi for pi, fi in zip(p, fc))
        for col in cols:
            s = sum(pi * ei for pi, ei in zip(p, col))
            h = h + abs(s)
        cost = self.inner.running_cost(t, x)
        return h if cost is None else h + cost

    def optimal_control(self, t, x, p):
        return list(self._a)

    def worst_disturbance(self, t, x, p):
        fc, cols = self._columns(t, x)
        out = []
        for k, col in enumerate(cols):
            s = sum(pi * ei for pi, ei in zip(p, col))
            out.append(self._b_mid[k] + self._b_rad[k] * B.where(s >= 0, 1.0 + 0 * s, -1.0 + 0 * s))
        return out

    def dissipation(self, t, x, p_lo=None, p_hi=None):
        fc, cols = self._columns(t, x)
        out = []
        for i, fi in enumerate(fc):
            a = abs(fi)
            for col in cols:
                a = a + abs(col[i])
            out.append(a)
        return out


def solve_held(problem: ReachAvoidProblem, grid: Grid, times: Sequence[float], settings: SolverSettings,
               controls: np.ndarray, *, sink: SnapshotSink | None = None, start: tuple[int, Any] | None = None,
               progress: Any = None) -> Any:
    """March the sampled-data value backwards over the sample times ``times`` (one control period apart).

    :param problem: the reach-avoid problem (classical or soft); its dynamics must be affine in the disturbance
    :param grid: its grid
    :param times: the sample times ``t_0 < ... < t_N = T``
    :param settings: numerical settings (the same as the continuous solve)
    :param controls: ``(J, m)`` candidate held actions
    :param sink: ``sink(k, t_k, W_k)`` for every sample time, from the last
    :param start: ``(k, W_k)`` to resume from
    :param progress: optional tqdm-like object, advanced in model seconds
    :return: the value at ``times[0]``
    """
    times = output_times(times)
    controls = np.asarray(controls, dtype=np.float64)
    if controls.ndim != 2 or controls.shape[1] != problem.dynamics.control_dim or not np.isfinite(controls).all():
        raise ValueError(f"controls must be finite with shape (J, {problem.dynamics.control_dim}), got {controls.shape}")
    held = HeldControl(problem.dynamics)
    op = HamiltonianOperator(replace(problem, dynamics=held), grid, settings)
    held.bind(op.x[0])
    # hundreds of short marches (a period per candidate): compiled steps pay off on every grid here, where the
    # continuous solve leaves small grids to the array code (solver.FUSED_MIN_NODES)
    stepper = Stepper(op, settings if settings.compile is not None else replace(settings, compile=True))
    k0, u = initial_value(op, times, start, sink)
    for k in range(k0 - 1, -1, -1):
        best = None
        for a in controls:
            held.set_control(a)
            w = march(stepper, times[k + 1], u, times[k])
            best = w if best is None else B.minimum(best, w)
        u = best
        if progress is not None:
            progress.update(max(0.0, min(times[-1] - times[k], progress.total or math.inf) - progress.n))
        if sink is not None:
            sink(k, times[k], u)
    return u


def make_consistent(model: Any, fields: dict[str, tuple[Any, list[float], Grid]], dt: float, eps: float,
                    controls: np.ndarray, band: float, progress: Any = None, cap: float | None = None
                    ) -> dict[str, Any]:
    """Raise node values of the sampled-data table where the filter's one-period test disagrees with the PDE.

    The PDE sub-solves and the filter's test (:class:`~softreach.reach.proof.lookahead.Lookahead`: exact enclosures of
    the held period, the exact maximum of the interpolant over them, the budget bound) approximate the same
    minimum over held actions with different errors; where the PDE is the lower one, a state the table
    certifies can have no action that passes the test (a dead end). Backwards from the horizon, every node with
    a value in ``[-band, 0]`` gets ``max(value, min_a test(node, a))`` against the already consistent next
    snapshot (``V`` nodes at ``z = 0``), capped at ``band`` where no action passes; nodes in the target have
    landed and keep their value. Values only rise: the sets
    only shrink, and at every node the table now promises nothing the test cannot deliver.

    :param fields: ``{"V": (values, times, grid), "W_eps": (...)}``, values writable ``(n_t, *grid)``
    :param band: depth below 0 that is checked (nodes deeper are counted, not changed: see the return); a
        ``Q_min`` field is checked at every node that some budget makes feasible
    :param cap: ``Q_min``'s value where no budget suffices (:class:`~softreach.reach.numerics.budget_surface.BudgetSurfaceProblem`)
    :return: statistics per field: nodes checked and raised, dead ends, the largest raise, and of a sample of
        64 deeper nodes per snapshot how many have no action that passes the test (``deep_inconsistent``,
        expected 0: the band is deep enough)
    """
    from ..proof.lookahead import Lookahead

    stats = {name: {"checked": 0, "raised": 0, "dead_ends": 0, "largest_raise": 0.0, "deep_sampled": 0,
                    "deep_inconsistent": 0} for name in ("V", "W_eps", "Q_min") if name in fields}
    rng = np.random.default_rng(0)
    times = fields["W_eps" if "W_eps" in fields else "Q_min"][1]
    for k in range(len(times) - 2, -1, -1):
        nxt = {name: (vals[k + 1:k + 2], np.asarray(tt[k + 1:k + 2]), g) for name, (vals, tt, g) in fields.items()}
        la = Lookahead(nxt, model, dt, eps, controls, target_checks=model.substeps)
        if "Q_min" in fields:
            if cap is None:
                raise ValueError("a Q_min field needs cap, the value that says no budget suffices")
            _consistent_budget_surface(la, model, fields["Q_min"], k, times, stats["Q_min"], cap)
        for name, (vals, _, grid) in ((n, fields[n]) for n in ("V", "W_eps") if n in fields):
            cur = np.asarray(vals[k], dtype=np.float64)
            # nodes deeper than the band are assumed consistent; a sample of them checks that assumption
            deep = np.flatnonzero(cur < -band)
            deep = np.unravel_index(rng.choice(deep, size=min(64, len(deep)), replace=False), cur.shape)
            idx = np.nonzero((cur <= 0) & (cur >= -band))
            idx = tuple(np.concatenate([i, d]) for i, d in zip(idx, deep))
            n_deep = len(deep[0])
            if len(idx[0]) == 0:
                continue
            pts = np.stack([np.asarray(grid.lo[a]) + idx[a] * grid.spacing[a] for a in range(grid.ndim)], axis=1)
            n = model.state_dim
            x = pts[:, :n]
            z = pts[:, n] if name == "W_eps" else np.zeros(len(pts))
            # a node in the target (inside C2 and C1) has landed: the episode ends there, no action is needed
            keep = ~(np.asarray(model.landed(times[k], [x[:, i] for i in range(n)])) & (z >= 0))
            is_deep = (np.arange(len(x)) >= len(x) - n_deep)[keep]
            idx = tuple(i[keep] for i in idx)
            x, z = x[keep], z[keep]
            if len(x) == 0:
                continue
            ok, best = best_candidate(la, np.full(len(x), times[k]), x, np.maximum(z, 0.0))
            score = np.where(ok, best, np.inf)
            # below z = 0 the budget is already overspent: nothing there is certified by the test
            score = np.where(z < 0, np.inf, score)
            new = np.maximum(cur[idx], np.minimum(score, band))
            raised = (new > cur[idx]) & ~is_deep
            s = stats[name]
            s["deep_sampled"] += int(is_deep.sum())
            s["deep_inconsistent"] += int(((score > 0) & is_deep).sum())
            new = np.where(is_deep, cur[idx], new)
            s["checked"] += int(len(x) - is_deep.sum())
            s["raised"] += int(raised.sum())
            s["dead_ends"] += int((~np.isfinite(score) & ~is_deep).sum())
            if raised.any():
                s["largest_raise"] = max(s["largest_raise"], float((new - cur[idx])[raised].max()))
                cur[idx] = new
                vals[k] = cur.astype(vals.dtype)
        if progress is not None:
            progress.update(1)
    return stats


def consistency_gaps(model: Any, fields: dict[str, tuple[Any, list[float], Grid]], dt: float, eps: float,
                     controls: np.ndarray, samples: int = 20000, seed: int = 0) -> dict[str, Any]:
    """How far the interpolated certificate promises more than the best held action delivers, between nodes.

    At each sample time ``t_k``, for ``samples`` uniform states of the grid box with ``D_k <= 0`` (not landed),
    the *gap* ``min_a test(x, a) - D_k(x)`` (:class:`~softreach.reach.proof.lookahead.Lookahead`): where it is positive
    the best action ends slightly shallower than where it started, and a state riding the set's boundary can
    reach a dead end (no action passes). :func:`make_consistent` removes the gap at the nodes; this measures
    what remains in between.

    :return: ``{"max_gap": [...], "p99_gap": [...], "dead_ends": [...], "sampled": [...]}`` per sample time
    """
    from ..proof.lookahead import Lookahead

    rng = np.random.default_rng(seed)
    n = model.state_dim
    if "W_eps" in fields:
        _, Wt, Wg = fields["W_eps"]
        lo, hi = np.asarray(Wg.lo), np.asarray(Wg.hi)
    else:  # a budget surface: budgets up to the horizon (no run spends more)
        _, Wt, Qg = fields["Q_min"]
        lo, hi = np.append(Qg.lo, 0.0), np.append(Qg.hi, float(Wt[-1]))
    out: dict[str, list] = {"max_gap": [], "p99_gap": [], "dead_ends": [], "sampled": []}
    for k in range(len(Wt) - 1):
        now = {name: (vals[k:k + 2], np.asarray(tt[k:k + 2]), g) for name, (vals, tt, g) in fields.items()}
        la = Lookahead(now, model, dt, eps, controls, target_checks=model.substeps)
        pts = rng.uniform(np.append(lo[:n], max(0.0, lo[-1])), hi, size=(samples, n + 1))
        x, z = pts[:, :n], pts[:, n]
        t = np.full(samples, float(Wt[k]))
        d = la.certificate(t, x, z)
        keep = (d <= 0) & ~np.asarray(model.landed(t[0], [x[:, i] for i in range(n)]))
        x, z, d = x[keep], z[keep], d[keep]
        ok, best = best_candidate(la, t[: len(x)], x, z)
        score = np.where(ok, best, np.inf)
        finite = np.isfinite(score)
        gap = score[finite] - d[finite]
        out["max_gap"].append(float(gap.max()) if len(gap) else 0.0)
        out["p99_gap"].append(float(np.quantile(gap, 0.99)) if len(gap) else 0.0)
        out["dead_ends"].append(int((~finite).sum()))
        out["sampled"].append(int(len(x)))
    return out


def _consistent_budget_surface(la: Any, model: Any, field: tuple[Any, Any, Grid], k: int, times: Sequence[float],
                               stats: dict[str, Any], cap: float, iterations: int = 12) -> None:
    """:func:`make_consistent` for a ``Q_min`` snapshot: every node that some budget up to the time left makes
    feasible gets at least the smallest budget with which a held action passes the test from it (found by
    bisection: passing only gets easier with more budget), and the cap where none does. Values only rise.

    :param la: the test against the already consistent next snapshot
    :param field: ``(values, times, grid)`` of ``Q_min``, values writable
    :param cap: the value that says no budget suffices
    :param iterations: bisection steps; the budget found passes, so it errs upwards by at most
        ``(T - t_k) / 2^iterations``
    """
    vals, _, grid = field
    cur = np.asarray(vals[k], dtype=np.float64)
    left = float(times[-1] - times[k])
    idx = np.nonzero(cur <= left + 1e-9)
    if len(idx[0]) == 0:
        return
    x = np.stack([np.asarray(grid.lo[a]) + idx[a] * grid.spacing[a] for a in range(grid.ndim)], axis=1)
    n = model.state_dim
    keep = ~np.asarray(model.landed(times[k], [x[:, i] for i in range(n)]))
    idx = tuple(i[keep] for i in idx)
    x = x[keep]
    if len(x) == 0:
        return
    t = np.full(len(x), float(times[k]))

    def passes(z: np.ndarray) -> np.ndarray:
        return best_candidate(la, t, x, z)[0]

    hi = np.full(len(x), left)
    feasible = passes(hi)
    lo = np.minimum(np.maximum(cur[idx], 0.0), left)
    at_lo = passes(lo) & feasible
    hi = np.where(at_lo, lo, hi)
    todo = feasible & ~at_lo
    for _ in range(iterations):
        if not todo.any():
            break
        mid = 0.5 * (lo + hi)
        ok = passes(mid)
        hi = np.where(todo & ok, mid, hi)
        lo = np.where(todo & ~ok, mid, lo)
    new = np.maximum(cur[idx], np.where(feasible, hi, cap))
    raised = new > cur[idx]
    stats["checked"] += int(len(x))
    stats["raised"] += int(raised.sum())
    stats["dead_ends"] += int((~feasible).sum())
    finite = raised & feasible
    if finite.any():
        stats["largest_raise"] = max(stats["largest_raise"], float((new - cur[idx])[finite].max()))
    if raised.any():
        cur[idx] = new
        vals[k] = cur.astype(vals.dtype)
