"""The environments' own numbers against the boxes the filter proves with, for the three built-in systems: the
states at a period's end against the end box widened by ``Lookahead.slack``, and RK4's stage states, where the env
reads the budget's rate, against the boxes the filter charges the budget by (the kernel's box from half a sub-step
on, ``period.may_spend``, and over each quarter of the period, ``period.spent``) widened by ``Lookahead.stage_slack``
(docs/filters.md, "Sound to the last bit")."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from softreach.reach import get_model
from softreach.reach.proof.lookahead import env_slack
from softreach.reach.sim.rk4 import rk4_stages


def _excursions(model, starts: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """How far, per axis, each period's end state lies outside its end box, and each stage state outside each such
    box of its instant: from ``starts`` states uniform over ``hard_box`` with a random candidate each, under every
    corner of the wind box."""
    dt, n, pieces = model.control_period, model.substeps, 4
    h = dt / n
    rng = np.random.default_rng(seed)
    box_lo, box_hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
    cands = np.asarray(model.held_candidates(), dtype=np.float64)
    winds = [list(w) for w in itertools.product(*zip(*model.disturbance_bounds))]
    lo, hi, ends, stage_out = np.empty(model.state_dim), np.empty(model.state_dim), [], []
    for _ in range(starts):
        x0, a = rng.uniform(box_lo, box_hi), cands[rng.integers(len(cands))]
        model.held_box_kernel(model.held_box_params, x0, x0, a, dt, dt, lo, hi)
        end_lo, end_hi = lo.copy(), hi.copy()
        for wind in winds:
            x, t = list(x0), 0.0
            for _ in range(n):
                end, stages = rk4_stages(model.f, t, x, list(a), wind, h)
                for s, state in zip((t, t + h / 2, t + h / 2, t + h), stages):
                    piece = min(int(s / (dt / pieces)), pieces - 1)
                    boxes = [(piece * dt / pieces, (piece + 1) * dt / pieces)] + ([(h / 2, dt)] if s >= h / 2 else [])
                    for s0, s1 in boxes:
                        model.held_box_kernel(model.held_box_params, x0, x0, a, s0, s1, lo, hi)
                        stage_out.append(np.maximum(lo - np.array(state), np.array(state) - hi))
                x, t = [float(v) for v in end], t + h
            ends.append(np.maximum(end_lo - np.array(x), np.array(x) - end_hi))
    return np.array(ends), np.array(stage_out)


@pytest.mark.parametrize("name", ["pointmass", "glider", "dubins"])
def test_the_envs_states_and_stages_lie_in_the_filters_widened_boxes(name):
    """No tolerance beyond the slacks. Dubins's end states lie off the exact motion's end box by RK4's error, up to
    ``2 rk4_error``, which the rounding alone does not cover; the point mass's middle stages off the exact motion by
    up to ``h^2 / 8`` times the acceleration along the altitude, which its state slack does not cover: some lie
    beyond them, so the test tells the slacks' parts apart."""
    model = get_model(name)
    states, stages = env_slack(model, model.control_period, model.substeps)
    ends, stage_out = _excursions(model, 100, 1)
    assert np.isfinite(ends).all() and np.isfinite(stage_out).all()
    assert (ends <= states).all(), (ends.max(axis=0), states)
    assert (stage_out <= stages).all(), (stage_out.max(axis=0), stages)
    h = model.control_period / model.substeps
    if name == "pointmass":
        assert (stage_out > states).any() and stage_out[:, 1].max() > 0.5 * model.rk4_stage_error(h)[1]
    if name == "dubins":
        assert ends[:, :2].max() > 0.5 * model.substeps * model.rk4_error(h)[0]
