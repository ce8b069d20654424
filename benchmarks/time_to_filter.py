"""Time from a model to its first filtered step, from empty caches ("cold") and with the same caches again ("warm").

    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py                       # point mass, its default grid
    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --grid 51 51 --budget-points 56 --out t.json
    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --model glider --runs cold
    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --table-kind continuous --grid 51 51 --budget-points 56
    OMP_NUM_THREADS=1 python benchmarks/time_to_filter.py --model benchmarks.acc_model:CruiseControl \
        --table-kind continuous --runs cold [--no-ahead]            # a 2-D model, 145 x 109 x 45

Two processes, as a user runs them (each one's wall time counts the interpreter's start and imports):

1. ``solve``: ``softreach solve MODEL --held [--grid ...] [--budget-points ...] --threads N`` (the held table;
   ``--table-kind continuous``: without ``--held``, a table of the continuous-time game, which ranks candidates as
   well where the model's cells prove);
2. the user's script, timed in three parts: ``start`` (the interpreter and the imports of gymnasium, the env and
   the filter), ``cells`` (``SafetyFilter(make_env(MODEL), table)``: its landing cells unpacked from the package,
   loaded from the cache or built) and ``first step`` (``reset(seed=0)`` and one ``step`` of a random action: the
   filter's numba code loaded from the cache, or compiled).

``softreach solve`` starts compiling the filter's code in a background process where the cache lacks it
(:mod:`softreach.filters.background`), and the first decision waits for that process and loads its result, so a
cold run's ``first step`` holds what remains of the compilation after the solve and the cells; the background
process's CPU seconds are in no part's. ``--no-ahead`` switches it off (``SOFTREACH_COMPILE_AHEAD=0``): the first
decision then compiles. No step runs ``softreach compile``: a user need not know it.

"cold" points ``$SOFTREACH_CACHE`` (built cells, fused kernels, inductor's cache below it), ``$NUMBA_CACHE_DIR``
and ``$TORCHINDUCTOR_CACHE_DIR`` at a new empty folder; "warm" runs every phase again with the same folders (the
table is solved again: no cache holds tables). Python's own bytecode caches are not emptied. The load average is
printed beside each phase: wall time on a shared machine depends on what else runs.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

PHASES = ("solve", "start", "cells", "first step")


# ------------------------------------------------------------------ child processes
def _period(table: Any) -> float:
    """The filter's control period: the table's, or the model's for a table of the continuous-time game."""
    return float(table.control_period if table.control_period is not None else table.model.control_period)


def _child_filter(table_path: str, model: str) -> dict[str, Any]:
    """The user's script: a filtered environment made, reset and stepped once."""
    import numpy as np

    from softreach.agents.envs import make_env
    from softreach.filters import SafetyFilter
    from softreach.filters.precompile import decision_code_counts, decision_code_source
    from softreach.reach import load_table

    before = decision_code_counts()
    t0 = time.perf_counter()
    env = SafetyFilter(make_env(model), load_table(table_path))
    t1 = time.perf_counter()
    _, info = env.reset(seed=0)
    t2 = time.perf_counter()
    env.step(np.asarray(env.action_space.sample(), dtype=float))
    t3 = time.perf_counter()
    return {"cells": t1 - t0, "first step": t3 - t1, "reset": t2 - t1, "step": t3 - t2,
            "decision_code": decision_code_source(before),
            "certified": bool(info.get("certified"))}


