"""The sampled-data game: the control is held for a control period, the disturbance may change at any instant.

A controller that runs at a control period ``dt`` picks an action at ``t_k = k dt`` and holds it until ``t_k+1``;
the wind answers at every instant, knowing the held action. The value of that game at the sample times is

    W_k(x) = min over held actions a of  W^a_k(x),

where ``W^a_k`` solves, over ``[t_k, t_k+1]``, the reach-avoid variational inequality of the *disturbance-only*
game with ``a`` fixed (Hamiltonian ``max_b p . f(t, x, a, b)``), from the terminal value ``W_k+1``. Its zero
sublevel set is what a held-action controller can guarantee; it lies inside the continuous-time set (the control
commits first and cannot react inside a period). The minimum runs over a finite set of candidate actions
(:meth:`FilterPart.held_candidates`), so ``W_k`` is an upper bound of the value over all held actions: a state it
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
