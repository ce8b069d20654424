"""How far each built-in model's environment ends a period outside the exact motion's end box that the safety filter
proves with, and the allowance that covers it where the model's RK4 error is known.

    python benchmarks/env_error.py [--starts 200] [--seed 5] [--models pointmass glider dubins]

For each model: ``--starts`` states uniform over its ``hard_box``, each with a random held candidate
(:meth:`~softreach.reach.model_filter.FilterPart.held_candidates`) and every corner of the disturbance box held for
the period; the period is the environments' own (:func:`softreach.reach.sim.integrator.integrate_period` with the
model's ``control_period`` and ``substeps``), its end box the model's exact-motion bound
(:meth:`~softreach.reach.model_filter.FilterPart.held_enclosure_box`). It prints how many end states lie outside
that box, the largest excursion per axis, and the filter's slack (:func:`softreach.reach.proof.lookahead.env_slack`:
RK4's error a sub-step times the sub-steps plus the rounding), or that the model bounds no RK4 error; and whether
every end state lies inside the box widened by the slack.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from softreach.reach import get_model
from softreach.reach.proof.lookahead import env_slack
from softreach.reach.sim.integrator import integrate_period


def measure(name: str, starts: int, seed: int) -> dict:
    """The excursions of ``name``'s environment outside the exact end boxes (see the module docstring)."""
    model = get_model(name)
    dt, substeps = model.control_period, model.substeps
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
    cands = np.asarray(model.held_candidates(), dtype=np.float64)
    winds = [np.array(w) for w in itertools.product(*zip(*model.disturbance_bounds))]
    slack = env_slack(model, dt, substeps)
    worst, outside, inside_slack, runs = np.zeros(model.state_dim), 0, 0, 0
    for _ in range(starts):
        x = rng.uniform(lo, hi)
        a = cands[rng.integers(len(cands))]
        _, _, end_lo, end_hi = model.held_enclosure_box(0.0, x[None], x[None], a[None], dt)
        if not np.isfinite(end_lo).all() or not np.isfinite(end_hi).all():
            continue
        for w in winds:
            # eps and the budget's resolution move only the budget, which this does not read
            end = np.array(integrate_period(model, 0.0, x.tolist(), a.tolist(), w.tolist(), dt, substeps, 1.0,
                                            1e-3)[0])
            beyond = np.maximum(np.maximum(end_lo[0] - end, end - end_hi[0]), 0.0)
            worst = np.maximum(worst, beyond)
            outside += int(beyond.any())
            inside_slack += int(slack is not None and (beyond <= slack).all())
            runs += 1
    return {"model": name, "runs": runs, "outside": outside, "worst": worst, "slack": slack,
            "inside_slack": inside_slack, "substeps": substeps, "dt": dt}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--starts", type=int, default=200, help="random starts per model")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--models", nargs="+", default=["pointmass", "glider", "dubins"])
    args = parser.parse_args(argv)
    np.set_printoptions(precision=3)
    for name in args.models:
        r = measure(name, args.starts, args.seed)
        print(f"{name}: {r['outside']} of {r['runs']} env end states outside the exact motion's end box "
              f"({r['substeps']} RK4 sub-steps of {r['dt'] / r['substeps']:g} s); largest excursion per axis "
              f"{r['worst']}")
        if r["slack"] is None:
            print("    the model bounds no RK4 error: the filter proves the exact motion, no state allowance")
        else:
            print(f"    filter's slack {r['slack']}: {r['inside_slack']} of {r['runs']} inside the widened box")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
