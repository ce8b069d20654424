"""Audit of the sampled-data safety filter: certified region, decision latency, adversarial closed loop.

Measures, for one table (``filters.core.ValueFilter`` at the table's control period unless ``--dt``):

1. the filter's construction time;
2. the certified region at ``t = 0``: for each budget ``Q`` the state-grid nodes where ``vf.certify_start(0, x, Q)``
   holds (a start certified by a period, its cell or a plan of its own), as a measure (nodes x cell volume), beside the table's own ``RA~_Q`` (``set_measure(0, Q)``) and, with
   ``--continuous``, the continuous-time table's ``RA~_Q``, with their ratios. A grid
   reads ``RA~_Q`` at half a budget cell where ``Q`` lies below it (``RA~_0`` above all): the filter's region at
   that same budget is printed below the table, and at ``Q = 0`` the classical set ``{V <= 0}`` of each table,
   which ``RA~_0`` equals in the paper. Grid nodes on the sets' edges (the faces of ``C1`` among them) count for
   whole cells, so the same comparison follows on 20,000 states drawn uniformly over ``C1``: the share of the
   states in each table's set that the filter certifies;
3. latency: one decision (median of 200 calls, us) for a policy action that passes and for one the filter
   replaces, and a batch of 1,024 random states (median of 20 calls, ms); and a reset's search for a start's own plan (``certify_start`` of one
   start no period or cell certifies, median of up to 50);
4. the audit (``agents.audit.audit``): start classes x policies x winds, with and without the filter, one line
   per row and totals per (start class, filtered);
5. point mass only: the four starts of issue 10, each certified or not (and why) and run once.

Commands (from the repository root; the tables are made with ``softreach solve pointmass --held`` and
``softreach solve pointmass --grid 41 41 --budget-points 45 --out /tmp/pm41.srt --quiet --threads 1``)::

    python benchmarks/audit_filter.py --table /tmp/pm-held.srt --continuous /tmp/pm41.srt --json audit.json
    python benchmarks/audit_filter.py --table /tmp/pm41c.srt --continuous /tmp/pm41.srt --starts 1 \\
        --kinds certified --winds worst_case switch_inside --json /tmp/a.json        # a quick check (~25 s)

The full default audit is 5 start classes x 6 policies x 7 winds x 4 budgets x 5 starts, with and without the
filter (8,400 episodes; fewer where a class has fewer starts): expect half an hour or more on one core; ``--no-unneeded`` saves most of the
filtered rows' time. ``OMP_NUM_THREADS=1`` keeps the timings comparable on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from typing import Any, Callable

import numpy as np

from softreach.agents.audit import POLICIES, WINDS, Row, _policy, _wind, audit, run_episode
from softreach.filters.core import PASS, ValueFilter
from softreach.reach import load_table


#: issue 10: (label, (v, y), Q, policy, wind)
ISSUE10 = [("a", (-11.617215615759317, 11.37983843354814), 0.6, "random", "random_step"),
           ("b", (-6.664434729500593, 11.231233561283107), 0.6, "random", "random_step"),
           ("c", (-3.3190450928901623, 9.677689245918149), 0.3, "always_min", "switch_on_filter"),
           ("d", (9.657902043908564, 4.25817065470052), 0.06, "always_max", "constant_min")]


def _median_time(fn: Callable[[], Any], calls: int) -> float:
    """Median wall-clock seconds of one call over ``calls`` calls (after one warm-up call)."""
    fn()
    out = []
    for _ in range(calls):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def certified_region(vf: ValueFilter, table, budgets: list[float], continuous=None,
                     chunk: int = 20000) -> list[dict[str, Any]]:
    """Certified measure per budget beside the table's (and the continuous table's) ``RA~_Q``.

    A grid reads ``RA~_Q`` at ``max(Q, r)``, ``r`` half a budget cell (:meth:`~softreach.reach.tables.query.Table.set_mask`:
    ``W_eps(t, x, 0) >= 0`` everywhere). Where that is above ``Q`` the row also gives the filter's region at that
    same budget (``reference_budget``, ``certified_at_reference_budget``); at ``Q = 0`` it gives the classical set
    ``{V <= 0}`` of each table with ``V`` (``classical_set``, ``continuous_classical_set``), which ``RA~_0`` equals
    in the paper: two readings of one set, whose difference is the grid's."""
    field = "V" if "V" in table.header["fields"] else "W_eps"
    axes = table.state_axes(field)
    X = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)
    cell = table.cell_volume(field)

    def nodes(q: float) -> int:
        return sum(int(np.count_nonzero(vf.certify_start(0.0, X[i:i + chunk], q)[0]))
                   for i in range(0, len(X), chunk))

    out = []
    for q in budgets:
        count = nodes(q)
        r = {"Q": q, "nodes": len(X), "certified_nodes": count, "certified": count * cell,
             "set": table.set_measure(0.0, q)}
        r["certified_over_set"] = r["certified"] / r["set"] if r["set"] else math.nan
        if continuous is not None:
            r["continuous_set"] = continuous.set_measure(0.0, q)
            r["certified_over_continuous"] = r["certified"] / r["continuous_set"] if r["continuous_set"] else math.nan
        ref = max(q, table.budget_resolution)
        if ref > q:
            r["reference_budget"] = ref
            r["certified_at_reference_budget"] = nodes(ref) * cell
        if q == 0:
            for key, tb in (("classical_set", table), ("continuous_classical_set", continuous)):
                if tb is not None and "V" in tb.header["fields"]:
                    r[key] = tb.set_measure(0.0, None)
        out.append(r)
    return out


