"""Compare the sets of a budget-surface table (``Q_min``) with those of a ``W_eps`` table of the same model.

    python benchmarks/compare_surface.py QMIN.srt WEPS.srt [--budgets 0 5 10] [--t 0] [--simulate 40]

Per budget ``Q``: the measure of ``RA~_Q`` read from each table, on the ``W_eps`` table's state nodes (the
``Q_min`` table is interpolated there when its grid differs), their symmetric difference over the ``W_eps`` set's
measure, and the parts only one table claims. At ``Q = 0`` both read the classical ``V`` beside them (Prop. 3).

Which one is right where they differ? For the point mass, ``benchmarks/grade_pointmass.py`` answers exactly. For
any model, ``--simulate N`` draws up to ``N`` states from each part only one table claims and flies them: a state
counts as *flown* when one of the two tables' ``a*`` lands it with at most ``Q`` of budget and no hard violation
against every one of these winds: each table's worst case ``b*``, and the two constant extremes. That is evidence
the state belongs to ``RA~_Q`` (the state's table is right), not a proof: other winds exist. A state no controller
flies against one of them is outside ``RA~_Q`` for these controllers, and likely outside it.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from softreach.reach import load_table
from softreach.reach.sim.simulate import constant, rollout, table_control, table_disturbance


def _nodes(table) -> np.ndarray:
    axes = table.state_axes()
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.stack([m.ravel() for m in mesh], axis=1)


def _claims(table, pts: np.ndarray, t: float, q: float, same_nodes: bool) -> np.ndarray:
    # on the table's own nodes its slice is read as stored: the interpolant's weights round at a node, and where a
    # value is exactly 0 (a plateau of V on the target) that decides membership
    if same_nodes:
        return np.asarray(table.set_mask(t, q), dtype=bool).ravel()
    return np.asarray(table.contains(np.full(len(pts), t), pts, np.full(len(pts), q)), dtype=bool)


def _flown(model, tables, pts: np.ndarray, q: float, t: float, dt: float) -> np.ndarray:
    """Whether one of the tables' ``a*`` lands each state within budget against every test wind."""
    lo, hi = model.disturbance_bounds
    winds = [table_disturbance(tb) for tb in tables] + [constant(lo), constant(hi)]
    ok_any = np.zeros(len(pts), bool)
    for tb in tables:
        ok_all = np.ones(len(pts), bool)
        for wind in winds:
            r = rollout(model, pts, q, table_control(tb), wind, t0=t, dt=dt)
            ok_all &= r.landed & ~r.hard_violation & (r.budget_used <= q + 1e-6)
        ok_any |= ok_all
    return ok_any


def compare(q_table, w_table, budgets: list[float], t: float, simulate: int, seed: int = 0) -> list[dict]:
    if q_table.model_metadata["name"] != w_table.model_metadata["name"]:
        raise SystemExit(f"the tables are for {q_table.model_metadata['name']!r} and {w_table.model_metadata['name']!r}")
    pts = _nodes(w_table)
    cell = w_table.cell_volume()
    model = w_table.model
    dt = (model.control_period or model.horizon / 100) / 10
    rng = np.random.default_rng(seed)
    n = len(q_table.model_metadata["state_names"])
    qg, wg = q_table.grid(), w_table.grid()
    same = qg.shape[:n] == wg.shape[:n] and np.allclose(qg.lo[:n], wg.lo[:n]) and np.allclose(qg.hi[:n], wg.hi[:n])
    rows = []
    for q in budgets:
        in_q, in_w = _claims(q_table, pts, t, q, same), _claims(w_table, pts, t, q, True)
        row = {"Q": q, "Q_min_measure": float(in_q.sum() * cell), "W_eps_measure": float(in_w.sum() * cell),
               "only_Q_min": float((in_q & ~in_w).sum() * cell), "only_W_eps": float((in_w & ~in_q).sum() * cell)}
        row["symmetric_difference"] = (row["only_Q_min"] + row["only_W_eps"]) / max(row["W_eps_measure"], 1e-300)
        if simulate:
            for name, part in (("only_Q_min", in_q & ~in_w), ("only_W_eps", in_w & ~in_q)):
                idx = np.nonzero(part)[0]
                if len(idx) == 0:
                    continue
                pick = pts[rng.choice(idx, size=min(simulate, len(idx)), replace=False)]
                flown = _flown(model, (w_table, q_table), pick, q, t, dt)
                row[f"{name}_flown"] = f"{int(flown.sum())}/{len(flown)}"
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("q_min_table", help="a table of softreach solve MODEL --budget-surface")
    ap.add_argument("w_eps_table", help="a W_eps table of the same model (softreach solve MODEL)")
    ap.add_argument("--budgets", type=float, nargs="+", default=None, help="budgets Q (default: the model's)")
    ap.add_argument("--t", type=float, default=0.0, help="time of the sets [s]")
    ap.add_argument("--simulate", type=int, default=0, metavar="N",
                    help="fly up to N states from each part only one table claims (see above)")
    args = ap.parse_args(argv)
    q_table, w_table = load_table(args.q_min_table), load_table(args.w_eps_table)
    if not q_table.has_budget_surface or not w_table.has_budget:
        raise SystemExit("give a budget-surface table first, then a W_eps table")
    budgets = args.budgets if args.budgets is not None else list(w_table.model.default_budgets)
    print(f"{args.q_min_table} (Q_min {' x '.join(map(str, q_table.grid().shape))}) against {args.w_eps_table} "
          f"(W_eps {' x '.join(map(str, w_table.grid().shape))}), t = {args.t:g}, on the W_eps table's state nodes")
    print(f"  {'Q':>6} {'Q_min':>9} {'W_eps':>9} {'only Q_min':>11} {'only W_eps':>11} {'sym.diff':>9}"
          + ("  flown: only Q_min / only W_eps" if args.simulate else ""))
    for r in compare(q_table, w_table, budgets, args.t, args.simulate):
        line = (f"  {r['Q']:6.3g} {r['Q_min_measure']:9.3f} {r['W_eps_measure']:9.3f} {r['only_Q_min']:11.3f} "
                f"{r['only_W_eps']:11.3f} {100 * r['symmetric_difference']:8.2f}%")
        if args.simulate:
            line += f"  {r.get('only_Q_min_flown', '-'):>9} / {r.get('only_W_eps_flown', '-')}"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
