"""Where the safety filter's chain of certified steps breaks, and what step came before each break.

    python benchmarks/chain_breaks.py --table pointmass-held.srt [--policies always_max random anti_optimal]
        [--budgets 0.06 0.6] [--starts 3] [--wind worst_case] [--seed 1]

From certified starts, each policy runs through ``ValueFilter`` against the wind (the audit's policies and winds,
``softreach.filters.audit``; one wind piece per period). A step is *uncertified* when no candidate passed the
one-period test there (``info["certified"]`` false). Printed: how many steps were uncertified, how many of them
fell in the witness window before the horizon and how many before it, and, for every *break* (an uncertified
step right after a certified one), the reason of the step before it. A break after a step whose applied action was
the policy's (``pass``) would be a hole in the policy's rule; a break after ``optimal`` means the fallback found
no candidate that keeps the next state certified and applied one that merely passes.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter

import numpy as np

from softreach.reach.sim.integrator import integrate_period
from softreach.filters import ValueFilter
from softreach.filters.audit import _policy, _wind, sample_starts
from softreach.filters.core import REASONS
from softreach.reach import load_table


def run(vf: ValueFilter, policies: list[str], budgets: list[float], starts: int, wind: str, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    model, dt, T = vf.model, vf.dt, vf.lookahead.horizon
    window_start = T - vf.lookahead.exact_periods * dt
    steps = uncertified = in_window = 0
    before_break: Counter = Counter()
    for name in policies:
        for q in budgets:
            for x0 in sample_starts(vf, q, "certified", starts, rng):
                policy, play = _policy(name, vf, rng), _wind(wind, vf, rng, 1)
                x, z, t, was, prev, plan = np.asarray(x0, float), float(q), 0.0, False, None, None
                for k in range(int(round(T / dt))):
                    pol = policy(k, t, x, z)
                    applied, info = vf.filter(t, x, z, pol, plan=plan)
                    plan = info["plan"]
                    active = int(info["reason"]) != 0
                    steps += 1
                    if not bool(info["certified"]):
                        uncertified += 1
                        in_window += int(t >= window_start - 1e-9)
                        if prev is not None and prev[1]:
                            before_break[(name, REASONS[prev[0]])] += 1
                    prev = (int(info["reason"]), bool(info["certified"]))
                    b = play(t, x, z, pol, applied, active, was)
                    was = active
                    xs, cost, _, _ = integrate_period(model, t, list(map(float, x)), list(map(float, applied)),
                                                      list(map(float, b[0])), dt, model.substeps, vf.eps, 1e-6)
                    z -= cost
                    x, t = np.asarray(xs), (k + 1) * dt
                    pt = [np.float64(v) for v in x]
                    if bool(model.landed(t, pt)) or float(model.hard_constraint(t, pt)) > 0:
                        break
    return {"steps": steps, "uncertified": uncertified, "in_window": in_window, "before_break": before_break}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--table", required=True, help="a held table (softreach solve MODEL --held)")
    ap.add_argument("--policies", nargs="+", default=["always_max", "random", "anti_optimal"])
    ap.add_argument("--budgets", type=float, nargs="+", default=[0.06, 0.6])
    ap.add_argument("--starts", type=int, default=3, help="certified starts per policy and budget")
    ap.add_argument("--wind", default="worst_case")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    table = load_table(args.table)
    vf = ValueFilter(table, table.control_period, target_checks=table.model.substeps)
    r = run(vf, args.policies, args.budgets, args.starts, args.wind, args.seed)
    print(f"{args.table}: {r['steps']} steps from certified starts, {r['uncertified']} uncertified "
          f"({r['in_window']} in the witness window, {r['uncertified'] - r['in_window']} before it)")
    print(f"breaks (an uncertified step after a certified one): {sum(r['before_break'].values())}; the step before:")
    for (policy, reason), n in sorted(r["before_break"].items(), key=lambda kv: -kv[1]):
        print(f"  {policy:14s} {reason:12s} {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
