"""The CPU time step as compiled loops (reach/numerics/fused.py) against the array code it is recorded from."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from softreach.reach import Grid, SolverSettings, budget_axis, classical_problem, get_model, soft_problem, solve
from softreach.reach.problem import ReachAvoidProblem
from softreach.reach.numerics.fused import Rows
from softreach.reach.numerics.solver import HamiltonianOperator, Stepper
from softreach.reach.numerics.trace import Tape, Unsupported

import torch


def _soft_grid(n: int = 17, nz: int = 15):
    model = get_model("pointmass")
    z_lo, z_hi, k = budget_axis(model.horizon, nz)
    return model, Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), (n, n, k))


def _solve(problem, grid, times, engine, start=None, **settings):
    """March from ``times[-1]`` (the terminal value, or ``start``) to ``times[0]`` with the stepper's engine forced."""
    from softreach.reach.numerics import solver as S

    st = SolverSettings(**{"dtype": "float64", "compile": True, **settings})
    op = HamiltonianOperator(problem, grid, st)
    stepper = Stepper(op, st, engine=engine)
    assert stepper.engine == engine
    u = op.terminal(times[-1]) if start is None else torch.as_tensor(start, dtype=getattr(torch, st.dtype))
    for a, b in zip(times[::-1], times[-2::-1]):
        u = S.march(stepper, a, u, b)
    return u.numpy() if hasattr(u, "numpy") else np.asarray(u)


@pytest.mark.parametrize("scheme,order,dissipation", [("weno5", 3, "local"), ("weno3", 3, "godunov"),
                                                      ("eno2", 2, "local"), ("weno3", 2, "global"),
                                                      ("first", 1, "local")])
def test_fused_step_is_the_array_step(scheme, order, dissipation):
    """Every scheme, Runge-Kutta order and numerical Hamiltonian, in float64: the loops compute what the array code
    computes, to rounding (the loops multiply differences by 1/dx where the arrays divide by dx, and reorder sums).

    ENO2 with the global dissipation is left out: there its choice of the smaller of two second differences meets
    exact ties ``a = -b`` at the box distances' kinks, where that rounding decides the branch and the node moves by
    ``dt |a| / 2`` (3e-7 at 400 of 4,335 nodes here)."""
    model, grid = _soft_grid()
    problem = soft_problem(model, 1e-3, model.budget_scale)
    kw = dict(scheme=scheme, time_order=order, dissipation=dissipation)
    a = _solve(problem, grid, [0.9, 0.95, 1.0], "eager", **kw)
    b = _solve(problem, grid, [0.9, 0.95, 1.0], "fused", **kw)
    assert np.abs(a - b).max() <= 1e-12 * (1 + np.abs(a).max())


def test_fused_float32_table_has_the_same_sets_within_one_cell():
    """The float32 table (what ``softreach solve`` stores): every z slice's set measure within one cell of the array
    code's, classical V too."""
    model, grid = _soft_grid(21, 17)
    kw = dict(scheme="weno5", time_order=3, dtype="float32")
    for problem, g in ((soft_problem(model, 1e-3, model.budget_scale), grid),
                       (classical_problem(model), Grid(model.domain[0], model.domain[1], (41, 41)))):
        a = _solve(problem, g, [0.7, 1.0], "eager", **kw)
        b = _solve(problem, g, [0.7, 1.0], "fused", **kw)
        assert np.isfinite(b).all()
        axes = tuple(range(2))
        diff = np.abs((a <= 0).sum(axis=axes) - (b <= 0).sum(axis=axes))
        assert diff.max() <= 1, diff


