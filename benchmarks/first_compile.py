"""How long the one-time compilations take on a machine that has not compiled yet: the numbers behind the notices
``softreach solve`` (``reach.numerics.compute.COLD_COMPILE_S``) and the first filtered decision
(``agents.envs.FILTER_COMPILE_S``) print.

    OMP_NUM_THREADS=1 python benchmarks/first_compile.py torch    # the solver's torch.compile, empty cache
    OMP_NUM_THREADS=1 python benchmarks/first_compile.py filter TABLE   # softreach compile TABLE, empty cache

``torch``: ``softreach solve pointmass`` (its default grid) with the ``torch.compile`` engine (the GPU's, and a CPU's
for a model whose step cannot be compiled pointwise) and an empty ``TORCHINDUCTOR_CACHE_DIR``; the time between
dynamo's first compile start and its last compile end. ``filter``: ``softreach compile TABLE`` (a ``--held``
table) with an empty ``NUMBA_CACHE_DIR``. Each prints wall and CPU seconds (this process and its finished
children) and the load average, since wall time on a shared machine depends on what else runs.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time


def _cpu() -> float:
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def torch_compile() -> None:
    cache = tempfile.mkdtemp(prefix="inductor-cold-")
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache
    os.environ["TORCHINDUCTOR_COMPILE_THREADS"] = "1"  # compile in this process: its CPU time is counted
    from torch._dynamo.callback import callback_handler

    from softreach.reach.numerics import solver
    from softreach.reach.cli.commands import run_solve
    from softreach.cli import build_parser

    solver.CPU_ENGINE = "compile"
    marks: list[tuple[str, float, float]] = []
    callback_handler.register_start_callback(lambda a: marks.append(("start", time.perf_counter(), _cpu())))
    callback_handler.register_end_callback(lambda a: marks.append(("end", time.perf_counter(), _cpu())))
    out = os.path.join(cache, "pm.srt")
    args = build_parser().parse_args(["solve", "pointmass", "--quiet", "--compile", "yes", "--out", out])
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), _cpu()
    run_solve(args)
    t1, c1 = time.perf_counter(), _cpu()
    starts = [m for m in marks if m[0] == "start"]
    ends = [m for m in marks if m[0] == "end"]
    print(f"torch.compile, empty cache {cache}: {len(starts)} compiles; first start to last end "
          f"{ends[-1][1] - starts[0][1]:.1f} s wall, {ends[-1][2] - starts[0][2]:.1f} s CPU; "
          f"whole solve {t1 - t0:.1f} s wall, {c1 - c0:.1f} s CPU; load average {load0:.1f} -> "
          f"{os.getloadavg()[0]:.1f}")


def filter_compile(table: str) -> None:
    cache = tempfile.mkdtemp(prefix="numba-cold-")
    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), _cpu()
    subprocess.run([sys.executable, "-m", "softreach.cli", "compile", table], env=env, check=True)
    t1, c1 = time.perf_counter(), _cpu()
    print(f"softreach compile {table}, empty numba cache {cache}: {t1 - t0:.1f} s wall, {c1 - c0:.1f} s CPU "
          f"(with the interpreter's start); load average {load0:.1f} -> {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["torch"]:
        torch_compile()
    elif sys.argv[1:2] == ["filter"] and len(sys.argv) == 3:
        filter_compile(sys.argv[2])
    else:
        sys.exit(__doc__)
