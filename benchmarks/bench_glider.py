"""The glider's soft-constrained tables (paper §VI-B, issue 3): solve cost, verified sets, soundness.

Usage::

    # solve and time (wall clock, peak resident memory of this process); writes the table and a JSON summary
    python benchmarks/bench_glider.py solve --grid 91 29 21 --budget-points 21 --accuracy medium \\
        --out runs/glider.srt --json runs/glider_solve.json

    # the numbers of a table: highest verified altitude and measure per Q, Q = 0 against the classical set,
    # the horizon's effect (sets at t > 0 have a shorter horizon), and closed-loop soundness
    python benchmarks/bench_glider.py report runs/glider.srt --starts 60 --policies gradient lookahead \
        --json runs/glider_report.json

Protocol of ``report`` (the soundness part; the same for every table):

* starts: states drawn uniformly from the table's state box (seeded), kept where
  ``W_eps(0, x, max(Q, r)) <= -margin`` (``r`` is the table's budget resolution, the level that
  :meth:`~softreach.reach.tables.query.Table.set_mask` uses for ``Q = 0``), up to ``--starts`` per ``Q``;
* each start flies from ``t = 0`` with budget ``Q`` under a W-derived control (the paper's gradient control
  ``a*``, and optionally :func:`lookahead_control`; zero-order hold over ``--dt`` with 4 RK4 substeps,
  :func:`softreach.reach.sim.simulate.rollout`) against each of the winds: the table's
  worst case, constant tailwind (+10 kN), constant headwind (-10 kN), calm, and random bang-bang switching
  every 0.5 s and every 0.1 s;
* counted: hard-constraint violations (``c1 > 0`` at any substep), failures to land by the horizon, budget
  overruns (budget used ``> Q + 1e-3`` s, the paper's proxy), and the largest budget used minus ``Q``;
* ``--margin`` defaults to three times the largest change of ``W_eps`` over one control period seen along the
  worst-case closed loops of a pilot batch from inside the sets (printed as ``dW_per_period``; its largest
  increase, which the exact value would not show, as ``dW_rise_per_period``).

Timings on the shared 2-core machine vary by a factor 2-4 with the other jobs on it; the JSON records the
load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

BUDGETS = (0.0, 5.0, 10.0)


def _load() -> tuple[float, float, float]:
    try:
        return os.getloadavg()
    except OSError:  # pragma: no cover
        return (float("nan"),) * 3


def peak_rss_mib() -> float:
    """Peak resident set size of this process so far [MiB] (``ru_maxrss`` is in KiB on Linux)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def cmd_solve(args: argparse.Namespace) -> dict[str, Any]:
    from softreach.reach import SolveConfig, SolverSettings, get_model, solve_table

    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    model = get_model("glider")
    compile_ = {"auto": None, "yes": True, "no": False}[args.compile]
    settings = SolverSettings.from_accuracy(args.accuracy, dtype=args.dtype, device=args.device, compile=compile_)
    cfg = SolveConfig(shape=tuple(args.grid) if args.grid else model.default_shape,
                      budget_points=args.budget_points or model.default_budget_points,
                      budget_scale=args.budget_scale, eps=args.eps, settings=settings,
                      snapshots=args.snapshots or model.default_snapshots)
    load0 = _load()
    t0 = time.perf_counter()
    summary = solve_table(model, cfg, args.out, resume=not args.no_resume, progress=not args.quiet, budgets=BUDGETS)
    wall = time.perf_counter() - t0
    nodes = int(np.prod(cfg.shape)) * cfg.budget_points
    out = {"grid": list(cfg.shape), "budget_points": cfg.budget_points, "nodes_W": nodes, "accuracy": args.accuracy,
           "dtype": args.dtype, "device": args.device, "wall_s": wall, "wall_by_field_s": summary["wall_time_s"],
           "peak_rss_mib": peak_rss_mib(), "torch_threads": torch.get_num_threads(), "load_before": load0, "load_after": _load(), "cpus": os.cpu_count(),
           "platform": platform.platform(), "table": str(args.out), "budget_scale": summary["budget_scale"],
           "classical_measure": summary["classical_measure"], "soft_measure": summary["soft_measure"]}
    print(json.dumps(out, indent=2))
    return out


