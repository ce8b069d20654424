"""The last periods before the horizon: a policy that hovers just above the target must still be made to land.

There the table's certificate is a one-period game against the terminal value, whose interpolant between the
node that lands within the period and the one that cannot promised landings no held action delivers: a hovering
policy was let through until no action could land any more (a timeout from a certified state). The look-ahead
now judges end boxes in the last ``exact_periods`` sample times by a witness (``softreach.filters.table_pass.witness``), so a
state certified in that window lands.
"""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.filters import SafetyFilter, ValueFilter
from softreach.filters.compiled import CompiledDecision

ENV_ID = "softreach/PointMassLanding-v0"


def _hover_runs(table, winds=(-10.0, 0.0, 10.0), cells="auto", exact_periods=None):
    """Hover thrust held from just above the target band, late in the episode: (certified starts, outcomes)."""
    vf = ValueFilter(table, 0.01, target_checks=10, safe_cells=cells, landing_cells=cells)
    if exact_periods is not None:  # the witness window's length (0: none), in the decision built from it
        vf.lookahead.exact_periods = exact_periods
        vf.compiled = CompiledDecision(vf)
    base = gym.make(ENV_ID).unwrapped
    hover = float(base.normalized_action(np.array([base.model.params.gravity]))[0])
    starts, outcomes = 0, []
    for wind in winds:
        env = SafetyFilter(gym.make(ENV_ID, wind="constant", wind_value=wind), value_filter=vf)
        for t0 in (0.93, 0.96, 0.98):
            for y in (0.69, 0.7, 0.705, 0.71, 0.72, 0.75, 0.8, 0.9):
                _, info = env.reset(seed=0, options={"state": [0.0, y], "budget": 0.3, "time": t0})
                if not info["certified"]:
                    continue
                starts += 1
                done = False
                while not done:
                    _, _, term, trunc, info = env.step(np.array([hover], dtype=np.float32))
                    done = term or trunc
                outcomes.append("landed" if info["landed"] else "hard" if info["hard_violation"] else "timeout")
    return starts, outcomes


@pytest.mark.parametrize("cells", ["auto", None])
def test_hovering_above_the_target_is_made_to_land(pointmass_held_table, cells):
    # with the landing cells (proof) and with the table and its witness window alone
    starts, outcomes = _hover_runs(pointmass_held_table, cells=cells)
    assert starts >= 6, starts  # the scenario is exercised
    assert outcomes.count("landed") == len(outcomes), outcomes


def test_the_table_alone_lets_it_time_out(pointmass_held_table):
    """Without the witness window the same runs time out: the scenario is the failure it claims to cure."""
    _, outcomes = _hover_runs(pointmass_held_table, cells=None, exact_periods=0)
    assert "timeout" in outcomes or "hard" in outcomes, outcomes
