"""The sampled-data game's sub-solves on the compiled loops: the held action is an input of the compiled step
(``HeldControl.kernel_parameters``), so one compiled step serves every candidate; a step that kept the action it
was compiled with would give every candidate the same value."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from softreach.reach import Grid, budget_axis, get_model, soft_problem
from softreach.reach.numerics.held import HeldControl, solve_held
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings, Stepper, march


def _setup():
    m = get_model("pointmass")
    z = budget_axis(m.horizon, 10)
    grid = Grid(tuple(m.domain[0]) + (z[0],), tuple(m.domain[1]) + (z[1],), (17, 15, 10))
    return m, grid, soft_problem(m, 1e-3, m.budget_scale)


def test_held_solve_on_the_compiled_loops_is_the_array_code():
    """Ten periods, four candidates, float64: the compiled loops' value equals the array code's to rounding."""
    m, grid, problem = _setup()
    times = [0.9 + 0.01 * k for k in range(11)]
    controls = np.array([[-20.0], [0.0], [9.8], [20.0]])
    out = {}
    for compiled in (False, True):
        st = SolverSettings.from_accuracy("high", dtype="float64", compile=compiled)
        out[compiled] = np.asarray(solve_held(problem, grid, times, st, controls))
    scale = np.abs(out[False]).max()
    assert np.abs(out[True] - out[False]).max() <= 1e-12 * scale
    assert np.array_equal(out[True] <= 0, out[False] <= 0)


def test_one_compiled_step_reads_each_held_action():
    """Full thrust and full descent held over one period from the same value end apart, on the compiled loops as on
    the array code."""
    m, grid, problem = _setup()
    held = HeldControl(problem.dynamics)
    st = SolverSettings.from_accuracy("high", dtype="float64", compile=True)
    op = HamiltonianOperator(replace(problem, dynamics=held), grid, st)
    held.bind(op.x[0])
    stepper = Stepper(op, st)
    assert stepper.engine == "fused"
    u = op.terminal(1.0)
    ends = []
    for a in ([-20.0], [20.0], [-20.0]):
        held.set_control(a)
        ends.append(np.asarray(march(stepper, 1.0, u, 0.99)).copy())
    assert np.abs(ends[0] - ends[1]).max() > 1e-3
    assert np.array_equal(ends[0], ends[2])
