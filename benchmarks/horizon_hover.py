"""Hovering just above the target late in the episode: how often does a certified start still time out?

Usage::

    softreach solve pointmass --held --grid 41 41 --budget-points 45 --accuracy medium --dtype float32 \\
        --out pm-held41.srt
    OMP_NUM_THREADS=1 python benchmarks/horizon_hover.py --table pm-held41.srt [--exact-periods 1 3]

A policy holds the hover thrust (``u = g``) from rest at heights ``y`` just above the point mass's target band
(``y <= 0.7`` m), starting ``0.02``-``0.1`` s before the horizon, under constant winds ``-10, 0, 10``. For each
start the filter certifies, the run ends landed, with a hard violation or in a timeout; printed per start time and
per ``Lookahead.exact_periods`` (the last sample times before the horizon judged exactly instead of by the
table), with the slowest decision.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter

import numpy as np

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.filters import SafetyFilter, ValueFilter
from softreach.filters.compiled import CompiledDecision
from softreach.reach import load_table

ENV_ID = "softreach/PointMassLanding-v0"
STARTS = (0.9, 0.93, 0.95, 0.96, 0.97, 0.98)
HEIGHTS = (0.7, 0.705, 0.71, 0.72, 0.75, 0.8, 0.9, 1.0, 1.2)
WINDS = (-10.0, 0.0, 10.0)


def run(table, exact_periods: int) -> tuple[Counter, float]:
    """Outcomes per (start time, outcome), and the slowest filtered step [s]."""
    vf = ValueFilter(table, 0.01, target_checks=10)
    vf.lookahead.exact_periods = exact_periods
    vf.compiled = CompiledDecision(vf)  # the decision built with this window
    model = gym.make(ENV_ID).unwrapped
    hover = np.array([model.normalized_action(np.array([model.model.params.gravity]))[0]], dtype=np.float32)
    out, slowest = Counter(), 0.0
    for wind in WINDS:
        env = SafetyFilter(gym.make(ENV_ID, wind="constant", wind_value=wind), value_filter=vf)
        for t0 in STARTS:
            for y in HEIGHTS:
                _, info = env.reset(seed=0, options={"state": [0.0, y], "budget": 0.3, "time": t0})
                if not info["certified"]:
                    out[(t0, "not certified")] += 1
                    continue
                done = False
                while not done:
                    start = time.perf_counter()
                    _, _, term, trunc, info = env.step(hover)
                    slowest = max(slowest, time.perf_counter() - start)
                    done = term or trunc
                out[(t0, "landed" if info["landed"] else "hard" if info["hard_violation"] else "timeout")] += 1
    return out, slowest


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--table", required=True, help="a point-mass table of the sampled-data game (--held)")
    p.add_argument("--exact-periods", type=int, nargs="+", default=[1])
    args = p.parse_args()
    table = load_table(args.table)
    for k in args.exact_periods:
        out, slowest = run(table, k)
        print(f"exact_periods = {k} (slowest step {1e3 * slowest:.0f} ms)")
        for t0 in STARTS:
            row = {o: out[(t0, o)] for o in ("landed", "timeout", "hard", "not certified")}
            print(f"  t0 = {t0:.2f}: " + ", ".join(f"{o} {n}" for o, n in row.items()))
        timeouts = sum(n for (t0, o), n in out.items() if o == "timeout" and t0 <= 0.97)
        certified = sum(n for (t0, o), n in out.items() if o != "not certified" and t0 <= 0.97)
        print(f"  certified starts at t0 <= 0.97 that time out: {timeouts} of {certified}")


if __name__ == "__main__":
    main()