def _child_region(table_path: str, budgets: list[float], n: int) -> dict[str, Any]:
    """The certified region at ``t = 0`` on ``n`` states uniform over ``C1`` (``audit_filter.sampled_region``),
    beside the table's own ``RA~_Q``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from audit_filter import sampled_region

    from softreach.filters import ValueFilter
    from softreach.reach import load_table

    table = load_table(table_path)
    dt, checks = _period(table), int(getattr(table.model, "substeps", 1) or 1)
    t0 = time.perf_counter()
    vf = ValueFilter(table, dt, target_checks=checks)
    cells = sampled_region(vf, table, budgets, None, n=n)
    return {"cells": cells, "cells_s": time.perf_counter() - t0}


# ------------------------------------------------------------------ the parent
def _env(cache: Path, threads: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(SOFTREACH_CACHE=str(cache), NUMBA_CACHE_DIR=str(cache / "numba"),
               TORCHINDUCTOR_CACHE_DIR=str(cache / "inductor"), OMP_NUM_THREADS=str(threads),
               MKL_NUM_THREADS=str(threads), NUMBA_NUM_THREADS=str(threads))
    return env


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run_phase(cmd: list[str], env: dict[str, str]) -> tuple[float, dict[str, Any], tuple[float, float]]:
    """Run one phase's process; its wall seconds, the JSON line it printed (plus ``cpu_s``: its CPU seconds and
    those of the processes it waited for) and the load average at its start and end."""
    load0 = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), _cpu_children()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _cpu_children() - c0
    load = (load0, os.getloadavg()[0])
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stdout[-2000:]}\n{p.stderr[-4000:]}")
    detail: dict[str, Any] = {}
    for line in reversed(p.stdout.splitlines()):
        if line.startswith("TTF "):
            detail = json.loads(line[4:])
            break
    detail["cpu_s"] = cpu
    return wall, detail, load


def run_once(args: argparse.Namespace, cache: Path, table: Path) -> list[dict[str, Any]]:
    """Every phase once with the caches in ``cache``; one row per phase."""
    env = _env(cache, args.threads)
    if args.no_ahead:
        env["SOFTREACH_COMPILE_AHEAD"] = "0"
    me = [sys.executable, os.path.abspath(__file__)]
    held = ["--held"] if args.table_kind == "held" else []
    solve = ["softreach", "solve", args.model, *held, "--quiet", "--threads", str(args.threads), "--out", str(table)]
    if args.grid:
        solve += ["--grid", *map(str, args.grid)]
    if args.budget_points:
        solve += ["--budget-points", str(args.budget_points)]
    solve_cmd = [str(Path(sys.executable).with_name("softreach")), *solve[1:]]
    if table.exists():
        table.unlink()  # solved afresh every run: --no-resume is not needed, but a finished table is replaced
    wall, detail, load = _run_phase(solve_cmd, env)
    rows = [{"phase": "solve", "wall_s": wall, "load": load, **detail}]
    _print_row(rows[-1])
    wall, detail, load = _run_phase([*me, "--child", "filter", "--table", str(table), "--model", args.model], env)
    parts = {"start": wall - detail["cells"] - detail["first step"], "cells": detail["cells"],
             "first step": detail["first step"]}
    for phase, seconds in parts.items():
        # the script's CPU seconds are its process's, shown once, on its first part
        rows.append({"phase": phase, "wall_s": seconds, "load": load,
                     **(detail if phase == "start" else {"cpu_s": None})})
        _print_row(rows[-1])
    return rows


def _print_row(row: dict[str, Any]) -> None:
    cpu = "" if row["cpu_s"] is None else f"{row['cpu_s']:7.1f} s CPU "
    detail = {k: v for k, v in row.items() if k not in ("phase", "wall_s", "load")}
    print(f"  {row['phase']:<11} {row['wall_s']:8.1f} s wall, {cpu}(load {row['load'][0]:.1f} -> "
          f"{row['load'][1]:.1f}) {json.dumps(detail)}", flush=True)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="pointmass", help="a registered model or module:Class (default pointmass)")
    ap.add_argument("--grid", type=int, nargs="+", default=None, help="state grid of the held solve (default: "
                                                                     "softreach solve's)")
    ap.add_argument("--budget-points", type=int, default=None, help="budget nodes (default: softreach solve's)")
    ap.add_argument("--no-ahead", action="store_true", help="the solve does not compile the filter in the "
                                                             "background (SOFTREACH_COMPILE_AHEAD=0)")
    ap.add_argument("--threads", type=int, default=1, help="threads of every phase (default 1)")
    ap.add_argument("--table-kind", choices=("held", "continuous"), default="held",
                    help="the table solved: of the sampled-data game (--held, default) or of the continuous-time "
                         "game (ranks as well where the model's cells prove)")
    ap.add_argument("--runs", nargs="+", choices=("cold", "warm"), default=["cold", "warm"],
                    help="cold (empty caches) then warm (the same caches again); default both")
    ap.add_argument("--cache", default=None, help="cache folder to use (default: a new empty one)")
    ap.add_argument("--out", default=None, help="write the rows as JSON here")
    ap.add_argument("--region", type=float, nargs="*", default=None, metavar="Q",
                    help="after the runs, the certified region at t = 0 for these budgets (audit_filter."
                         "sampled_region), with the cells and with the table alone, in one more process")
    ap.add_argument("--states", type=int, default=20000, help="states uniform over C1 for --region (20,000)")
    ap.add_argument("--region-only", action="store_true",
                    help="no runs: only --region on the table already in --cache")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--table", default=None, help="the table's file (default: in the cache folder); with "
                                                   "--region-only, an existing table")
    args = ap.parse_args(argv)
    if args.child:
        fn = {"filter": lambda: _child_filter(args.table, args.model),
              "region": lambda: _child_region(args.table, args.region, args.states)}[args.child]
        print("TTF " + json.dumps(fn()), flush=True)
        return {}
    if args.threads < 1:
        raise SystemExit(f"--threads must be >= 1, got {args.threads}")
    if args.grid and any(g < 2 for g in args.grid):
        raise SystemExit(f"--grid sizes must be >= 2, got {args.grid}")
    cache = Path(args.cache) if args.cache else Path(tempfile.mkdtemp(prefix="softreach-ttf-"))
    cache.mkdir(parents=True, exist_ok=True)
    table = Path(args.table) if args.table else cache / f"{args.model.rpartition(':')[2]}-{args.table_kind}.srt"
    out: dict[str, Any] = {"model": args.model, "table_kind": args.table_kind, "grid": args.grid or "default", "budget_points":
                           args.budget_points or "default", "threads": args.threads, "cache": str(cache),
                           "cpus": os.cpu_count(), "runs": {}}
    for run in ([] if args.region_only else args.runs):
        print(f"{run}: caches in {cache}, load average {os.getloadavg()[0]:.1f}", flush=True)
        out["runs"][run] = run_once(args, cache, table)
    from softreach.reach import load_table

    g = load_table(str(table)).grid("W_eps")
    out["table_grid"] = [int(n) for n in g.shape]
    runs = list(out["runs"])
    print(f"\n{args.model}, {args.table_kind} table {' x '.join(map(str, out['table_grid']))} (state x budget), "
          f"{args.threads} thread(s), {os.cpu_count()} CPUs; wall seconds of the solve's process and of each part of "
          f"the script's (load average at the process's start -> end), and each process's CPU seconds")
    print(f"{'phase':<11} " + " ".join(f"{r + ' wall (load), CPU':>36}" for r in runs))
    for i, phase in enumerate(PHASES if runs else ()):
        cells = [out["runs"][r][i] for r in runs]
        print(f"{phase:<11} " + " ".join(f"{c['wall_s']:8.1f} s ({c['load'][0]:4.1f}->{c['load'][1]:4.1f}), "
                                          + (f"{'':>9}" if c["cpu_s"] is None else f"{c['cpu_s']:7.1f} s") for c in cells))
    if runs:
        print(f"{'total':<11} " + " ".join(f"{sum(c['wall_s'] for c in out['runs'][r]):8.1f} s{'':>14}"
                                          f"{sum(c['cpu_s'] or 0.0 for c in out['runs'][r]):7.1f} s" for r in runs))
    if args.region is not None:
        me = [sys.executable, os.path.abspath(__file__)]
        cmd = [*me, "--child", "region", "--table", str(table), "--states", str(args.states),
               "--region", *map(str, args.region or [0.0, 0.3, 0.6])]
        wall, out["region"], load = _run_phase(cmd, _env(cache, args.threads))
        print(f"\ncertified at t = 0, {args.states:,} states uniform over C1 ({wall:.0f} s, load {load[0]:.1f}): "
              f"certified, and certified / in the table's RA~_Q")
        for rc in out["region"]["cells"]:
            print(f"  Q = {rc['Q']:<4g} cells {rc['certified']:6d} ({100 * rc['certified'] / rc['states']:.1f} %), "
                  f"{rc['certified_in_held']} / {rc['in_held']} of RA~_Q")
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
