"""The last periods before the horizon: a policy that hovers just above the target must still be made to land.

Near ``T`` a table's interpolant, between the node that lands within the period and the one that cannot, promises
landings no held action delivers; a filter that trusted it let a hovering policy through until no action could
land any more. The landing cells read no table: a state they certify lands by ``T`` whatever the policy.
"""

from __future__ import annotations

import numpy as np

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)
from softreach.filters import SafetyFilter, ValueFilter

ENV_ID = "softreach/PointMassLanding-v0"


def _hover_runs(table, winds=(-10.0, 0.0, 10.0)):
    """Hover thrust held from just above the target band, late in the episode: (certified starts, outcomes)."""
    vf = ValueFilter(table, 0.01, target_checks=10)
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


def test_hovering_above_the_target_is_made_to_land(pointmass_held_table):
    starts, outcomes = _hover_runs(pointmass_held_table)
    assert starts >= 6, starts  # the scenario is exercised
    assert outcomes.count("landed") == len(outcomes), outcomes
