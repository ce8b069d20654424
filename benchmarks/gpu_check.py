"""On a GPU: the CUDA kernels (``reach/numerics/gpu.py``) against the CPU loops they share their node code with, and the time
stepping of a large grid alone.

    python benchmarks/gpu_check.py [--paper 300 300 200]

1. Agreement: ``W_eps`` of the point mass and of the glider (WENO5, RK3, float32) marched from ``T`` over a fifth of
   the horizon by the CUDA kernels and by the CPU loops (``reach/numerics/fused.py``); the largest difference of the values,
   relative to their largest magnitude, and how many nodes ``W <= 0`` differ.
2. Stepping: the point mass's ``W_eps`` on the ``--paper`` grid from ``T`` to 0 with the kernels alone (no table, no
   process start): steps, kernel launches per step, milliseconds per step, and the bandwidth of 32 B per node and
   stage against a device-to-device copy.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch

from softreach.reach import Grid, budget_axis, get_model, soft_problem
from softreach.reach.numerics.solver import HamiltonianOperator, SolverSettings, Stepper, march


def _operator(name: str, shape: tuple[int, ...], device: str) -> tuple:
    model = get_model(name)
    z_lo, z_hi, nz = budget_axis(model.horizon, shape[-1])
    grid = Grid(tuple(model.domain[0]) + (z_lo,), tuple(model.domain[1]) + (z_hi,), shape[:-1] + (nz,))
    settings = SolverSettings.from_accuracy("very_high", dtype="float32", device=device)
    return model, HamiltonianOperator(soft_problem(model, 1e-3, model.budget_scale), grid, settings), settings


#: where the kernels run: ``cpu`` only under numba-cuda's simulator (a dry run of this script without a GPU)
DEVICE = os.environ.get("GPU_CHECK_DEVICE", "cuda")


def _sync() -> None:
    if DEVICE != "cpu":
        torch.cuda.synchronize()


def agreement(name: str, shape: tuple[int, ...]) -> None:
    model, gop, gs = _operator(name, shape, DEVICE)
    _, cop, cs = _operator(name, shape, "cpu")
    t0 = time.perf_counter()
    gpu = Stepper(gop, gs, engine="cuda")
    made = time.perf_counter() - t0
    T = model.horizon
    a = march(gpu, T, gop.terminal(T), 0.8 * T).cpu().numpy()
    b = march(Stepper(cop, cs, engine="fused"), T, cop.terminal(T), 0.8 * T).numpy()
    scale = float(np.abs(b).max())
    print(f"{name} {'x'.join(map(str, shape))}: kernels ready in {made:.1f} s; max |gpu - cpu| = "
          f"{float(np.abs(a - b).max()):.3g} ({float(np.abs(a - b).max()) / scale:.2g} of max |W|); nodes W <= 0: "
          f"gpu {int((a <= 0).sum())}, cpu {int((b <= 0).sum())}, differing {int(((a <= 0) != (b <= 0)).sum())}")


def paper(shape: tuple[int, ...], gbs: float) -> None:
    model, op, st = _operator("pointmass", shape, DEVICE)
    stepper = Stepper(op, st, engine="cuda")
    cs = stepper.cuda
    steps = [0]
    original = cs.step

    def counted() -> None:
        steps[0] += 1
        original()

    cs.step = counted
    u = op.terminal(model.horizon)
    _sync()
    before = cs.launches
    t0 = time.perf_counter()
    march(stepper, model.horizon, u, 0.0)
    _sync()
    wall = time.perf_counter() - t0
    n, stages = op.grid.size, len(cs._stages)
    bw = 32 * n * stages * steps[0] / wall / 1e9
    print(f"point mass W_eps {'x'.join(map(str, shape))} ({n:,d} nodes), T -> 0: {steps[0]} steps in {wall:.2f} s, "
          f"{(cs.launches - before) / max(steps[0], 1):.1f} launches a step, {1e3 * wall / max(steps[0], 1):.2f} ms a "
          f"step, {bw:.0f} GB/s = {bw / gbs:.0%} of the device copy")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--paper", type=int, nargs=3, default=[300, 300, 200])
    ap.add_argument("--small", type=int, nargs=7, default=[41, 41, 45, 31, 15, 15, 15],
                    help="the point mass's grid, then the glider's, of the agreement check")
    args = ap.parse_args()
    import importlib.metadata as md

    import numba

    print(f"torch {torch.__version__}, numba {numba.__version__}, numba-cuda {md.version('numba-cuda')}, device "
          f"{torch.cuda.get_device_name(0) if DEVICE != 'cpu' else 'simulated'}", flush=True)
    from bench_solver import device_copy_gbs

    gbs = device_copy_gbs("cuda") if DEVICE != "cpu" else float("nan")
    print(f"device copy: {gbs:.0f} GB/s", flush=True)
    agreement("pointmass", tuple(args.small[:3]))
    agreement("glider", tuple(args.small[3:]))
    paper(tuple(args.paper), gbs)


if __name__ == "__main__":
    main()