def test_periodic_axis_and_per_end_rules():
    """The glider's 3-D V (sin and cos in its Hamiltonian) and a periodic 1-D advection (wrapped ghosts)."""
    model = get_model("glider")
    lo, hi = model.domain
    grid = Grid(lo, hi, (9, 9, 11), periodic=model.periodic_axes())
    problem = classical_problem(model)
    a = _solve(problem, grid, [model.horizon - 0.05, model.horizon], "eager", scheme="weno5", time_order=3)
    b = _solve(problem, grid, [model.horizon - 0.05, model.horizon], "fused", scheme="weno5", time_order=3)
    assert np.abs(a - b).max() <= 1e-9 * (1 + np.abs(a).max())

    from tests.test_solver import Advection  # noqa: PLC0415 - the 1-D test model lives there

    adv = Advection(1.0)
    g1 = Grid((0.0,), (2 * math.pi,), (40,), periodic=(True,))
    p1 = ReachAvoidProblem(dynamics=adv, model=adv, kind="classical")
    wave = np.sin(g1.axis(0))
    a = _solve(p1, g1, [0.0, 0.5], "eager", start=wave, scheme="weno5", time_order=3)
    b = _solve(p1, g1, [0.0, 0.5], "fused", start=wave, scheme="weno5", time_order=3)
    assert np.abs(a - np.sin(g1.axis(0) + 0.5)).max() < 1e-3  # the exact solution: the loops solve the equation
    assert np.abs(a - b).max() <= 1e-9 * (1 + np.abs(a).max())


def test_the_solve_picks_the_fused_loops_on_a_cpu_and_keeps_each_result():
    """``compile=True`` on a CPU runs the loops; a value ``march`` returns is a copy, not the stepper's buffer,
    which the next march overwrites."""
    from softreach.reach.numerics import solver as S

    model, grid = _soft_grid()
    st = SolverSettings.from_accuracy("medium", compile=True)
    op = HamiltonianOperator(soft_problem(model, 1e-3, model.budget_scale), grid, st)
    stepper = Stepper(op, st)
    assert stepper.engine == "fused"
    u0 = op.terminal(1.0)
    first = S.march(stepper, 1.0, u0, 0.98)
    kept = first.clone()
    S.march(stepper, 1.0, u0, 0.9)
    assert torch.equal(first, kept)


def test_fused_loops_per_step():
    """A step of order k runs k rate loops, k stage loops and k ghost refreshes of each axis: nothing else touches
    the grid."""
    model, grid = _soft_grid()
    st = SolverSettings.from_accuracy("very_high", compile=True)
    op = HamiltonianOperator(soft_problem(model, 1e-3, model.budget_scale), grid, st)
    stepper = Stepper(op, st)
    calls: dict[str, int] = {}
    fs = stepper.fused
    fs.rows = Rows(1)  # one call a loop: with more threads each loop is called once per chunk of rows
    module = fs.kernels

    def counted(name):
        def run(*args):
            kind = name.split("_")[0]
            calls[kind] = calls.get(kind, 0) + 1
            return getattr(module, name)(*args)
        return run

    fs.kernels = SimpleNamespace(**{n: counted(n) for n in dir(module) if n.split("_")[0] in ("rate", "stage", "ghosts")})
    fs.stages = [counted(f.__name__) for f in fs.stages]
    u = op.terminal(1.0)
    r, speed = stepper.rate(1.0, u)
    calls.clear()
    stepper.step(1.0, u, r, 0.1 / speed)
    assert calls == {"rate": 2, "stage": 3, "ghosts": 3 * 3}, calls


def test_unsupported_code_is_refused_and_the_array_code_runs():
    """A Python branch on a node's value cannot be compiled pointwise: the tracer says so, and the solver keeps the
    array code."""
    tape = Tape()
    x = tape.var("x")
    with pytest.raises(Unsupported):
        bool(x > 0)
    with pytest.raises(Unsupported):
        float(x)
    with pytest.raises(Unsupported):
        np.cumsum(x)

    from tests.test_solver import Advection  # noqa: PLC0415

    class Branchy(Advection):
        def hamiltonian(self, t, x, p):
            if (p[0] > 0).all():  # a Python branch on the values
                return p[0] * self.c
            return super().hamiltonian(t, x, p)

    adv = Branchy(1.0)
    grid = Grid((0.0,), (2 * math.pi,), (16,), periodic=(True,))
    st = SolverSettings(scheme="first", time_order=1, compile=True)
    op = HamiltonianOperator(ReachAvoidProblem(dynamics=adv, model=adv, kind="classical"), grid, st)
    assert Stepper(op, st).engine != "fused"
    with pytest.raises(ValueError, match="cannot be compiled pointwise"):
        Stepper(op, st, engine="fused")
