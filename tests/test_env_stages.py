"""The stage states of the environments' RK4, where they read the budget's rate, against the boxes the filter charges
the budget by: the kernel's box from half a sub-step on (``period.may_spend``) and over each quarter of the period
(``period.spent``), widened by ``Lookahead.stage_slack`` (docs/filters.md, "Sound to the last bit")."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from softreach.reach import get_model
from softreach.reach.proof.lookahead import env_slack
from softreach.reach.sim.rk4 import rk4_stages


def _excursions(model, starts: int, seed: int) -> np.ndarray:
    """How far each stage state of a period's sub-steps lies outside each such box of its instant, per axis: from
    ``starts`` states uniform over ``hard_box`` with a random candidate each, under every corner of the wind box."""
    dt, n, pieces = model.control_period, model.substeps, 4
    h = dt / n
    rng = np.random.default_rng(seed)
    box_lo, box_hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
    cands = np.asarray(model.held_candidates(), dtype=np.float64)
    winds = [list(w) for w in itertools.product(*zip(*model.disturbance_bounds))]
    lo, hi, out = np.empty(model.state_dim), np.empty(model.state_dim), []
    for _ in range(starts):
        x0, a = rng.uniform(box_lo, box_hi), cands[rng.integers(len(cands))]
        for wind in winds:
            x, t = list(x0), 0.0
            for _ in range(n):
                end, stages = rk4_stages(model.f, t, x, list(a), wind, h)
                for s, state in zip((t, t + h / 2, t + h / 2, t + h), stages):
                    piece = min(int(s / (dt / pieces)), pieces - 1)
                    boxes = [(piece * dt / pieces, (piece + 1) * dt / pieces)] + ([(h / 2, dt)] if s >= h / 2 else [])
                    for s0, s1 in boxes:
                        model.held_box_kernel(model.held_box_params, x0, x0, a, s0, s1, lo, hi)
                        out.append(np.maximum(lo - np.array(state), np.array(state) - hi))
                x, t = [float(v) for v in end], t + h
    return np.array(out)


@pytest.mark.parametrize("name", ["pointmass", "dubins"])
def test_stage_states_lie_in_the_budgets_boxes_widened_by_the_stage_slack(name):
    """No tolerance beyond ``stage_slack``. The point mass's middle stages lie off the exact motion by up to ``h^2 / 8``
    times the acceleration along the altitude, which its state slack (rounding only) does not cover: some lie beyond
    it, so the test tells the two slacks apart; Dubins's stages lie in the kernel's boxes up to rounding."""
    model = get_model(name)
    states, stages = env_slack(model, model.control_period, model.substeps)
    out = _excursions(model, 100, 1)
    assert (out <= stages).all(), (out.max(axis=0), stages)
    if name == "pointmass":
        h = model.control_period / model.substeps
        assert (out > states).any() and out[:, 1].max() > 0.5 * model.rk4_stage_error(h)[1]
