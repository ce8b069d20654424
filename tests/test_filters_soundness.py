"""Closed loops under the sampled-data filter against adversaries: held actions, winds that switch inside the
period or in answer to the filter, policies nobody tuned to. A small version of ``benchmarks/audit_filter.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the environments)
from softreach.filters import SafetyFilter, ValueFilter
from softreach.agents.audit import POLICIES, Row, _policy, _wind, audit, run_episode
from softreach.filters.plans import NO_PLAN, PLAN_LAND, advance_plan
from softreach.reach import get_model
from softreach.reach.sim.integrator import integrate_period

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


def _planned_starts(vf, q, n, seed, segments=1):
    """Starts that no single period or cell certifies but a plan of their own does (of ``segments`` held
    candidates), with their plans."""
    lo, hi = (np.asarray(v, dtype=float) for v in vf.model.hard_box)
    x = np.random.default_rng(seed).uniform(lo, hi, (3000, len(lo)))
    ok, why, _, plans = vf.certify_start(0.0, x, q)
    one = vf.certify(0.0, x, q)[0]
    planned = plans[:, 0, 0] >= 0
    # a plan is searched only where nothing else certifies, and certifies where it is found
    assert not (planned & one).any() and (ok == (one | planned)).all()
    assert all(why[i] == "certified" for i in np.nonzero(planned)[0])
    pick = planned & ((plans[:, 1, 0] >= 0) == (segments == 2))
    return x[pick][:n], plans[pick][:n]


def _fly_start_plan(vf, x0, plan, q, rng, trials):
    """Hold a start plan's segments in turn against winds that switch between their bounds at three random
    instants of every period (RK4, not the enclosures it was proven with): every run keeps C1 and the budget and
    ends in the landing cells or lands."""
    model, dt = vf.model, vf.dt
    (b_lo,), (b_hi,) = model.disturbance_bounds
    # landing is checked where the environment checks it, at its sub-step ends
    checks = [dt * (i + 1) / vf.target_checks for i in range(vf.target_checks)]
    held = [vf.lookahead.candidates[j] for j, periods, _ in plan if j >= 0 for _ in range(periods)]
    for trial in range(trials):
        x, z, t, landed = list(map(float, x0)), q, 0.0, False
        for a in held:
            cuts = np.unique(np.r_[0.0, rng.uniform(0.0, dt, 3), checks])
            for c0, c1 in zip(cuts[:-1], cuts[1:]):
                b = [b_lo if (trial + rng.integers(2)) % 2 else b_hi]
                x, cost, _, _ = integrate_period(model, t + c0, x, a, b, c1 - c0, 2, vf.eps, 1e-6)
                z -= cost
                assert float(model.hard_constraint(t + c1, x)) <= 0, (x0, plan, x)
                landed = c1 in checks and bool(model.landed(t + c1, x))
                if landed:
                    break
            t += dt
            if landed:
                break
        assert z >= -1e-9, (x0, plan, z)
        assert landed or vf.landing_cells.contains(t, np.asarray(x)[None], z)[0], (x0, plan, x, z)


def test_a_start_plan_holds_what_it_claims(vf):
    """A start's plan of one held candidate: a plan one period shorter fails this (the run is not yet in the
    cells)."""
    q = 0.06
    starts, plans = _planned_starts(vf, q, 8, seed=4)
    assert len(starts) >= 4
    rng = np.random.default_rng(5)
    for x0, plan in zip(starts, plans):
        _fly_start_plan(vf, x0, plan, q, rng, 6)


def test_advance_plan_hands_over_the_second_segment_only_when_the_first_ran_its_course():
    no = np.array(NO_PLAN)
    following, done, second = np.array([3, 2, PLAN_LAND]), np.array([3, 0, PLAN_LAND]), np.array([1, 4, PLAN_LAND])
    assert [list(v) for v in advance_plan(following, second)] == [list(following), list(second)]
    assert [list(v) for v in advance_plan(done, second)] == [list(second), list(no)]
    # an action passed: the filter dropped the plan, and the queued segment goes with it
    assert [list(v) for v in advance_plan(no, second)] == [list(no), list(no)]
    assert [list(v) for v in advance_plan(done, no)] == [list(done), list(no)]


def test_audit_from_starts_certified_only_by_a_plan_of_their_own(vf):
    """The runs from such starts, the plan handed to the first step, never fail; without it they start
    uncertified (so the plan is what certifies them)."""
    rows = audit(vf, [0.06, 0.6], starts_per_row=2, kinds=("planned",), policies=("random", "always_min",
                 "always_max", "anti_optimal"), winds=("worst_case", "switch_inside", "switch_on_filter"), pieces=4,
                 seed=2, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    assert sum(r.episodes for r in filtered) == 4 * 3 * 2 * 2
    assert sum(r.hard_violations + r.overspends for r in filtered) == 0, [r.failures for r in filtered]
    assert sum(r.landed for r in filtered) == sum(r.episodes for r in filtered)
    assert sum(r.uncertified_steps for r in filtered) == 0
    # the plan is what certifies some of them: held without it, no candidate gets a certified step there. The
    # search runs where `certify` finds no candidate ending in certified cells, which does not use the filter's
    # other pass (an end box from whose every state some candidate is admissible), so a planned start may also
    # have a candidate the filter certifies alone
    starts, _ = _planned_starts(vf, 0.6, 8, seed=6)
    by_some = np.zeros(len(starts), bool)
    for j in range(len(vf.lookahead.candidates)):
        _, info = vf.filter(0.0, starts, 0.6, vf.lookahead.candidates[np.full(len(starts), j)])
        by_some |= info["certified"]
    assert len(starts) and not by_some.all()


def test_wrapper_hands_a_start_its_plan(vf):
    env = SafetyFilter(gym.make("softreach/PointMassLanding-v0", wind="random"), value_filter=vf)
    starts, plans = _planned_starts(vf, 0.3, 4, seed=7)
    assert len(starts)
    for i, (x0, plan) in enumerate(zip(starts, plans)):
        _, info = env.reset(seed=i, options={"state": x0.tolist(), "budget": 0.3})
        assert info["certified"] and info["certified_reason"] == "certified"
        assert np.array_equal(info["start_plan"], plan)
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(env.action_space.sample())
            done = terminated or truncated
            assert info["certified"] and not info["hard_violation"] and info["budget_used"] <= 0.3 + 1e-9
        assert info["landed"]


def test_glider_audit_from_certified_starts(glider_held_table):
    vf = ValueFilter(glider_held_table, 0.1, target_checks=get_model("glider").substeps)
    rows = audit(vf, [5.0, 10.0], starts_per_row=2, kinds=("certified", "edge", "planned"),
                 policies=("random", "always_max"),
                 winds=("worst_case", "switch_inside", "switch_on_filter"), pieces=2, seed=0, check_unneeded=False)
    filtered = [r for r in rows if r.filtered]
    # starts on the faces of C1's box too, one coordinate exactly at its bound
    assert sum(r.episodes for r in filtered if r.starts == "certified") >= 12
    assert sum(r.episodes for r in filtered if r.starts == "edge") >= 12
    # and starts that only a plan of their own certifies
    assert sum(r.episodes for r in filtered if r.starts == "planned") >= 12
    assert sum(r.hard_violations + r.overspends for r in filtered) == 0, [r.failures for r in filtered]


#: glider states that no single held angle from the state certifies at Q = 5 but two in sequence do (by the
#: packaged cells; found by CompiledDecision.start_plans with every row searched for two segments)
TWO_ANGLE_STARTS = [[9.292976274617553, 81.54197091844232, -0.045972736491441055],
                    [1.5974903238648426, 80.98291223616016, -0.022155006349714453],
                    [10.58611239445255, 81.63657903203169, -0.051038693539694174],
                    [1.7119242801694132, 80.85957148337502, -0.0029189124023140736]]


def test_glider_start_plans_of_two_angles_in_sequence(glider_held_table):
    """A plan may hold two angles in turn: flown against switching winds each keeps C1 and the budget and ends in
    the landing cells, and filtered runs from such starts, the second segment handed over as the first ends, never
    fail under adversarial winds."""
    vf = ValueFilter(glider_held_table, 0.1, target_checks=get_model("glider").substeps)
    q = 5.0
    x = np.asarray(TWO_ANGLE_STARTS)
    assert not vf.certify(0.0, x, q)[0].any()
    plans = vf.compiled.start_plans(np.zeros(len(x)), x, np.full(len(x), q), vf.start_periods,
                                    np.ones(len(x), bool))
    two = plans[:, 1, 0] >= 0
    assert two.sum() >= 3, plans
    rng = np.random.default_rng(10)
    for x0, plan in zip(x[two], plans[two]):
        assert plan[0, 1] >= 1 and plan[1, 1] >= 1
        _fly_start_plan(vf, x0, plan, q, rng, 4)
        for pname, wname in (("random", "switch_on_filter"), ("always_max", "worst_case"),
                             ("anti_optimal", "switch_inside")):
            row = Row(pname, wname, "planned", True)
            out = run_episode(vf, vf, x0, q, _policy(pname, vf, rng), _wind(wname, vf, rng, 2), 2, 2, row, False,
                              start_plan=plan)
            assert not out["hard"] and out["budget_used"] <= q + 1e-9 and out["landed"], (x0, plan, pname, wname)
            assert row.uncertified_steps == 0, (x0, plan, pname, wname)
