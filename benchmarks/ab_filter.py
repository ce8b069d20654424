"""Two installations of softreach timed against each other, interleaved, so that a shared machine's swings in speed
fall on both alike: the same decisions of one thread, asked of each in turn many times.

    git worktree add /tmp/before COMMIT && cp -a .venv /tmp/before/.venv
    /tmp/before/.venv/bin/python -m pip install -q --no-deps -e /tmp/before
    OMP_NUM_THREADS=1 python benchmarks/ab_filter.py --table pm-held.srt \\
        now=.venv/bin/python before=/tmp/before/.venv/bin/python

Each installation runs in a process of its own (this file with ``--worker``) that builds ``ValueFilter(table, 0.01)``
on one thread and, asked for a task, times it once: ``batch_certified`` (1,024 certified states), ``batch_random``
(1,024 random states and actions), ``certify`` (:meth:`ValueFilter.certify` of the random states) and
``single_certified`` (256 single certified states, one call each; per call). The driver asks each process in turn,
``--rounds`` times, and prints the best and the median of each task and installation side by side [us], and the
ratio of the first two installations' medians.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

TASKS = ("batch_certified", "batch_random", "certify", "single_certified")


def worker(table_path: str) -> None:
    import numpy as np

    from softreach.filters import ValueFilter
    from softreach.reach import load_table

    rng = np.random.default_rng(0)
    n = 1024
    x = np.c_[rng.uniform(-15, 15, n), rng.uniform(0, 18, n)]
    z, t, a = rng.uniform(0, 0.6, n), np.round(rng.uniform(0, 0.9, n) * 0.94, 2), rng.uniform(-60, 60, (n, 1))
    vf = ValueFilter(load_table(table_path), 0.01)
    vf.threads = 1
    certified = np.nonzero(vf.certify(t, x, z)[0])[0]
    rows = np.resize(certified, n)
    batch = (t[rows], x[rows], z[rows], a[rows])
    singles = [(float(t[i]), x[i].copy(), float(z[i]), a[i].copy()) for i in certified[:256]]

    def single() -> None:
        for s in singles:
            vf.filter(*s)

    tasks = {"batch_certified": (lambda: vf.filter(*batch), 5, 1),
             "batch_random": (lambda: vf.filter(t, x, z, a), 1, 1), "certify": (lambda: vf.certify(t, x, z), 3, 1),
             "single_certified": (single, 2, len(singles))}
    for run, _, _ in tasks.values():  # compiled code loaded, caches warm
        run()
    print("ready", flush=True)
    for line in sys.stdin:
        run, repeats, per = tasks[line.strip()]
        start = time.perf_counter()
        for _ in range(repeats):
            run()
        print((time.perf_counter() - start) / repeats / per * 1e6, flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--table", required=True, help="a point-mass held table (softreach solve pointmass --held)")
    parser.add_argument("--rounds", type=int, default=25, help="times each task is asked of each installation")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("pythons", nargs="*", metavar="NAME=PYTHON", help="an installation's interpreter, named")
    args = parser.parse_args()
    if args.worker:
        worker(args.table)
        return
    named = dict(p.split("=", 1) for p in args.pythons)
    if len(named) < 2:
        parser.error(f"give two or more NAME=PYTHON, got {args.pythons}")
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = {name: subprocess.Popen([py, __file__, "--worker", "--table", args.table], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, text=True, env=env) for name, py in named.items()}
    for name, proc in procs.items():
        if proc.stdout.readline().strip() != "ready":
            sys.exit(f"{name} ({named[name]}) did not start; its error is above")
    times: dict[tuple[str, str], list[float]] = {}
    for _ in range(args.rounds):
        for task in TASKS:
            for name, proc in procs.items():
                proc.stdin.write(task + "\n")
                proc.stdin.flush()
                times.setdefault((task, name), []).append(float(proc.stdout.readline()))
    for proc in procs.values():
        proc.stdin.close()
        proc.wait()
    first, second = list(procs)[:2]
    print(f"{'task [us]':18s}" + "".join(f"{name + ' best':>16s}{name + ' median':>16s}" for name in procs)
          + f"{first + '/' + second:>20s}")
    for task in TASKS:
        cells = "".join(f"{min(times[task, n]):16.1f}{statistics.median(times[task, n]):16.1f}" for n in procs)
        ratio = statistics.median(times[task, first]) / statistics.median(times[task, second])
        print(f"{task:18s}{cells}{ratio:20.3f}")


if __name__ == "__main__":
    main()
