"""Seconds for one :func:`softreach.reach.sim.simulate.rollout` of many point-mass states.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_rollout.py [--states 1000] [--substeps 4 10] [--repeats 3]

Protocol: ``--states`` starts drawn uniformly from the point mass's start box (seed 0), budget 0.3 s, control
period 0.01 s over the 1 s horizon, ``eps = 1e-3``; the control is a feedback that dives past the soft speed
limit (``-12 m/s`` above 6 m, so most runs leave ``C2`` and come back: the budget integral's kinks are crossed)
and then brakes towards ``-0.5 m/s``; the wind switches between its extremes every 50 ms (seed 1). One figure per
sub-step count (the model's default first), each the best of ``--repeats`` runs.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from softreach.reach.models import get_model
from softreach.reach.sim.simulate import random_switching, rollout


def _control(t: float, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Dive at -12 m/s above 6 m, then brake towards -0.5 m/s (thrust clipped to the control box)."""
    v_ref = np.where(x[:, 1] > 6.0, -12.0, -0.5)
    return np.clip(9.8 + 20.0 * (v_ref - x[:, 0]), -60.0, 60.0)[:, None]


def main(argv: list[str] | None = None) -> None:
    """Time the rollouts and print one line per sub-step count.

    :param argv: command-line arguments (default: ``sys.argv``)
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--states", type=int, default=1000, help="simulations in the batch")
    parser.add_argument("--substeps", type=int, nargs="*", default=[], help="sub-step counts besides the default")
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure; the best is kept")
    args = parser.parse_args(argv)
    model = get_model("pointmass")
    lo, hi = model.start_box
    x0 = np.random.default_rng(0).uniform(lo, hi, (args.states, 2))
    for sub in [None, *args.substeps]:
        best, ro = np.inf, None
        for _ in range(args.repeats):
            start = time.perf_counter()
            ro = rollout(model, x0, 0.3, _control, random_switching(model, seed=1), dt=0.01, eps=1e-3,
                         **({} if sub is None else {"substeps": sub}))
            best = min(best, time.perf_counter() - start)
        print(f"substeps {sub or 'default':>7}: {best:.3f} s for {args.states} states; landed {int(ro.landed.sum())}, "
              f"left C1 {int(ro.hard_violation.sum())}, mean budget used {np.nanmean(ro.budget_used):.4f} s")


if __name__ == "__main__":
    main()