def _ratio(a: float, b: float) -> float:
    """``a / b``, NaN where ``b`` is 0 (a coarse table's empty set)."""
    return a / b if b else math.nan


def print_reference_notes(region: list[dict[str, Any]]) -> None:
    """The region at the budget where the grid reads ``RA~_Q``, and ``Q = 0`` against the classical sets."""
    for r in region:
        if "reference_budget" in r:
            c = r["certified_at_reference_budget"]
            line = (f"Q = {r['Q']:g}: the held table reads RA~_Q at {r['reference_budget']:.4g} s (half a budget cell); at that "
                    f"budget the filter certifies {c:.2f} ({_ratio(c, r['set']):.3f} of the held RA~_Q")
            line += f", {_ratio(c, r['continuous_set']):.3f} of the continuous one)" if "continuous_set" in r else ")"
            print(line)
        parts = [f"{name} {r[key]:.2f} (certified at Q = 0: {r['certified'] / r[key]:.3f} of it)"
                 for key, name in (("classical_set", "held"), ("continuous_classical_set", "continuous"))
                 if r.get(key)]
        if parts:
            print("Q = 0 against the classical set {V <= 0}: " + ", ".join(parts))


def sampled_region(vf: ValueFilter, table, budgets: list[float], continuous=None, n: int = 20000,
                   seed: int = 0) -> list[dict[str, Any]]:
    """The region by states drawn uniformly over the hard-constraint box at ``t = 0``, where grid nodes (which
    :func:`certified_region` counts, each for its whole cell) weigh the sets' boundaries as much as their inside:
    the share of the states in each table's ``RA~_Q`` (:meth:`~softreach.reach.tables.query.Table.contains`, the rule of
    its ``set_mask`` at the states; at ``Q = 0`` also its classical set ``{V <= 0}``) that the filter certifies."""
    lo, hi = (np.asarray(v, dtype=float) for v in vf.model.hard_box)
    x = np.random.default_rng(seed).uniform(lo, hi, size=(n, len(lo)))
    out = []
    for q in budgets:
        ok, _, _, plans = vf.certify_start(0.0, x, q)
        r: dict[str, Any] = {"Q": q, "states": n, "certified": int(ok.sum()),
                             "certified_by_start_plan": int((plans[:, 0, 0] >= 0).sum()),
                             "certified_by_two_segments": int((plans[:, 1, 0] >= 0).sum())}
        for name, tb in (("held", table), ("continuous", continuous)):
            if tb is None:
                continue
            sets = {"": tb.contains(0.0, x, q)}
            if q == 0 and "V" in tb.header["fields"]:
                sets["_classical"] = tb.contains(0.0, x)
            for tag, inside in sets.items():
                r[f"in_{name}{tag}"] = int(inside.sum())
                r[f"certified_in_{name}{tag}"] = int((ok & inside).sum())
        out.append(r)
    return out


