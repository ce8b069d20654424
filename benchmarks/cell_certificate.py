"""What the cell certificates cost and keep: build time, and the states they certify against the table's own set
and, for the point mass, the exact sets.

    OMP_NUM_THREADS=1 python benchmarks/cell_certificate.py --table pointmass-held.srt
        [--shape 300 2880 --holds 1 2 4 --dz 0.00015625 | --cached] [--states 20000] [--times 0 0.5 0.9]
        [--exact-pointmass] [--later 0.5 1 2]
    python benchmarks/cell_certificate.py --table pointmass-held.srt --write-packaged [--checks 2]

Certified means ``ValueFilter.certify`` (the landing cells, proven), against the table's set (``Table.contains``: its
interpolant ``<= 0``, which a held table claims and nothing proves), on states drawn uniformly over ``C1``.
``--exact-pointmass`` also counts the states of the exact continuous-time sets
(``softreach.reach.numerics.exact_pointmass``), which hold every state any controller can land from, and the cells'
states outside them (unsound; 0 expected).


``--write-packaged`` (re)writes the cells the package ships (``reach/proof/cells/``, the model's ``cell_shape``, for the
filter's default ``target_checks`` 1 and the environment's sub-steps, or those of ``--checks``) from the table's
candidates and period. The package ships the point mass's for 1 and 10, the glider's for its environment's 2 only
(``--checks 2``: its pair of games took 16 min to build, beside another job).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from softreach.filters import ValueFilter
from softreach.reach import load_table
from softreach.reach.proof.cell_certificate import PACKAGED, CellCertificate, cache_file, cell_key
from softreach.reach.proof.lookahead import Lookahead


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--table", required=True, help="a held table (softreach solve MODEL --held)")
    ap.add_argument("--shape", type=int, nargs="+", help="cells per state axis (default: the model's cell_shape)")
    ap.add_argument("--holds", type=int, nargs="+", help="plan lengths in periods (default: the model's cell_holds)")
    ap.add_argument("--dz", type=float, help="budget cell [s] (default: cell_certificate.default_dz)")
    ap.add_argument("--states", type=int, default=20000)
    ap.add_argument("--times", type=float, nargs="+", default=[0.0, 0.5, 0.9])
    ap.add_argument("--budgets", type=float, nargs="+", help="default: the model's default budgets")
    ap.add_argument("--exact-pointmass", action="store_true", help="compare with the point mass's exact sets")
    ap.add_argument("--cached", action="store_true",
                    help="the cells a filter uses (packaged, or cached by an earlier build) instead of a build")
    ap.add_argument("--later", type=float, nargs="+",
                    help="also: of the states in the table's set that the cells miss, the share still in it at a "
                         "start this many seconds later, beside that share of the cells' states")
    ap.add_argument("--write-packaged", action="store_true", help="write the cells the package ships, and stop")
    ap.add_argument("--checks", type=int, nargs="+", help="with --write-packaged: only these target_checks")
    args = ap.parse_args(argv)
    table = load_table(args.table)
    model = table.model
    if args.write_packaged:
        return write_packaged(table, args.checks)
    la = Lookahead.from_table(table, model, table.control_period, table.eps, target_checks=model.substeps)
    shape = tuple(args.shape) if args.shape else model.cell_shape
    if shape is None:
        ap.error(f"{model.name} declares no cell_shape; give --shape")
    holds = tuple(args.holds) if args.holds else model.cell_holds
    if args.cached:
        if args.shape or args.holds or args.dz:
            ap.error("--cached uses the model's cell_shape and cell_holds; leave out --shape, --holds and --dz")
        vf = ValueFilter(table, table.control_period, target_checks=model.substeps)
    else:
        t0 = time.perf_counter()
        land = CellCertificate.build(la, shape, dz=args.dz, holds=holds)
        print(f"landing cells {shape}, budget cells of {land.dz:g} s, plans of {list(holds)} periods: "
              f"built in {time.perf_counter() - t0:.1f} s")
        vf = ValueFilter(table, table.control_period, target_checks=model.substeps, landing_cells=land)
    budgets = args.budgets or list(model.default_budgets)
    rng = np.random.default_rng(0)
    lo, hi = (np.asarray(b, float) for b in model.hard_box)
    x = rng.uniform(lo, hi, (args.states, len(lo)))
    print(f"{args.states:,} states uniform over C1: in the table's set / certified by the cells (proven)"
          + (" / exact set / cells outside it" if args.exact_pointmass else ""))
    for t in args.times:
        parts, late = [], []
        for q in budgets:
            table_only = table.contains(t, x, q)
            cells = vf.certify(t, x, q)[0]
            part = f"Q = {q:g}: {int(table_only.sum())} / {int(cells.sum())}"
            if args.exact_pointmass:
                from softreach.reach.numerics.exact_pointmass import exact_member

                exact = np.asarray(exact_member(x[:, 0], x[:, 1], q, model.horizon - t), bool)
                part += f" / {int(exact.sum())} / {int((cells & ~exact).sum())}"
            parts.append(part)
            # how much time to spare the states the cells miss have, against the cells' own states
            missed = table_only & ~cells
            for later in args.later or ():
                share = [float(table.contains(t + later, x[k], q).mean()) if k.any() else float("nan")
                         for k in (missed, cells)]
                late.append(f"Q = {q:g}, {later:g} s later: {share[0]:.0%} of the missed, {share[1]:.0%} of the "
                            f"cells' states")
        print(f"  t = {t:g} s: " + "; ".join(parts))
        for line in late:
            print(f"    in the table's set at a later start: {line}")
    return 0


def write_packaged(table, checks_list: list[int] | None = None) -> int:
    """Build the model's default cells for ``target_checks`` 1 and the model's sub-steps (or ``checks_list``) into
    :data:`PACKAGED`."""
    model = table.model
    PACKAGED.mkdir(exist_ok=True)
    for checks in checks_list or sorted({1, model.substeps}):
        la = Lookahead.from_table(table, model, table.control_period, table.eps, target_checks=checks)
        t0 = time.perf_counter()
        cells = CellCertificate.build(la, model.cell_shape, holds=model.cell_holds)
        path = cache_file(cell_key(la, model.cell_shape, holds=model.cell_holds), PACKAGED)
        cells.save(path)
        print(f"{path}: built in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
