"""CPU time of one Runge-Kutta stage of the solver's compiled CPU loops, the point mass's ``W_eps``.

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/stage_time.py [--grid 101 101 --budget-points 111]
        [--accuracy very_high] [--until 0.9]

Marches from ``T`` to ``--until`` after a short warm-up march (compilation and caches out of the way) and prints
the stages it ran, the CPU milliseconds a stage (``time.process_time``, which a loaded machine changes less than the
wall clock) and the wall milliseconds a stage. To compare two versions of the package, run it from each (a frozen
copy on ``PYTHONPATH``) in the same minute.
"""

from __future__ import annotations

import argparse
import os
import time

import softreach
from softreach.reach import Grid, budget_axis, get_model, soft_problem
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings, Stepper, march


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=int, nargs=2, default=[101, 101])
    ap.add_argument("--budget-points", type=int, default=111)
    ap.add_argument("--accuracy", default="very_high", choices=["low", "medium", "high", "very_high"])
    ap.add_argument("--until", type=float, default=0.9, help="the time the march stops at (from T = 1)")
    args = ap.parse_args()
    model = get_model("pointmass")
    z_lo, z_hi, nz = budget_axis(model.horizon, args.budget_points)
    grid = Grid(tuple(model.domain[0]) + (z_lo,), tuple(model.domain[1]) + (z_hi,), tuple(args.grid) + (nz,))
    settings = SolverSettings.from_accuracy(args.accuracy, dtype="float32", device="cpu")
    op = HamiltonianOperator(soft_problem(model, 1e-3, model.budget_scale), grid, settings)
    stepper = Stepper(op, settings, engine="fused")
    u = op.terminal(model.horizon)
    march(stepper, model.horizon, u, model.horizon - 0.01)  # warm-up
    loops = type(stepper.fused)
    stages = [0]
    rate = loops._rate

    def counted(self, *a, **k):
        stages[0] += 1
        return rate(self, *a, **k)

    loops._rate = counted
    cpu, wall = time.process_time(), time.perf_counter()
    march(stepper, model.horizon, u, args.until)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    print(f"softreach from {os.path.dirname(softreach.__file__)}; {args.accuracy}, "
          f"{'x'.join(map(str, grid.shape))}: {stages[0]} stages, {1e3 * cpu / stages[0]:.1f} ms of CPU a stage, "
          f"{1e3 * wall / stages[0]:.1f} ms wall (load {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
