"""Point-mass measurements reported in the README and the closing notes (not tests: they take minutes).

    python benchmarks/pointmass_checks.py soundness pointmass.srt [--margin 0.1] [--dt 2e-3]
    python benchmarks/pointmass_checks.py kappa --grid 61 61 --budget-points 67 --accuracy medium --kappas 1 10 50
    python benchmarks/pointmass_checks.py ceiling --sizes 101 201 401
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from softreach.reach import Grid, SolverSettings, budget_axis, classical_problem, get_model, load_table, soft_problem, solve
from softreach.reach.sim.simulate import constant, random_switching, rollout, table_control, table_disturbance


def soundness(args) -> None:
    """Closed loops from every other grid node with W <= -margin: the table's a* against four disturbances."""
    table = load_table(args.table)
    model = table.model
    axes = table.state_axes("V")
    mesh = np.meshgrid(*[a[::2] for a in axes], indexing="ij")
    pts = np.stack([m.ravel() for m in mesh], axis=1)
    winds = {"worst": table_disturbance(table), "+10": constant(10.0), "-10": constant(-10.0),
             "switching": random_switching(model, seed=1)}
    totals = np.zeros(4, int)
    for q in args.budgets:
        starts = pts[table.value(0.0, pts, np.full(len(pts), q)) <= -args.margin]
        for name, wind in winds.items():
            ro = rollout(model, starts, q, table_control(table), wind, dt=args.dt, eps=table.eps)
            over = (ro.budget_used > q + args.dt).sum()
            totals += [len(starts), ro.landed.sum(), ro.hard_violation.sum(), over]
            print(f"Q={q:<5g} wind={name:9s} starts={len(starts):4d} landed={ro.landed.sum():4d} "
                  f"hard={ro.hard_violation.sum()} overruns={over}")
    starts = pts[table.value(0.0, pts) <= -args.margin]
    ro = rollout(model, starts, 0.0, lambda t, x, z: table.optimal_control(t, x), lambda t, x, z: table.worst_disturbance(t, x), dt=args.dt)
    print(f"classical V: starts={len(starts)} landed={ro.landed.sum()} hard={ro.hard_violation.sum()}")
    print(f"W_eps total: runs={totals[0]} landed={totals[1]} hard={totals[2]} overruns={totals[3]}")


def kappa(args) -> None:
    """RA~_0 (W at dz/2) and RA~_Q measures against the classical RA for several budget scales."""
    model = get_model("pointmass")
    s = SolverSettings.from_accuracy(args.accuracy, dtype="float32")
    grid = Grid(model.domain[0], model.domain[1], tuple(args.grid))
    V = np.asarray(solve(classical_problem(model), grid, [0.0, 1.0], s))
    cell = grid.cell_volume
    print(f"classical RA {((V <= 0).sum() * cell):.2f}")
    z_lo, z_hi, nz = budget_axis(1.0, args.budget_points)
    g3 = Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), tuple(args.grid) + (nz,))
    iz0 = int(round(-z_lo / g3.spacing[2]))
    for k in args.kappas:
        t0 = time.perf_counter()
        W = np.asarray(solve(soft_problem(model, 1e-3, k), g3, [0.0, 1.0], s))
        ra, raw, half = V <= 0, W[:, :, iz0] <= 0, 0.5 * (W[:, :, iz0] + W[:, :, iz0 + 1]) <= 0
        print(f"kappa={k:g}: raw z=0 slice {raw.sum() * cell:.2f} (sym. diff {(raw ^ ra).sum() * cell:.2f}), "
              f"RA~_0 at dz/2 {half.sum() * cell:.2f} (sym. diff {(half ^ ra).sum() * cell:.2f}), {time.perf_counter() - t0:.0f} s")


def ceiling(args) -> None:
    """The classical set's highest altitude from rest against the exact bang-coast-bang value."""
    model = get_model("pointmass")
    print(f"exact ceiling {model.exact_ceiling():.3f} m")
    for n in args.sizes:
        grid = Grid(model.domain[0], model.domain[1], (n, n))
        V = np.asarray(solve(classical_problem(model), grid, [0.0, 1.0], SolverSettings.from_accuracy(args.accuracy)))
        iv = int(np.argmin(np.abs(grid.axis(0))))
        print(f"{n}x{n}: v = {grid.axis(0)[iv]:.3g}, ceiling {grid.axis(1)[V[iv] <= 0].max():.3f} m (dy {grid.spacing[1]:.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("soundness")
    p.add_argument("table")
    p.add_argument("--margin", type=float, default=0.1)
    p.add_argument("--dt", type=float, default=2e-3)
    p.add_argument("--budgets", type=float, nargs="+", default=[0.06, 0.3, 0.6])
    p.set_defaults(func=soundness)
    p = sub.add_parser("kappa")
    p.add_argument("--grid", type=int, nargs=2, default=[61, 61])
    p.add_argument("--budget-points", type=int, default=67)
    p.add_argument("--accuracy", default="medium")
    p.add_argument("--kappas", type=float, nargs="+", default=[1.0, 10.0, 50.0])
    p.set_defaults(func=kappa)
    p = sub.add_parser("ceiling")
    p.add_argument("--sizes", type=int, nargs="+", default=[101, 201, 401])
    p.add_argument("--accuracy", default="very_high")
    p.set_defaults(func=ceiling)
    args = ap.parse_args()
    args.func(args)


if __name__ == "__main__":
    main()
