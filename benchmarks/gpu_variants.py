"""On a GPU: where the time of a CUDA step goes, and what the kernels' variants would change.

    python benchmarks/gpu_variants.py [--paper 300 300 200] [--steps 40]

For each variant of the generated kernels (:func:`softreach.reach.numerics.gpu.kernel_source`, rewritten as text
here; the library is not changed): the agreement with the CPU loops on a small grid (as ``gpu_check.py``), then on
the ``--paper`` grid the milliseconds of one step and of each kernel alone (CUDA events, the mean over
``--steps`` launches after warm-up). Variants:

- ``base``: the kernels as the library writes them;
- ``constmul``: a division by a constant ``x / F(c)`` written as the product ``x * F(1/c)`` (one rounding more);
- ``fastdiv``: ``constmul``, and the other divisions by ``libdevice.fast_fdividef`` (approximate);
- ``fastmath``: numba-cuda's ``fastmath=True`` on every kernel (flush to zero, approximate division, and LLVM's
  fast flags, which let it drop the kernels' non-finite checks: an upper bound only);
- ``block128`` / ``block512``: 128 or 512 threads a block instead of 256.
"""

from __future__ import annotations

import argparse
import re
import time

import numpy as np
import torch

import gpu_check
from softreach.reach.numerics import gpu
from softreach.reach.numerics.solver import Stepper

BASE_SOURCE = gpu.kernel_source
BASE_BLOCK = gpu.BLOCK


def _constmul(src: str) -> str:
    def inverse(m: re.Match) -> str:
        return f"({m.group(1)} * F({1.0 / float(m.group(2))!r}))"

    return re.sub(r"\((\w+) / F\(([0-9.eE+-]+)\)\)", inverse, src)


def _fastdiv(src: str) -> str:
    src = _constmul(src).replace("from numba import cuda", "from numba import cuda\nfrom numba.cuda import libdevice")
    # the node code's float32 lines only (``tN = (a / b)``), not the clock's float64 arithmetic
    return re.sub(r"^(\s+t\d+ = )\(((?:F\([^()]*\))|\w+) / (\w+)\)$", r"\1libdevice.fast_fdividef(\2, \3)", src,
                  flags=re.M)


VARIANTS = {
    "base": (lambda s: s, BASE_BLOCK),
    "constmul": (_constmul, BASE_BLOCK),
    "fastdiv": (_fastdiv, BASE_BLOCK),
    "fastmath": (lambda s: s.replace("_JIT = dict(cache=True)", "_JIT = dict(cache=True, fastmath=True)"), BASE_BLOCK),
    "block128": (lambda s: s, 128),
    "block512": (lambda s: s, 512),
}


def use(name: str) -> None:
    rewrite, block = VARIANTS[name]
    gpu.kernel_source = lambda op, dtype: rewrite(BASE_SOURCE(op, dtype))
    gpu.BLOCK = block


def _events_ms(fn, n: int) -> float:
    a, b = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    for _ in range(3):
        fn()
    a.record()
    for _ in range(n):
        fn()
    b.record()
    torch.cuda.synchronize()
    return a.elapsed_time(b) / n


def timings(shape: tuple[int, ...], steps: int) -> str:
    model, op, st = gpu_check._operator("pointmass", shape, "cuda")
    cs = Stepper(op, st, engine="cuda").cuda
    cs._load(op.terminal(model.horizon))
    cs.t.fill_(model.horizon)
    cs.target.fill_(0.0)
    step = _events_ms(cs.step, steps)
    rate = _events_ms(lambda: cs._rate(*cs._rate_args, 1), steps)
    stage = _events_ms(lambda: cs._stages[0](*cs._stage_args, False), steps)
    ghosts = _events_ms(lambda: cs._ghosts(cs._up), steps)
    clock = _events_ms(lambda: cs._clock(*cs._clock_args), steps)
    return (f"step {step:.3f} ms, rate {rate:.3f}, stage {stage:.3f}, ghosts {ghosts:.3f}, clock {clock:.3f} ms; "
            f"{op.grid.size / rate / 1e6:.2f} G nodes/s in the rate")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--paper", type=int, nargs=3, default=[300, 300, 200])
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS))
    args = ap.parse_args()
    print(f"device {torch.cuda.get_device_name(0)}, torch {torch.__version__}", flush=True)
    for name in args.variants:
        use(name)
        t0 = time.perf_counter()
        try:
            print(f"--- {name}", flush=True)
            gpu_check.agreement("pointmass", (41, 41, 45))
            print(f"{name}: {timings(tuple(args.paper), args.steps)} ({time.perf_counter() - t0:.1f} s)", flush=True)
        except Exception as exc:  # a variant that does not compile says so and the others go on
            print(f"{name}: failed: {type(exc).__name__}: {str(exc)[:400]}", flush=True)
    np.set_printoptions(precision=3)


if __name__ == "__main__":
    main()
