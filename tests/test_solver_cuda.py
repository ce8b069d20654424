"""The GPU's time step (reach/numerics/gpu.py) checked without a GPU, in numba-cuda's simulator: the same values as the CPU
loops it shares its node code with, the host loop's steps, a fixed number of kernel launches per step and one read of
the device per batch of steps.

The simulator is switched on by ``NUMBA_ENABLE_CUDASIM=1`` before numba is imported, so the checks run in a fresh
interpreter (the ``simulated`` fixture)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from shared_tables import lock, run_root

pytestmark = pytest.mark.process

_PRELUDE = '''
import json, math, sys
# the simulator runs each GPU thread as a Python thread and waits for them by polling: at the interpreter's default
# switch interval (5 ms) the polling thread keeps the GIL that long each time a simulated thread is to run
sys.setswitchinterval(1e-4)
import numpy as np
from softreach.reach import Grid, budget_axis, classical_problem, get_model, soft_problem
from softreach.reach.numerics import device_loop, fused
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings, Stepper, march

def operator(problem, grid, **kw):
    st = SolverSettings(**{"dtype": "float32", **kw})
    return HamiltonianOperator(problem, grid, st), st

def both(problem, grid, t, target, start=None, **kw):
    """(cuda values, fused values, cuda stepper, host-loop steps, device reads)"""
    op, st = operator(problem, grid, **kw)
    u = op.terminal(t) if start is None else start
    gpu = Stepper(op, st, engine="cuda")
    reads = []
    original = device_loop.march_in_batches
    def counting(advance, *a, **k):
        def counted(n):
            reads.append(n)
            return advance(n)
        return original(counted, *a, **k)
    device_loop.march_in_batches = counting
    launches = gpu.cuda.launches
    a = march(gpu, t, u, target).numpy()
    device_loop.march_in_batches = original
    cpu = Stepper(op, st, engine="fused")
    steps = []
    step = cpu.fused.step
    cpu.fused.step = lambda *x: (steps.append(1), step(*x))[1]
    b = march(cpu, t, u, target).numpy()
    return a, b, gpu.cuda.launches - launches, len(steps), reads
'''


_CASES = '''
out = {}
m = get_model("pointmass")
z = budget_axis(m.horizon, 8)
g = Grid(tuple(m.domain[0]) + (z[0],), tuple(m.domain[1]) + (z[1],), (7, 6, 5))
a, b, launches, steps, reads = both(soft_problem(m, 1e-3, m.budget_scale), g, 1.0, 0.94, scheme="weno5")
out["weno5"] = {"diff": float(np.abs(a - b).max()), "scale": float(np.abs(b).max()), "launches": launches,
                "steps": steps, "reads": reads}

d = get_model("dubins")
g = Grid(tuple(d.domain[0]), tuple(d.domain[1]), (6, 5, 7), periodic=d.periodic_axes())
a, b, launches, steps, reads = both(classical_problem(d), g, d.horizon, d.horizon - 0.05, scheme="eno2",
                                   time_order=2)
out["periodic"] = {"periodic": list(g.periodic), "diff": float(np.abs(a - b).max()),
                   "scale": float(np.abs(b).max()), "launches": launches, "steps": steps}

g = Grid(tuple(m.domain[0]), tuple(m.domain[1]), (9, 8))
op, st = operator(classical_problem(m), g, scheme="first", time_order=1)
gpu = Stepper(op, st, engine="cuda")
u = op.terminal(1.0).clone()
u[4, 4] = float("nan")
try:
    march(gpu, 1.0, u, 0.9)
    out["nan"] = None
except FloatingPointError as exc:
    out["nan"] = str(exc)
print(json.dumps(out))
'''


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> dict:
    """The three cases below, run once per test run (the workers of ``pytest -n`` share the result) in a fresh
    interpreter with numba-cuda's simulator switched on."""
    path = run_root(tmp_path_factory) / "cuda_simulated.json"
    with lock(path):
        if not path.exists():
            env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "OMP_NUM_THREADS": "1"}
            r = subprocess.run([sys.executable, "-c", _PRELUDE + _CASES], capture_output=True, text=True, env=env,
                               timeout=600)
            assert r.returncode == 0, r.stderr[-4000:]
            path.write_text(r.stdout.strip().splitlines()[-1])
    return json.loads(path.read_text())


def test_cuda_kernels_march_the_point_mass_as_the_cpu_loops(simulated):
    """``W_eps`` (WENO5, RK3, float32) on a grid whose axes differ in length, so that a transposed index or a wrong
    ghost layer shows: every value equal to the CPU loops' (the simulator rounds as they do), the host loop's number
    of steps, ten launches a step (three rates, the clock, three stages, three ghost refreshes) and at most three
    reads of the device for the whole march."""
    out = simulated["weno5"]
    assert out["scale"] > 1.0
    assert out["diff"] == 0.0
    assert out["steps"] >= 2
    assert sum(out["reads"]) == out["steps"]
    assert len(out["reads"]) <= 3
    # the load's ghost refresh, then ten a step
    assert out["launches"] == 1 + 10 * out["steps"]


def test_cuda_kernels_on_a_periodic_axis_and_two_stage_scheme(simulated):
    """A periodic angle (the Dubins car's ``V``, ENO2/RK2): the ghost kernel wraps the angle and extrapolates the
    other axes; the values agree with the CPU loops to float32 rounding (``math.cos`` runs in double precision in
    the simulator, ``np.cos`` in single on the CPU), and a RK2 step is seven launches."""
    out = simulated["periodic"]
    assert out["periodic"][-1]
    assert out["diff"] <= 1e-5 * out["scale"]
    assert out["launches"] == 1 + 7 * out["steps"]


def test_cuda_march_raises_on_a_value_that_is_not_finite(simulated):
    """A NaN in the value makes the speed infinite on the device; the batch's read raises, naming the times."""
    assert simulated["nan"] is not None and "not finite" in simulated["nan"]