def print_sampled(rows: list[dict[str, Any]]) -> None:
    """One line per budget: certified states, and the share of each set's states that are certified."""
    n = rows[0]["states"] if rows else 0
    print(f"{n:,} states uniform over C1 at t = 0: certified, and certified / in each table's set")
    for r in rows:
        parts = [f"{label} {r['certified_in_' + key]} / {r['in_' + key]} "
                 f"({r['certified_in_' + key] / r['in_' + key]:.3f})"
                 for key, label in (("held", "held RA~_Q"), ("held_classical", "held {V <= 0}"),
                                    ("continuous", "continuous RA~_Q"), ("continuous_classical", "continuous {V <= 0}"))
                 if r.get("in_" + key)]
        print(f"  Q = {r['Q']:g}: {r['certified']} certified ({r['certified_by_start_plan']} by a plan of their own, "
              f"{r['certified_by_two_segments']} of them of two segments); "
              + ", ".join(parts))


def timings(vf: ValueFilter, q: float, seed: int) -> dict[str, Any]:
    """Single decisions (an action that passes, one that is replaced) and a batch of 1,024 states."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(v, dtype=float) for v in vf.model.hard_box)
    x = rng.uniform(lo, hi, size=(4000, len(lo)))
    ok, _, _ = vf.certify(0.0, x, q)
    cands = vf.lookahead.candidates
    pick = None
    for xi in x[ok][:200]:
        _, info = vf.filter(0.0, np.repeat(xi[None], len(cands), axis=0), q, cands)
        passed = info["reason"] == PASS
        if passed.any() and (~passed).any():
            pick = (xi, cands[int(np.argmax(passed))], cands[int(np.argmin(passed))])
            break
    out: dict[str, Any] = {"Q": q}
    if pick is None:
        print(f"  (no certified state at Q={q} with both a passing and a replaced candidate: single timings skipped)")
    else:
        xi, a_pass, a_rep = pick
        out.update(state=xi.tolist(), pass_action=a_pass.tolist(), replaced_action=a_rep.tolist(),
                   single_pass_us=_median_time(lambda: vf.filter(0.0, xi, q, a_pass), 200) * 1e6,
                   single_replaced_us=_median_time(lambda: vf.filter(0.0, xi, q, a_rep), 200) * 1e6)
    # a reset's search for a start's own plan, from starts that no period or cell certifies: all of them, and those
    # the table puts in its set (where a model with two segments also searches two); one start a call
    _, why, _ = vf.certify(0.0, x, q)
    why = np.array(why)
    for key, reasons in (("start_plan_search_ms", ("not_in_set", "no_certified_action")),
                         ("start_plan_search_in_set_ms", ("no_certified_action",))):
        pool = x[np.isin(why, reasons)][:51]
        if len(pool) > 1:
            starts = iter(pool)
            out[key] = _median_time(lambda: vf.certify_start(0.0, next(starts), q), len(pool) - 1) * 1e3
    xb, ab = x[:1024], rng.uniform(vf.a_lo, vf.a_hi, size=(1024, vf.m))
    out["batch1024_ms"] = _median_time(lambda: vf.filter(0.0, xb, q, ab), 20) * 1e3
    return out


def totals(rows: list[Row]) -> list[dict[str, Any]]:
    """Per (start class, filtered): sums, the largest overspend and the mean policy-acting fraction."""
    out = []
    for key in dict.fromkeys((r.starts, r.filtered) for r in rows):
        rs = [r for r in rows if (r.starts, r.filtered) == key]
        acting = [r.policy_steps / r.steps for r in rs if r.steps]
        out.append({"kind": key[0], "filtered": key[1], "episodes": sum(r.episodes for r in rs),
                    "hard_violations": sum(r.hard_violations for r in rs), "overspends": sum(r.overspends for r in rs),
                    "largest_overspend": max(r.largest_overspend for r in rs), "landed": sum(r.landed for r in rs),
                    "policy_acting_mean": statistics.mean(acting) if acting else math.nan,
                    "unneeded": sum(r.unneeded for r in rs), "interventions": sum(r.interventions for r in rs)})
    return out


def issue10(vf: ValueFilter, args) -> list[dict[str, Any]]:
    """The four starts of issue 10, each with a fresh :class:`Row`."""
    rng = np.random.default_rng(args.seed)
    out = []
    for label, x0, q, pname, wname in ISSUE10:
        x0 = np.asarray(x0, dtype=float)
        cert, reason, nxt, _ = vf.certify_start(0.0, x0, q)
        row = Row(pname, wname, f"issue10-{label}", True)
        pol = _policy(pname, vf, np.random.default_rng(rng.integers(1 << 31)))
        wind = _wind(wname, vf, np.random.default_rng(rng.integers(1 << 31)), args.pieces)
        outcome = run_episode(vf, vf, x0, q, pol, wind, args.pieces, args.substeps, row, True)
        out.append({"label": label, "start": x0.tolist(), "Q": q, "policy": pname, "wind": wname,
                    "certified": bool(cert), "reason": reason, "best_next": float(nxt),
                    "hard": bool(row.hard_violations), "budget_used": outcome["budget_used"], "overspent": bool(row.overspends),
                    "landed": bool(row.landed), "row": row.as_dict()})
    return out


def _num(v: Any) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.3f}"


def _clean(v: Any) -> Any:
    """JSON-safe: NaN/inf to None, numpy scalars to Python ones."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    return None if isinstance(v, float) and not math.isfinite(v) else v


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--table", required=True, help="a W_eps or Q_min table, solved with --held for certification")
    p.add_argument("--continuous", help="a continuous-time table of the same model: its RA~_Q for comparison")
    p.add_argument("--dt", type=float, help="control period [s] (default: the table's control_period)")
    p.add_argument("--budgets", type=float, nargs="+", help="budgets Q [s] (default: the model's default_budgets)")
    p.add_argument("--kinds", nargs="+", default=["certified", "boundary", "edge", "planned", "outside"],
                   choices=["certified", "boundary", "edge", "planned", "outside"], metavar="KIND",
                   help="start classes: certified boundary edge planned outside (default all)")
    p.add_argument("--policies", nargs="+", default=list(POLICIES), choices=POLICIES, metavar="POLICY",
                   help=f"policies: {' '.join(POLICIES)} (default all)")
    p.add_argument("--winds", nargs="+", default=list(WINDS), choices=WINDS, metavar="WIND",
                   help=f"winds: {' '.join(WINDS)} (default all)")
    p.add_argument("--starts", type=int, default=5, help="starts per (start class, budget)")
    p.add_argument("--pieces", type=int, default=4, help="wind pieces per control period")
    p.add_argument("--substeps", type=int, default=2, help="integrator substeps per piece")
    p.add_argument("--seed", type=int, default=0, help="seed of starts, policies and winds")
    p.add_argument("--no-unfiltered", action="store_true", help="leave out the unfiltered baseline rows")
    p.add_argument("--no-unneeded", action="store_true", help="skip the unneeded-intervention check (faster)")
    p.add_argument("--json", help="write all results to this JSON file")
    args = p.parse_args(argv)

    table = load_table(args.table)
    dt = args.dt if args.dt is not None else table.control_period
    if dt is None:
        p.error(f"{args.table} has no control_period (not solved with --held): give --dt")
    model = table.model
    budgets = args.budgets or list(model.default_budgets)
    is_pm = model.name == "pointmass"  # the issue's regression starts are point-mass states
    t0 = time.perf_counter()
    # the environment checks landing at its sub-step ends; the filter may count on exactly those
    vf = ValueFilter(table, dt, target_checks=model.substeps)
    res: dict[str, Any] = {"table": args.table, "dt": dt, "build_s": time.perf_counter() - t0, "budgets": budgets,
                           "table_control_period": table.control_period}
    print(f"table {args.table}: grid {table.grid(vf.lookahead.budget_field).shape}, dt {dt} s, table solved for "
          f"{'a period of ' + format(table.control_period, 'g') + ' s' if table.control_period else 'continuous time'}")
    print(f"filter build: {res['build_s'] * 1e3:.1f} ms")

    cont = load_table(args.continuous) if args.continuous else None
    res["region"] = certified_region(vf, table, budgets, cont)
    head = f"\n{'Q':>5s} {'certified':>10s} {'RA~_Q held':>11s} {'ratio':>6s}"
    head += f" {'RA~_Q cont.':>11s} {'ratio':>6s}" if cont else ""
    print(head)
    for r in res["region"]:
        line = f"{r['Q']:5.2f} {r['certified']:10.2f} {r['set']:11.2f} {r['certified_over_set']:6.3f}"
        line += f" {r['continuous_set']:11.2f} {r['certified_over_continuous']:6.3f}" if cont else ""
        print(line)
    print_reference_notes(res["region"])
    res["sampled_region"] = sampled_region(vf, table, budgets, cont, seed=args.seed)
    print_sampled(res["sampled_region"])

    res["timing"] = timings(vf, max(budgets), args.seed)
    tm = res["timing"]
    print(f"\nlatency at Q={tm['Q']}: " + (f"single pass {tm['single_pass_us']:.0f} us, single replaced "
                                        f"{tm['single_replaced_us']:.0f} us, " if "single_pass_us" in tm else "")
          + f"batch of 1024 {tm['batch1024_ms']:.2f} ms")
    if "start_plan_search_ms" in tm:
        print(f"a reset from a start no period or cell certifies (certify_start, median of up to 50): "
              f"{tm['start_plan_search_ms']:.1f} ms"
              + (f", {tm['start_plan_search_in_set_ms']:.1f} ms from those in the table's set"
                 if "start_plan_search_in_set_ms" in tm else ""))

    t0 = time.perf_counter()
    rows = audit(vf, budgets, starts_per_row=args.starts, kinds=args.kinds, policies=args.policies, winds=args.winds,
                 pieces=args.pieces, substeps=args.substeps, seed=args.seed, unfiltered=not args.no_unfiltered,
                 check_unneeded=not args.no_unneeded)
    res["audit_s"] = time.perf_counter() - t0
    res["rows"] = [r.as_dict() for r in rows]
    print(f"\naudit ({res['audit_s']:.1f} s)\n{'kind':10s} {'policy':13s} {'wind':17s} {'filt':>4s} {'eps':>4s} "
          f"{'hard':>4s} {'over':>4s} {'max over':>8s} {'land':>4s} {'acting':>6s} {'unneed':>6s} {'uncert':>6s}")
    for r in res["rows"]:
        print(f"{r['starts']:10s} {r['policy']:13s} {r['wind']:17s} {'yes' if r['filtered'] else 'no':>4s} "
              f"{r['episodes']:4d} {r['hard_violations']:4d} {r['overspends']:4d} {r['largest_overspend']:8.4f} "
              f"{r['landed']:4d} {_num(r['policy_acting']):>6s} {r['unneeded_fraction']:6.3f} {r['uncertified_steps']:6d}")
    res["totals"] = totals(rows)
    print(f"\ntotals\n{'kind':10s} {'filt':>4s} {'eps':>5s} {'hard':>4s} {'over':>4s} {'max over':>8s} {'land':>5s} "
          f"{'acting':>6s} {'unneeded/interv.':>16s}")
    for s in res["totals"]:
        print(f"{s['kind']:10s} {'yes' if s['filtered'] else 'no':>4s} {s['episodes']:5d} {s['hard_violations']:4d} "
              f"{s['overspends']:4d} {s['largest_overspend']:8.4f} {s['landed']:5d} {_num(s['policy_acting_mean']):>6s} "
              f"{str(s['unneeded']) + '/' + str(s['interventions']):>16s}")

    if is_pm:
        res["issue10"] = issue10(vf, args)
        print("\nissue 10 starts")
        for s in res["issue10"]:
            print(f"({s['label']}) x0={s['start']} Q={s['Q']} {s['policy']}/{s['wind']}: certified {s['certified']} "
                  f"({s['reason']}); hard {s['hard']}, budget used {s['budget_used']:.4f} s vs Q {s['Q']} "
                  f"(overspent {s['overspent']}), landed {s['landed']}, uncertified steps "
                  f"{s['row']['uncertified_steps']}, interventions {s['row']['interventions']}/{s['row']['steps']}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(_clean(res), fh, indent=2)
        print(f"\nwrote {args.json}")
    return res


if __name__ == "__main__":
    main()