# ---------------------------------------------------------------------------------------------- report
def set_numbers(table, budgets: Sequence[float] = BUDGETS, times: Sequence[float] = (0.0,)) -> dict[str, Any]:
    """Highest verified altitude and measure of ``RA~_Q`` (and of the classical ``RA``) at each time."""
    from softreach.reach.cli.plotting_nd import highest_node

    out: dict[str, Any] = {}
    for t in times:
        row: dict[str, Any] = {}
        if "V" in table.fields:
            ra = table.set_mask(t)
            row["classical"] = {"top_altitude_m": highest_node(table, ra), "measure": table.set_measure(t)}
        for q in budgets:
            m = table.set_mask(t, q)
            row[f"Q={q:g}"] = {"top_altitude_m": highest_node(table, m), "measure": table.set_measure(t, q)}
        out[f"t={t:g}"] = row
    if "V" in table.fields:
        ra, ra0 = table.set_mask(0.0), table.set_mask(0.0, 0.0)
        vol = table.cell_volume("V")
        out["q0_vs_classical"] = {"in_classical_not_q0": float((ra & ~ra0).sum()) * vol,
                                  "in_q0_not_classical": float((ra0 & ~ra).sum()) * vol,
                                  "relative_symmetric_difference": float((ra ^ ra0).sum()) / max(1, int(ra.sum()))}
    return out


def winds(model, seed: int = 0) -> dict[str, Any]:
    """The wind sequences of the protocol (the table's worst case is added by :func:`soundness`)."""
    from softreach.reach.sim.simulate import constant, random_switching

    w = model.disturbance_bounds[1][0]
    return {"tailwind": constant([w]), "headwind": constant([-w]), "calm": constant([0.0]),
            "switch_0.5s": random_switching(model, seed=seed, hold=0.5),
            "switch_0.1s": random_switching(model, seed=seed + 1, hold=0.1)}


