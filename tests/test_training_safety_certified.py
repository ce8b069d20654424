"""What a training run counts about its own safety, split by whether the safety filter certified each episode's
start (``training_safety.json``'s ``certified_starts``): the filter's guarantee covers only those episodes, and an
environment's own starts (the glider's) need not lie in ``RA~_Q``."""

from __future__ import annotations

import numpy as np
import pytest

from softreach.agents.safe_train import TrainingSafetyCounter


def _end(landed=False, hard=False, budget=0.0, certified=None):
    info = {"landed": landed, "hard_violation": hard, "budget": budget}
    if certified is not None:
        info["filter_episode"] = {"certified_start": certified}
    return info


def _feed(counter, rows):
    for infos, dones in rows:
        counter.locals = {"infos": infos, "dones": np.array(dones)}
        counter._on_step()


def test_counts_split_by_certified_start():
    c = TrainingSafetyCounter()
    mid = {"filter_active": True}
    _feed(c, [
        ([mid, mid], [False, False]),
        ([_end(hard=True, budget=-0.5, certified=False), _end(landed=True, certified=True)], [True, True]),
        ([_end(hard=True, certified=False), {}], [True, False]),
        ([_end(budget=-0.002, certified=True), _end(landed=True, certified=False)], [True, True]),
    ])
    s = c.summary()
    assert (s["episodes"], s["landed"], s["hard_violations"], s["over_budget"]) == (5, 2, 2, 2)
    assert s["interventions"] == 2 and s["steps"] == 8
    # certified: the landing of step 2 and the overspend (0.002 s past Q, more than the 1 ms allowance) of step 4
    assert s["certified_starts"] == {"episodes": 2, "landed": 1, "hard_violations": 0, "over_budget": 1}


def test_without_a_filter_nothing_is_claimed_about_certified_starts():
    c = TrainingSafetyCounter()
    _feed(c, [([_end(hard=True), _end(landed=True)], [True, True])])
    s = c.summary()
    assert s["hard_violations"] == 1 and s["certified_starts"] is None
    assert TrainingSafetyCounter().summary()["certified_starts"] is None


def test_certified_flag_is_the_one_reported_at_that_episodes_reset(pointmass_held_table):
    """Through the vectorised environment training uses (auto-reset at an episode's end): each ended episode is
    counted with the ``certified`` its own ``reset`` reported, not the next episode's."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from softreach.agents.envs import make_env

    venv = DummyVecEnv([lambda: make_env("pointmass", wind="random", filter_table=pointmass_held_table,
                                         monitor=True) for _ in range(2)])
    venv.seed(3)
    venv.reset()
    starts = [[bool(venv.reset_infos[i]["certified"])] for i in range(2)]
    expected: list[bool] = []
    c = TrainingSafetyCounter()
    rng = np.random.default_rng(0)
    try:
        while len(expected) < 12:
            obs, rew, dones, infos = venv.step(rng.uniform(-1, 1, size=(2, 1)).astype(np.float32))
            c.locals = {"infos": infos, "dones": dones}
            c._on_step()
            for i in range(2):
                if dones[i]:
                    expected.append(starts[i][-1])
                    starts[i].append(bool(venv.reset_infos[i]["certified"]))
    finally:
        venv.close()
    got = [bool(e[4]) for e in c.ends]
    assert got == expected
    assert 0 < sum(expected) < len(expected)  # both kinds of start, or a shifted flag could go unnoticed
    s = c.summary()["certified_starts"]
    assert s["episodes"] == sum(expected)
    # from a certified start the filter keeps the hard constraint and the budget whatever the policy does
    assert s["hard_violations"] == 0 and s["over_budget"] == 0


def test_sweep_table_and_report_carry_the_certified_counts():
    """results.csv gains the certified-start counts of a run trained under a filter (empty without one), and the
    report's training cell sums them over the seeds beside the per-100k rates it already had."""
    from types import SimpleNamespace

    from softreach.agents.sweep import EvalSetting
    from softreach.agents.sweep_methods import method_lines
    from softreach.agents.sweep_report import table_rows

    ev = EvalSetting(wind="random", budget=0.3, filter="on", episodes=20, starts="certified", seed=0,
                     checkpoint="best", table=None)
    agg = {"landing_rate": {"value": 1.0, "low": 0.8, "high": 1.0, "count": 20, "n": 20},
           "hard_violation_rate": {"value": 0.0, "low": 0.0, "high": 0.2, "count": 0, "n": 20},
           "over_budget_rate": {"value": 0.0, "low": 0.0, "high": 0.2, "count": 0, "n": 20},
           "return": {"mean": 150.0, "std": 1.0, "n": 20}, "control_effort": {"mean": 0.3, "std": 0.1, "n": 20},
           "time_to_land": {"mean": 0.7, "std": 0.1, "n": 20}, "intervention_rate": {"mean": 0.1, "std": 0.0, "n": 20}}

    def item(seed, rule, certified):
        run = SimpleNamespace(run_id=f"r{seed}{rule}", model="pointmass", algo="ppo", method="plain", rule=rule,
                              budget=None, wind="random", variant="default", seed=seed, timesteps=1000, n_envs=2,
                              table="t.srt")
        safety = {"episodes": 30, "landed": 20, "hard_violations": 4, "over_budget": 2,
                  "per_100k": {"hard_violations": 400.0, "over_budget": 200.0}, "certified_starts": certified}
        result = {"status": "done", "train": {"timesteps": 1000, "safety": safety},
                  "evaluations": {ev.eval_id: {"status": "done", "rule": "switch", "aggregates": agg}}}
        return run, [ev], result

    cert = [{"episodes": 12, "landed": 12, "hard_violations": 0, "over_budget": 1},
            {"episodes": 9, "landed": 8, "hard_violations": 2, "over_budget": 0}]
    rows = table_rows([item(0, "switch", cert[0]), item(1, "switch", cert[1]), item(0, "none", None)])
    assert [(r["train_certified_episodes"], r["train_certified_hard_violations"], r["train_certified_over_budget"])
            for r in rows] == [(12, 0, 1), (9, 2, 0), (None, None, None)]
    lines = method_lines(rows)
    filtered = next(x for x in lines if "trained under the filter" in x)
    assert filtered.rstrip(" |").endswith("400, 200; from certified starts 2, 1 in 21 episodes")
    plain = next(x for x in lines if "learned without the filter" in x)
    assert plain.rstrip(" |").endswith("400, 200")


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, "-q"]))
