"""Closed loops under the sampled-data filter against adversaries: held actions, winds that switch inside the
period or in answer to the filter, policies nobody tuned to. A small version of ``benchmarks/audit_filter.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the environments)
from softreach.filters import SafetyFilter, ValueFilter
from softreach.filters.audit import POLICIES, Row, _policy, _wind, audit, run_episode
from softreach.reach import get_model

DT = 0.01
#: issue 10: starts where the earlier filter (pointwise a*, held) left C1 or overspent
ISSUE10 = [((-11.617215615759317, 11.37983843354814), 0.6, "random", "random_step"),
           ((-6.664434729500593, 11.231233561283107), 0.6, "random", "random_step"),
           ((-3.3190450928901623, 9.677689245918149), 0.3, "always_min", "switch_on_filter"),
           ((9.657902043908564, 4.25817065470052), 0.06, "always_max", "constant_min")]


@pytest.fixture(scope="module")
def vf(pointmass_held_table):
    # landing is checked where the env checks it, at its sub-step ends (the audit does the same)
    return ValueFilter(pointmass_held_table, DT, target_checks=get_model("pointmass").substeps)


def test_audit_from_certified_starts_never_leaves_c1_nor_overspends(vf):
    rows = audit(vf, [0.0, 0.3], starts_per_row=2, kinds=("certified",), policies=POLICIES,
                 winds=("worst_case", "switch_inside", "switch_on_filter", "helps_policy"), pieces=4, seed=0,
                 check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    raw = [r for r in rows if not r.filtered]
    assert sum(r.episodes for r in filtered) == len(POLICIES) * 4 * 2 * 2
    assert sum(r.hard_violations for r in filtered) == 0, [r.failures for r in filtered if r.hard_violations]
    assert sum(r.overspends for r in filtered) == 0, [r.failures for r in filtered if r.overspends]
    # the same policies and winds without the filter: the audit can see a failure
    assert sum(r.hard_violations + r.overspends for r in raw) > len(raw)
    # the policy keeps authority: it acts in a good share of the steps
    assert sum(r.policy_steps for r in filtered) > 0.3 * sum(r.steps for r in filtered)


def test_audit_from_starts_on_the_faces_of_c1(vf):
    """Certified starts with one coordinate exactly at its hard bound, where rounding decides."""
    rows = audit(vf, [0.0, 0.3], starts_per_row=2, kinds=("edge",), policies=("random", "always_min", "always_max"),
                 winds=("worst_case", "switch_inside", "switch_on_filter"), pieces=4, seed=1, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    assert sum(r.episodes for r in filtered) == 3 * 3 * 2 * 2
    assert sum(r.hard_violations + r.overspends for r in filtered) == 0, [r.failures for r in filtered]
    assert sum(r.landed for r in filtered) == sum(r.episodes for r in filtered)


@pytest.mark.parametrize("case", range(4))
def test_issue10_starts(vf, case):
    x0, q, pname, wname = ISSUE10[case]
    certified, why, _ = vf.certify(0.0, x0, q)
    rng = np.random.default_rng(case)
    row = Row(pname, wname, "issue10", True)
    out = run_episode(vf, vf, np.asarray(x0), q, _policy(pname, vf, rng), _wind(wname, vf, rng, 4), 4, 2, row, False)
    # held actions are judged over the whole period: none of these runs leaves C1 or overspends, certified or not
    assert not out["hard"] and out["budget_used"] <= q + 1e-9, (why, out)


def test_wrapper_reports_certification_and_keeps_it(vf, pointmass_held_table):
    env = SafetyFilter(gym.make("softreach/PointMassLanding-v0", wind="random"), value_filter=vf)
    rng = np.random.default_rng(3)
    x = rng.uniform([-15, 0], [15, 18], (3000, 2))
    ok, _, _ = vf.certify(0.0, x, 0.3)
    starts = x[ok][:6]
    for i, x0 in enumerate(starts):
        _, info = env.reset(seed=i, options={"state": x0.tolist(), "budget": 0.3})
        assert info["certified"] and info["certified_reason"] == "certified"
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            done = terminated or truncated
            assert not info["hard_violation"] and info["budget_used"] <= 0.3 + 1e-9
        assert info["filter_episode"]["certified_start"]
    _, info = env.reset(options={"state": [0.0, 17.0], "budget": 0.0})
    assert not info["certified"] and info["certified_reason"] == "not_in_set"


def test_glider_audit_from_certified_starts(glider_held_table):
    vf = ValueFilter(glider_held_table, 0.1, target_checks=get_model("glider").substeps)
    assert vf.sampled
    rows = audit(vf, [5.0, 10.0], starts_per_row=2, kinds=("certified", "edge"), policies=("random", "always_max"),
                 winds=("worst_case", "switch_inside", "switch_on_filter"), pieces=2, seed=0, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    # starts on the faces of C1's box too, one coordinate exactly at its bound
    assert sum(r.episodes for r in filtered if r.starts == "certified") >= 12
    assert sum(r.episodes for r in filtered if r.starts == "edge") >= 12
    assert sum(r.hard_violations + r.overspends for r in filtered) == 0, [r.failures for r in filtered]
