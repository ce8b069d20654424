"""The time-marching solver: pure advection (exact solution), output times, backends, compiled path, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softreach.reach.dynamics import ControlAndDisturbanceAffine
from softreach.reach.numerics.grid import Grid
from softreach.reach.problem import Model, ReachAvoidProblem
from softreach.reach.numerics.solver import SolverSettings, solve


class Advection(Model, ControlAndDisturbanceAffine):
    """``x' = c`` on a periodic line, no inputs that matter (a zero-width control box)."""

    name = "advection"
    state_names = ("x",)
    control_bounds = ((0.0,), (0.0,))
    disturbance_bounds = ((0.0,), (0.0,))
    time_invariant = True

    def __init__(self, c: float = 1.0):
        self.c = c

    def drift(self, t, x):
        return [self.c + 0 * x[0]]

    def control_matrix(self, t, x):
        return [[0]]

    def disturbance_matrix(self, t, x):
        return [[0]]

    def target(self, t, x):  # never binding: the VI reduces to the plain HJ equation
        return 1e6 + 0 * x[0]

    def hard_constraint(self, t, x):
        return -1e6 + 0 * x[0]

    def soft_constraint(self, t, x):
        return -1e6 + 0 * x[0]


def _advect(n, scheme, order, backend="numpy", dtype="float64", T=1.0, compile=False):
    model = Advection(1.0)
    grid = Grid((0.0,), (2 * math.pi,), (n,), periodic=(True,))
    x = grid.axis(0)
    problem = ReachAvoidProblem(dynamics=model, model=model, kind="classical")
    # start from sin(x) at T: replace the terminal condition through a resumed start
    settings = SolverSettings(scheme=scheme, time_order=order, backend=backend, dtype=dtype, cfl=0.5, compile=compile)
    u = solve(problem, grid, [0.0, T], settings, start=(1, np.sin(x)))
    from softreach.reach.backend import to_numpy

    # backward in time with x' = c: W(0, x) = W(T, x + c T)
    return np.abs(to_numpy(u) - np.sin(x + T)).max()


@pytest.mark.parametrize("scheme,order,rate", [("first", 1, 0.8), ("eno2", 2, 1.6), ("weno5", 3, 2.7)])
def test_pure_advection_converges_at_the_scheme_order(scheme, order, rate):
    errors = [_advect(n, scheme, order) for n in (40, 80, 160)]
    rates = [math.log2(a / b) for a, b in zip(errors, errors[1:])]
    assert errors[-1] < 0.05
    assert min(rates) > rate, (errors, rates)


def test_torch_and_numpy_agree():
    a = _advect(64, "weno5", 3, backend="numpy")
    b = _advect(64, "weno5", 3, backend="torch")
    assert abs(a - b) < 1e-10


@pytest.mark.parametrize("fused", [False, True], ids=["rate-compiled", "step-fused"])
def test_compiled_step_matches_eager(fused, monkeypatch):
    """Both compiled paths: the rate alone (small grids), and the whole step fused (``FUSED_STEP_NODES``)."""
    import torch  # noqa: F401
    monkeypatch.setattr("softreach.reach.numerics.solver.FUSED_STEP_NODES", 0 if fused else 10**12)
    monkeypatch.setattr("softreach.reach.numerics.solver.CPU_ENGINE", "compile")
    eager = _advect(48, "eno2", 2, backend="torch", dtype="float32", compile=False)
    compiled = _advect(48, "eno2", 2, backend="torch", dtype="float32", compile=True)
    assert abs(eager - compiled) < 1e-5


def test_steps_land_exactly_on_output_times():
    model = Advection(1.0)
    grid = Grid((0.0,), (2 * math.pi,), (32,), periodic=(True,))
    problem = ReachAvoidProblem(dynamics=model, model=model, kind="classical")
    seen = []
    solve(problem, grid, [0.0, 0.013, 0.5, 0.77, 1.0], SolverSettings(backend="numpy", scheme="first", time_order=1),
          sink=lambda k, t, u: seen.append((k, t)))
    assert seen == [(4, 1.0), (3, 0.77), (2, 0.5), (1, 0.013), (0, 0.0)]


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="cfl"):
        SolverSettings(cfl=1.5)
    with pytest.raises(ValueError, match="time_order"):
        SolverSettings(time_order=4)
    with pytest.raises(ValueError, match="unknown accuracy 'ultra'"):
        SolverSettings.from_accuracy("ultra")
    with pytest.raises(ValueError, match="numpy backend runs on the CPU"):
        SolverSettings(backend="numpy", device="cuda")
    with pytest.raises(ValueError, match="strictly increasing"):
        model = Advection()
        solve(ReachAvoidProblem(model, model, "classical"), Grid((0.0,), (1.0,), (8,)), [1.0, 0.0])


def test_cuda_request_without_a_gpu_is_a_clear_error():
    import torch
    if torch.cuda.is_available():
        pytest.skip("a GPU is present")
    with pytest.raises(RuntimeError, match="no CUDA device"):
        SolverSettings(device="cuda")


def test_grid_validation():
    with pytest.raises(ValueError, match="integer >= 2"):
        Grid((0.0,), (1.0,), (0,))
    with pytest.raises(ValueError, match="lo < hi"):
        Grid((1.0,), (0.0,), (5,))
    with pytest.raises(ValueError, match="1 to 5 dimensions"):
        Grid((0.0,) * 6, (1.0,) * 6, (3,) * 6)
    with pytest.raises(ValueError, match="finite"):
        Grid((0.0,), (float("nan"),), (5,))


@pytest.mark.parametrize("fused", [False, True], ids=["rate-compiled", "step-fused"])
def test_compiled_soft_solve_has_no_graph_break(fused, monkeypatch):
    """A graph break sends every step back to eager Python and recompiles for each new time. The
    graphs are dynamo's, whatever compiles them, so the solve's ``torch.compile`` runs them with dynamo's eager
    backend here (no code generated); :func:`test_compiled_step_matches_eager` runs inductor's code."""
    import functools

    import torch
    monkeypatch.setattr("softreach.reach.numerics.solver.FUSED_STEP_NODES", 0 if fused else 10**12)
    monkeypatch.setattr("softreach.reach.numerics.solver.CPU_ENGINE", "compile")
    monkeypatch.setattr(torch, "compile", functools.partial(torch.compile, backend="eager"))
    from torch._dynamo.utils import counters

    from softreach.reach import budget_axis, get_model, soft_problem

    model = get_model("pointmass")
    z_lo, z_hi, nz = budget_axis(1.0, 23)
    grid = Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), (21, 21, nz))
    torch._dynamo.reset()
    counters.clear()
    solve(soft_problem(model, 1e-3, model.budget_scale), grid, [0.0, 0.03, 0.06],
          SolverSettings.from_accuracy("medium", dtype="float32", compile=True))
    assert not counters["graph_break"], dict(counters["graph_break"])
    assert sum(counters["stats"].get(k, 0) for k in ("unique_graphs",)) <= 2