def lookahead_control(table, lookahead: float = 0.1, n_alpha: int = 27):
    """A second W-derived control: ``argmin_alpha max_F W_eps(t + L, x + L f(x, alpha, F), z - L h_eps(x))`` over
    ``n_alpha`` angles and the two ends of the wind box (one explicit Euler step of ``L`` seconds).

    The paper's control is ``argmin_alpha max_F grad W . f`` with the gradient from central differences over
    one grid cell (:func:`softreach.reach.sim.simulate.table_control`). Near the top of the sets, where the 10 s
    horizon binds, that one drifts away from the flight-path limit and runs out of time; this one compares
    values a step ahead instead of a smoothed gradient (docs/glider.md, "Soundness").
    """
    model = table.model
    lo, hi = model.control_bounds[0][0], model.control_bounds[1][0]
    alphas = np.linspace(lo, hi, n_alpha)
    winds_ = (model.disturbance_bounds[0][0], model.disturbance_bounds[1][0])
    r = table.budget_resolution

    def policy(t: float, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        n = len(x)
        comps = [x[:, i] for i in range(x.shape[1])]
        z_next = np.maximum(np.maximum(z, r) - lookahead * np.asarray(model.violation_rate(t, comps, table.eps)), r)
        t_next = min(t + lookahead, table.horizon)
        best, arg = np.full(n, np.inf), np.zeros(n)
        for a in alphas:
            worst = np.full(n, -np.inf)
            for w in winds_:
                f = np.stack([np.broadcast_to(np.asarray(fi, float), (n,)) for fi in
                              model.f(t, comps, [np.full(n, a)], [np.full(n, w)])], axis=1)
                worst = np.maximum(worst, table.value(t_next, x + lookahead * f, z_next))
            better = worst < best
            best, arg = np.where(better, worst, best), np.where(better, a, arg)
        return arg[:, None]

    return policy


def sample_starts(table, q: float, n: int, margin: float, seed: int = 0, pool: int = 200_000) -> np.ndarray:
    """Up to ``n`` states drawn uniformly from the table's state box with ``W_eps(0, x, max(q, r)) <= -margin``."""
    rng = np.random.default_rng(seed)
    g = table.grid("W_eps")
    d = g.ndim - 1
    lo, hi = np.array(g.lo[:d]), np.array(g.hi[:d])
    x = lo + rng.random((pool, d)) * (hi - lo)
    w = table.value(0.0, x, np.full(pool, max(q, table.budget_resolution)))
    ok = np.nonzero(w <= -margin)[0]
    return x[ok[:n]]


def value_change_per_period(table, ro) -> tuple[float, float]:
    """Along the rollouts ``ro``: the largest ``|W_eps(t_{k+1}, x_{k+1}, z_{k+1}) - W_eps(t_k, x_k, z_k)|`` and the
    largest increase (the exact value does not increase along a closed loop that plays the optimal control)."""
    change = rise = 0.0
    prev = None
    for k in range(len(ro.t)):
        alive = np.isfinite(ro.x[k, :, 0])
        val = np.full(ro.x.shape[1], np.nan)
        if alive.any():
            val[alive] = table.value(ro.t[k], ro.x[k, alive], np.maximum(ro.z[k, alive], table.budget_resolution))
        if prev is not None:
            both = np.isfinite(val) & np.isfinite(prev)
            if both.any():
                d = val[both] - prev[both]
                change = max(change, float(np.max(np.abs(d))))
                rise = max(rise, float(np.max(d)))
        prev = val
    return change, rise


def soundness(table, budgets: Sequence[float] = BUDGETS, n_starts: int = 60, margin: float | None = None,
              dt: float = 0.01, seed: int = 0, pilot: int = 20, wind_names: Sequence[str] | None = None,
              policy: str = "gradient") -> dict[str, Any]:
    """Closed-loop check of the sets (module docstring, "Protocol"); ``policy``: ``gradient`` (the paper's
    ``a*``, :func:`softreach.reach.sim.simulate.table_control`) or ``lookahead`` (:func:`lookahead_control`)."""
    from softreach.reach.sim.simulate import rollout, table_control, table_disturbance

    model = table.model
    ctrl = table_control(table) if policy == "gradient" else lookahead_control(table)
    out: dict[str, Any] = {"policy": policy, "dt": dt, "n_starts_per_Q": n_starts, "seed": seed}
    changes, rises = [0.0], [0.0]
    for q in budgets:
        x = sample_starts(table, q, pilot, 0.0, seed=seed + 99)
        if len(x):
            ro = rollout(model, x, q, ctrl, table_disturbance(table), dt=dt, eps=table.eps)
            c, r = value_change_per_period(table, ro)
            changes.append(c)
            rises.append(r)
    out["dW_per_period"] = max(changes)
    out["dW_rise_per_period"] = max(rises)
    if margin is None:
        margin = 3.0 * max(changes)
    out["margin"] = margin
    totals = {"runs": 0, "hard_violations": 0, "not_landed": 0, "budget_overruns": 0}
    per_q: dict[str, Any] = {}
    for q in budgets:
        x = sample_starts(table, q, n_starts, margin, seed=seed)
        entry: dict[str, Any] = {"starts": int(len(x))}
        if len(x):
            entry["start_altitude_range_m"] = [float(x[:, 0].min()), float(x[:, 0].max())]
            seqs = {"worst_case": table_disturbance(table), **winds(model, seed)}
            for name, dist in seqs.items():
                if wind_names is not None and name not in wind_names:
                    continue
                t0 = time.perf_counter()
                ro = rollout(model, x, q, ctrl, dist, dt=dt, eps=table.eps)
                over = ro.budget_used > q + 1e-3
                res = {"hard_violations": int(ro.hard_violation.sum()), "not_landed": int((~ro.landed).sum()),
                       "budget_overruns": int(over.sum()), "max_budget_used_minus_Q": float(np.max(ro.budget_used - q)),
                       "max_landing_time_s": float(np.nanmax(ro.landing_time)) if ro.landed.any() else None,
                       # where the runs that did not land were at the horizon: altitude [m] and sink rate [m/s]
                       "not_landed_end": [[float(ro.x[ro.steps[j], j, 0]),
                                           float(-ro.x[ro.steps[j], j, 1] * np.sin(ro.x[ro.steps[j], j, 2]))]
                                          for j in np.nonzero(~ro.landed & ~ro.hard_violation)[0]],
                       "wall_s": time.perf_counter() - t0}
                entry[name] = res
                totals["runs"] += len(x)
                totals["hard_violations"] += res["hard_violations"]
                totals["not_landed"] += res["not_landed"]
                totals["budget_overruns"] += res["budget_overruns"]
        per_q[f"Q={q:g}"] = entry
    out["per_Q"] = per_q
    out["totals"] = totals
    return out


def cmd_report(args: argparse.Namespace) -> dict[str, Any]:
    from softreach.reach import load_table

    table = load_table(args.table)
    g = table.grid("W_eps")
    out: dict[str, Any] = {"table": str(args.table), "grid_W": list(g.shape), "spacing_W": list(g.spacing),
                           "budget_resolution_s": table.budget_resolution, "budget_scale": table.budget_scale,
                           "eps": table.eps, "wall_time_s": table.header.get("wall_time")}
    out["sets"] = set_numbers(table, BUDGETS, times=args.times)
    if args.starts > 0:
        for policy in args.policies:
            out[f"soundness_{policy}"] = soundness(table, BUDGETS, n_starts=args.starts, margin=args.margin, dt=args.dt,
                                                   seed=args.seed, policy=policy, wind_names=args.winds)
    out["load_after"] = _load()
    print(json.dumps(out, indent=2))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("solve")
    s.add_argument("--grid", type=int, nargs=3)
    s.add_argument("--budget-points", type=int)
    s.add_argument("--budget-scale", type=float)
    s.add_argument("--eps", type=float, default=1e-3)
    s.add_argument("--accuracy", default="medium", choices=["low", "medium", "high", "very_high"])
    s.add_argument("--dtype", default="float32")
    s.add_argument("--device", default="cpu")
    s.add_argument("--compile", default="auto", choices=["auto", "yes", "no"])
    s.add_argument("--snapshots", type=int)
    s.add_argument("--out", required=True)
    s.add_argument("--no-resume", action="store_true")
    s.add_argument("--quiet", action="store_true")
    s.add_argument("--threads", type=int, default=None,
                   help="torch intra-op threads (default: torch's, i.e. OMP_NUM_THREADS or the core count)")
    s.add_argument("--json")
    r = sub.add_parser("report")
    r.add_argument("table")
    r.add_argument("--starts", type=int, default=60, help="soundness starts per Q (0: skip)")
    r.add_argument("--margin", type=float, default=None)
    r.add_argument("--dt", type=float, default=0.01)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--times", type=float, nargs="+", default=[0.0, 1.0, 2.0])
    r.add_argument("--policies", nargs="+", default=["gradient"], choices=["gradient", "lookahead"])
    r.add_argument("--winds", nargs="+", default=None,
                   help="subset of worst_case tailwind headwind calm switch_0.5s switch_0.1s (default: all)")
    r.add_argument("--json")
    args = ap.parse_args(argv)
    out = cmd_solve(args) if args.cmd == "solve" else cmd_report(args)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
