"""Grade point-mass tables against the exact soft-constrained reach-avoid sets (``reach/numerics/exact_pointmass.py``).

    python benchmarks/grade_pointmass.py TABLE.srt [TABLE.srt ...] [--budgets 0 0.06 0.3 0.6] [--t 0] [--json]

Per table and budget, on the table's own nodes (each standing for one cell, as ``Table.set_measure`` counts):
the exact area, the area the table claims (``Table.set_mask(t, Q)``), the unsound area (claimed, proved infeasible),
the missed area, the symmetric difference over the exact area, and how far from the exact boundary the differences
reach, in cells. Where the table answers ``q_min``, its ``Q_min`` surface is compared with the exact one on the same
nodes. A sampled-data table (actions held) solves a harder game than the continuous one the reference solves: its
unsound area still means what it says, its missed area includes the price of holding actions.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from scipy.ndimage import distance_transform_cdt

from softreach.reach import load_table
from softreach.reach.numerics.exact_pointmass import exact_mask, exact_q_min, grade


def _depths(table, q: float, t: float) -> tuple[int, int]:
    """The farthest unsound node outside, and missed node inside, the exact set, in cells (chessboard)."""
    exact = exact_mask(table, q, t)
    claimed = np.asarray(table.set_mask(t, q), dtype=bool)
    inside = distance_transform_cdt(exact, metric="chessboard")
    outside = distance_transform_cdt(~exact, metric="chessboard")
    unsound, missed = claimed & ~exact, exact & ~claimed
    return (int(outside[unsound].max()) if unsound.any() else 0, int(inside[missed].max()) if missed.any() else 0)


def _q_min_report(table, t: float) -> dict[str, float] | None:
    if not hasattr(table, "q_min"):
        return None
    vv, yy = np.meshgrid(*table.state_axes(), indexing="ij")
    try:
        got = np.asarray(table.q_min(t, np.stack([vv.ravel(), yy.ravel()], axis=1)), dtype=np.float64).reshape(vv.shape)
    except (KeyError, ValueError):
        return None
    exact = exact_q_min(vv, yy, table.horizon - t, table.model.params)
    both = np.isfinite(got) & np.isfinite(exact)
    err = got[both] - exact[both]
    resolution = float(getattr(table, "budget_resolution", 0.0))
    return {"nodes_exact_finite": int(np.isfinite(exact).sum()), "nodes_table_finite": int(np.isfinite(got).sum()),
            "finite_where_exact_infinite": int((np.isfinite(got) & ~np.isfinite(exact)).sum()),
            "infinite_where_exact_finite": int((~np.isfinite(got) & np.isfinite(exact)).sum()),
            "mean_abs_error": float(np.abs(err).mean()) if err.size else float("nan"),
            "max_abs_error": float(np.abs(err).max()) if err.size else float("nan"),
            "optimistic_nodes": int((err < -resolution - 1e-9).sum()), "budget_resolution": resolution}


def grade_table(path: str, budgets: list[float], t: float, verify: bool) -> dict:
    t0 = time.perf_counter()
    table = load_table(path, verify_checksum=verify)
    if table.model_metadata["name"] != "pointmass":
        raise SystemExit(f"{path}: a {table.model_metadata['name']!r} table; the exact reference covers the point mass")
    out = {"path": path, "shape": list(table.grid().shape), "control_period": table.control_period,
           "budgets": {}, "q_min": _q_min_report(table, t)}
    for q, row in grade(table, budgets, t).items():
        row["unsound_depth_cells"], row["missed_depth_cells"] = _depths(table, q, t)
        out["budgets"][q] = row
    out["seconds"] = time.perf_counter() - t0
    return out


def _print(report: dict, t: float) -> None:
    held = report["control_period"]
    kind = f"sampled-data, actions held {held:g} s" if held else "continuous time"
    print(f"{report['path']}: grid {' x '.join(map(str, report['shape']))}, {kind}, t = {t:g}")
    print(f"  {'Q [s]':>6} {'exact':>8} {'claimed':>8} {'unsound':>8} {'missed':>8} {'sym.diff':>9} "
          f"{'depth out/in':>13}   (areas in m^2/s)")
    for q, r in report["budgets"].items():
        print(f"  {q:6.3g} {r['exact_area']:8.2f} {r['claimed_area']:8.2f} {r['unsound_area']:8.2f} "
              f"{r['missed_area']:8.2f} {100 * r['relative_difference']:8.2f}% "
              f"{r['unsound_depth_cells']:>6d}/{r['missed_depth_cells']:<6d}")
    qm = report["q_min"]
    if qm:
        print(f"  Q_min on the nodes: finite at {qm['nodes_table_finite']} (exact {qm['nodes_exact_finite']}); "
              f"finite where no budget suffices {qm['finite_where_exact_infinite']}, infinite where one does "
              f"{qm['infinite_where_exact_finite']}")
        print(f"    where both finite: mean |error| {qm['mean_abs_error']:.4f} s, max {qm['max_abs_error']:.4f} s; "
              f"below the exact by more than the budget resolution {qm['budget_resolution']:.4g} s: "
              f"{qm['optimistic_nodes']} nodes")
    print(f"  ({report['seconds']:.1f} s)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("tables", nargs="+", help="point-mass .srt tables with W_eps")
    ap.add_argument("--budgets", type=float, nargs="+", default=[0.0, 0.06, 0.3, 0.6], help="budgets Q [s]")
    ap.add_argument("--t", type=float, default=0.0, help="time of the sets [s] (default 0)")
    ap.add_argument("--no-verify", action="store_true", help="skip the tables' checksums (trusted files only)")
    ap.add_argument("--json", action="store_true", help="print one JSON object per table instead of text")
    args = ap.parse_args(argv)
    for path in args.tables:
        report = grade_table(path, args.budgets, args.t, not args.no_verify)
        if args.json:
            print(json.dumps(report, default=float))
        else:
            _print(report, args.t)
    return 0


if __name__ == "__main__":
    sys.exit(main())
