"""What the verified safe cells cost and keep: build time, the share of ``C1`` they prove safe, and how many of
the states the landing certificate covers stay certified once every action must end in them.

    OMP_NUM_THREADS=1 python benchmarks/safe_cells.py --table pointmass-held.srt [--shape 150 1440] [--states 20000]

Certified means some candidate passes the one-period test (``ValueFilter.certify``), drawn uniformly over ``C1``
at each time and budget, with the cells (``safe_cells``) and without (``safe_cells=None``).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from softreach.filters import ValueFilter
from softreach.reach import load_table
from softreach.reach.safe_cells import SafeCells


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--table", required=True, help="a held table (softreach solve MODEL --held)")
    ap.add_argument("--shape", type=int, nargs="+", help="cells per state axis (default: the model's)")
    ap.add_argument("--states", type=int, default=20000)
    ap.add_argument("--times", type=float, nargs="+", default=[0.0, 0.5, 0.85])
    ap.add_argument("--budgets", type=float, nargs="+", help="default: the model's default budgets")
    args = ap.parse_args(argv)
    table = load_table(args.table)
    model = table.model
    plain = ValueFilter(table, table.control_period, target_checks=model.substeps, safe_cells=None)
    shape = tuple(args.shape) if args.shape else model.safe_cell_shape
    if shape is None:
        ap.error(f"{model.name} declares no safe_cell_shape; give --shape")
    t0 = time.perf_counter()
    cells = SafeCells.build(plain.lookahead, shape)
    build = time.perf_counter() - t0
    vf = ValueFilter(table, table.control_period, target_checks=model.substeps, safe_cells=cells)
    budgets = args.budgets or list(model.default_budgets)
    print(f"{args.table}: {len(cells.m.reshape(cells.steps + 1, -1)[0]):,} cells {shape}, built in {build:.1f} s")
    print("share of C1's cells safe at t = 0: " + ", ".join(f"Q = {q:g}: {cells.fraction(0, q):.1%}" for q in budgets))
    rng = np.random.default_rng(0)
    lo, hi = (np.asarray(b, float) for b in model.hard_box)
    x = rng.uniform(lo, hi, (args.states, len(lo)))
    print(f"{args.states:,} states uniform over C1; certified without cells -> with cells (kept)")
    for t in args.times:
        parts = []
        for q in budgets:
            before = plain.certify(t, x, q)[0]
            after = vf.certify(t, x, q)[0]
            parts.append(f"Q = {q:g}: {before.sum()} -> {after.sum()} ({after.sum() / max(before.sum(), 1):.1%}"
                         f"{'' if not (after & ~before).any() else f', {(after & ~before).sum()} new'})")
        print(f"  t = {t:g} s: " + "; ".join(parts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
