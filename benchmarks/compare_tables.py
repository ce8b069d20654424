"""How far two tables of the same model and grid are apart: per field the largest difference of the values, the
nodes on the other side of zero (of the nodes ``<= 0`` in the first), and the sets' measures at ``t = 0``.

    python benchmarks/compare_tables.py A.srt B.srt [--budgets 0 0.3 0.6]

For instance the same solve with the compiled loops and with the array code (``SolverSettings.compile``).
"""

from __future__ import annotations

import argparse

import numpy as np

from softreach.reach import load_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("first")
    ap.add_argument("second")
    ap.add_argument("--budgets", type=float, nargs="+", default=[0.0, 0.3, 0.6])
    args = ap.parse_args()
    a, b = load_table(args.first), load_table(args.second)
    if set(a.fields) != set(b.fields):
        raise SystemExit(f"the tables hold different fields: {sorted(a.fields)} and {sorted(b.fields)}")
    for name in a.fields:
        va, vb = np.asarray(a.values(name)), np.asarray(b.values(name))
        if va.shape != vb.shape:
            raise SystemExit(f"{name}: shapes {va.shape} and {vb.shape} differ")
        print(f"{name} {va.shape}: max |difference| {float(np.abs(va - vb).max()):.3g}; nodes on the other side of "
              f"zero {int(((va <= 0) != (vb <= 0)).sum())} of {int((va <= 0).sum())}")
    for q in args.budgets:
        print(f"RA~_Q at t = 0, Q = {q:g}: {a.set_measure(0.0, q):.4f} and {b.set_measure(0.0, q):.4f}")


if __name__ == "__main__":
    main()
