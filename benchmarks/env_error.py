"""How far each built-in model's environment lies outside the boxes the safety filter proves with: its states at the
end of a period outside the exact motion's end box, and the stage states where it reads the budget's rate outside the
boxes the filter charges the budget by; and the allowances that cover them where the model bounds them.

    python benchmarks/env_error.py [--starts 200] [--seed 5] [--models pointmass glider dubins]

For each model: ``--starts`` states uniform over its ``hard_box``, each with a random held candidate
(:meth:`~softreach.reach.model_filter.FilterPart.held_candidates`) and every corner of the disturbance box held for
the period, integrated as the environments do (:func:`softreach.reach.sim.rk4.rk4_stages`, the model's
``control_period`` and ``substeps``). End states against the model's exact-motion end box
(:meth:`~softreach.reach.model_filter.FilterPart.held_enclosure_box`); stage states against the kernel's boxes the
filter bounds the budget's rate over: the quarter of the period holding their instant (``reach.proof.period.spent``)
and, from half a sub-step on, the rest of the period (``period.may_spend``). It prints how many lie outside, the
largest excursion per axis, and the filter's allowances (:func:`softreach.reach.proof.lookahead.env_slack`), or that
the model bounds no error; and how many lie inside the boxes widened by them.
"""

from __future__ import annotations

import argparse
import itertools

import numpy as np

from softreach.reach import get_model
from softreach.reach.proof.lookahead import env_slack
from softreach.reach.sim.rk4 import rk4_stages


def measure(name: str, starts: int, seed: int, pieces: int = 4) -> dict:
    """The excursions of ``name``'s environment outside the filter's boxes (see the module docstring)."""
    model = get_model(name)
    dt, n = model.control_period, model.substeps
    h = dt / n
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
    cands = np.asarray(model.held_candidates(), dtype=np.float64)
    winds = [list(w) for w in itertools.product(*zip(*model.disturbance_bounds))]
    slacks = env_slack(model, dt, n)
    p_lo, p_hi = np.empty(model.state_dim), np.empty(model.state_dim)
    out = {kind: {"runs": 0, "outside": 0, "worst": np.zeros(model.state_dim), "covered": 0}
           for kind in ("end", "stage")}

    def record(kind: str, state: list[float], b_lo: np.ndarray, b_hi: np.ndarray) -> None:
        r, beyond = out[kind], np.maximum(np.maximum(b_lo - state, np.asarray(state) - b_hi), 0.0)
        r["runs"] += 1
        r["outside"] += int(beyond.any())
        r["worst"] = np.maximum(r["worst"], beyond)
        r["covered"] += int(slacks is not None and (beyond <= slacks[kind == "stage"]).all())

    for _ in range(starts):
        x0, a = rng.uniform(lo, hi), cands[rng.integers(len(cands))]
        _, _, end_lo, end_hi = model.held_enclosure_box(0.0, x0[None], x0[None], a[None], dt)
        if not (np.isfinite(end_lo).all() and np.isfinite(end_hi).all()):
            continue
        for wind in winds:
            x, t = list(x0), 0.0
            for _ in range(n):
                end, stages = rk4_stages(model.f, t, x, list(a), wind, h)
                for s, state in zip((t, t + h / 2, t + h / 2, t + h), stages):
                    piece = min(int(s / (dt / pieces)), pieces - 1)
                    boxes = [(piece * dt / pieces, (piece + 1) * dt / pieces)] + ([(h / 2, dt)] if s >= h / 2 else [])
                    for s0, s1 in boxes:
                        model.held_box_kernel(model.held_box_params, x0, x0, a, s0, s1, p_lo, p_hi)
                        record("stage", state, p_lo, p_hi)
                x, t = [float(v) for v in end], t + h
            record("end", x, end_lo[0], end_hi[0])
    return {"model": name, "substeps": n, "dt": dt, "slacks": slacks, **out}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--starts", type=int, default=200, help="random starts per model")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--models", nargs="+", default=["pointmass", "glider", "dubins"])
    args = parser.parse_args(argv)
    np.set_printoptions(precision=3)
    for name in args.models:
        r = measure(name, args.starts, args.seed)
        print(f"{name} ({r['substeps']} RK4 sub-steps of {r['dt'] / r['substeps']:g} s a period):")
        for kind, what in (("end", "end states outside the exact motion's end box"),
                           ("stage", "stage states' comparisons outside the budget's boxes")):
            e = r[kind]
            print(f"    {e['outside']} of {e['runs']} {what}; largest excursion per axis {e['worst']}")
        if r["slacks"] is None:
            print("    the model bounds no RK4 error: the filter proves the exact motion, no state allowance")
        else:
            print(f"    the filter's allowances: states {r['slacks'][0]}, stages {r['slacks'][1]}; inside the widened "
                  f"boxes: {r['end']['covered']} of {r['end']['runs']} end states, {r['stage']['covered']} of "
                  f"{r['stage']['runs']} stage states")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
