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


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(pytest.main([__file__, "-q"]))
