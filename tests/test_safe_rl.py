"""The constrained-RL baselines (PPO-Lagrangian, PPO-Saute): their update rules, and a tiny sweep of every method
so the adapters to the registered environments keep working."""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")
import stable_baselines3  # noqa: F401

from softreach.agents.envs import make_env  # noqa: E402
from softreach.agents.safe_rl import (LagrangeMultiplier, PPOLagrangian, SafeRLConfig, SautePolicy,  # noqa: E402
                                      SauteWrapper, combine_advantages, gae, saute_observation)
from softreach.agents.sweep import SweepRun, SweepSpec, stable_hash  # noqa: E402

#: "over budget" is ``budget_used > Q + 1 ms``: the paper's proxy for a budget kept (spec §2, paper §VI-A:
#: ``W_eps + 1e-3 <= 0``), the rule docs/agents.md states for training counts and evaluations alike
OVER_BUDGET_MARGIN = 1e-3

TINY = {"run": {"eval_freq": 0, "checkpoint_freq": 0}, "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 1}}


# --------------------------------------------------------------------------------------------- the multiplier

def test_multiplier_rises_over_the_limit_and_is_clipped_at_zero():
    lam = LagrangeMultiplier(init=0.5, lr=0.035)
    # Adam's first step is lr * g / (|g| + 1e-8): lambda moves by lr against the loss's gradient -(J_c - d)
    assert lam.update(3.0) == pytest.approx(0.5 + 0.035, abs=1e-6)
    assert lam.update(0.7) > 0.535  # still over the limit: still rising
    down = LagrangeMultiplier(init=0.001, lr=0.035)
    assert down.update(-2.0) == 0.0  # under the limit: 0.001 - 0.035 clipped at 0
    assert down.update(-2.0) == 0.0
    capped = LagrangeMultiplier(init=1.0, lr=0.5, upper=1.2)
    assert capped.update(10.0) == pytest.approx(1.2)
    with pytest.raises(ValueError, match="nan"):
        lam.update(float("nan"))


def test_combined_advantage_penalises_cost_in_proportion_to_lambda():
    rng = np.random.default_rng(0)
    adv_r, adv_c = rng.normal(size=200), rng.normal(size=200)
    std_r = (adv_r - adv_r.mean()) / adv_r.std()
    assert np.allclose(combine_advantages(adv_r, adv_c, 0.0), std_r, atol=1e-6)  # lambda 0: PPO's advantage
    # centred cost advantages: a constant cost added to every step changes nothing
    assert np.allclose(combine_advantages(adv_r, adv_c + 5.0, 2.0), combine_advantages(adv_r, adv_c, 2.0))
    # two steps equal in reward, the second costlier by 1: it loses lambda / (1 + lambda) of advantage
    a = combine_advantages(np.array([1.0, 1.0, -1.0, -1.0]), np.array([0.0, 1.0, 0.0, 0.0]), 3.0)
    assert a[0] - a[1] == pytest.approx(3.0 / 4.0)


def test_gae_matches_sb3_rollout_buffer():
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer

    rng = np.random.default_rng(1)
    n, k = 7, 3
    buf = RolloutBuffer(n, spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,)), n_envs=k, gamma=0.9, gae_lambda=0.8)
    rewards, values = rng.normal(size=(n, k)).astype(np.float32), rng.normal(size=(n, k)).astype(np.float32)
    starts = (rng.random((n, k)) < 0.3).astype(np.float32)
    for t in range(n):
        buf.add(np.zeros((k, 2)), np.zeros((k, 1)), rewards[t], starts[t], __import__("torch").as_tensor(values[t]),
                __import__("torch").zeros(k))
    last_v, last_done = rng.normal(size=k).astype(np.float32), np.array([True, False, True])
    buf.compute_returns_and_advantage(__import__("torch").as_tensor(last_v), last_done)
    adv, ret = gae(rewards, values, starts, last_v, last_done, 0.9, 0.8)
    assert np.allclose(adv, buf.advantages, atol=1e-5) and np.allclose(ret, buf.returns, atol=1e-5)


def _lag_model(budget: float) -> PPOLagrangian:
    from stable_baselines3.common.vec_env import DummyVecEnv

    venv = DummyVecEnv([lambda: make_env("pointmass", budget=budget)] * 2)
    return PPOLagrangian("MlpPolicy", venv, n_steps=4, batch_size=8, n_epochs=1, seed=0, device="cpu",
                         cost_unit=0.01, safe=SafeRLConfig(cost_gamma=0.5))


def test_cost_recorder_measures_cost_in_periods_and_episode_excess():
    from softreach.agents.safe_rl import _CostRecorder

    model = _lag_model(0.3)
    model._last_obs = np.zeros((2, 4), dtype=np.float32)
    rec = _CostRecorder(model)

    class Buf:
        pos = 0

    infos = [{"cost": 0.005}, {"cost": 0.0}]
    rec.locals = {"infos": infos, "dones": np.array([False, False]), "rollout_buffer": Buf}
    rec._on_step()
    assert model._costs[0].tolist() == pytest.approx([0.5, 0.0])  # 5 ms of a 10 ms period: half a period
    term = np.ones(4, dtype=np.float32)
    Buf.pos = 1
    # env 0 ends by its time limit after 5 + 5 ms outside C2 with Q = 30 ms: (10 - 30) / 10 = -2 periods;
    # env 1 ends landed having used nothing of Q = 20 ms: -2 periods as well, and no bootstrap
    rec.locals = {"infos": [{"cost": 0.005, "budget_used": 0.01, "budget": 0.02, "terminal_observation": term,
                             "TimeLimit.truncated": True},
                            {"cost": 0.0, "budget_used": 0.0, "budget": 0.02, "terminal_observation": term}],
                  "dones": np.array([True, True]), "rollout_buffer": Buf}
    rec._on_step()
    assert model._excess == pytest.approx([-2.0, -2.0])
    boot = 0.5 * float(model.cost_value(term[None])[0])  # cost_gamma * V_c(terminal observation)
    assert model._costs[1].tolist() == pytest.approx([0.5 + boot, 0.0], abs=1e-6)
    assert model._ep_cost.tolist() == [0.0, 0.0]


@pytest.mark.parametrize("budget, rises", [(0.0, True), (1.0, False)])
def test_lagrangian_multiplier_follows_the_episodes_cost(budget, rises):
    """Q = 0: every episode's excess is its cost >= 0, and a falling point mass leaves C2, so lambda rises;
    Q = T = 1 s: no episode can use more than T, so the excess is <= 0 and lambda is clipped to 0."""
    model = _lag_model(budget)
    model.learn(400)  # 50 updates of 8 steps
    assert model.lagrange_multiplier > 0.001 if rises else model.lagrange_multiplier == 0.0


# --------------------------------------------------------------------------------------------- Saute

def test_saute_observation_and_penalty_exactly_once_the_budget_is_spent():
    q, scale, n = 0.02, 0.5, 3.0
    plain = make_env("pointmass", budget=q)
    env = SauteWrapper(make_env("pointmass", budget=q), penalty=n, scale=scale)
    assert env.observation_space.shape == (5,)
    opts = {"state": [-9.5, 15.0]}
    o_plain, _ = plain.reset(seed=3, options=opts)
    obs, _ = env.reset(seed=3, options=opts)
    assert obs[-1] == pytest.approx(q / scale) and np.array_equal(obs[:4], o_plain)
    down = np.array([-1.0], dtype=np.float32)  # full downward push: past -10 m/s, then past -15 m/s
    kinds = []
    for _ in range(100):
        o_plain, r_plain, term, trunc, info_p = plain.step(down)
        obs, r, term_s, trunc_s, info = env.step(down)
        z = info_p["budget"]
        assert obs[-1] == pytest.approx(z / scale, abs=1e-6) and np.array_equal(obs[:4], o_plain)
        assert (term_s, trunc_s) == (term, trunc)
        if z < 0:
            assert r == -n and info["saute_penalised"]
        else:
            assert r == r_plain and not info["saute_penalised"]
        kinds.append(z < 0)
        if term or trunc:
            break
    assert False in kinds and True in kinds  # the episode crossed from within the budget to spent
    policy = SautePolicy(type("M", (), {"predict": lambda self, o, deterministic=True: (o, None)})(), scale)
    assert np.array_equal(policy.predict(o_plain)[0], saute_observation(o_plain, scale))


def test_saute_default_scale_is_the_largest_budget():
    assert SauteWrapper(make_env("pointmass"), 1.0).scale == pytest.approx(0.6)
    assert SauteWrapper(make_env("pointmass", budget=0.0), 1.0).scale == pytest.approx(0.01)  # Q = 0: dt
    with pytest.raises(ValueError, match="penalty"):
        SauteWrapper(make_env("pointmass"), 0.0)


# --------------------------------------------------------------------------------------------- the grid

def test_plain_run_ids_are_those_of_earlier_sweeps():
    run = SweepRun(model="pointmass", algo="ppo", rule="none", budget=None, wind="random", seed=0)
    old = {"model": "pointmass", "algo": "ppo", "rule": "none", "budget": None, "wind": "random", "seed": 0,
           "variant": "default", "table": None, "timesteps": None, "n_envs": None, "run_overrides": {},
           "algo_overrides": {}}
    assert run.run_id == f"pointmass-ppo-none-s0-{stable_hash(old)}"
    lag = SweepRun(model="pointmass", algo="ppo", rule="none", budget=None, wind="random", seed=0, method="lag")
    assert lag.run_id.startswith("pointmass-ppo-lag-none-s0-") and lag.run_id != run.run_id


def test_baselines_train_without_the_filter(tmp_path):
    pointmass_table_path = tmp_path / "table.srt"  # the grid and these checks only need the file to exist
    pointmass_table_path.touch()
    spec = SweepSpec(methods=("plain", "lag", "saute"), rules=("none", "switch"), seeds=(0,),
                     tables={"pointmass": str(pointmass_table_path)})
    assert sorted((r.method, r.rule) for r in spec.runs()) == [("lag", "none"), ("plain", "none"),
                                                               ("plain", "switch"), ("saute", "none")]
    with pytest.raises(ValueError, match="'bogus'"):
        SweepSpec(methods=("bogus",), rules=("none",)).check()
    with pytest.raises(ValueError, match="no run"):
        SweepSpec(methods=("lag",), rules=("switch",), tables={"pointmass": str(pointmass_table_path)}).check()
    with pytest.raises(ValueError, match="lambda_lr"):
        SweepSpec(methods=("lag",), rules=("none",), overrides={"safe": {"lambda_lr": -1}}).check()
    with pytest.raises(ValueError, match="algo 'ppo'"):
        SweepSpec(methods=("saute",), algos=("sac",), rules=("none",)).check()


@pytest.mark.process
def test_tiny_sweep_of_every_method(tmp_path):
    """A few hundred steps per method, evaluated without a table: every row done, the training counts equal the
    Monitor's own log of the same episodes, and the figure is drawn. The runs go to a spawned worker process (the
    sweep's local pool)."""
    from softreach.agents.sweep_cli import run_sweep
    from softreach.agents.sweep_report import read_table

    spec = SweepSpec(methods=("plain", "lag", "saute"), rules=("none",), budgets=(0.06,), seeds=(0,),
                     timesteps=256, n_envs=2, overrides=TINY, eval_winds=("random",), eval_budgets=(0.06, 0.3),
                     episodes=2)
    out = tmp_path / "sweep"
    res = run_sweep(spec, out, log=lambda s: None)
    rows = read_table(out / "results.csv")
    assert len(rows) == 6 and {r["status"] for r in rows} == {"done"}
    assert sorted({r["method"] for r in rows}) == ["lag", "plain", "saute"]
    for run in spec.runs():
        train = out / "runs" / run.run_id / "train"
        monitor = []
        for f in sorted((train / "monitor").glob("train-*.monitor.csv")):
            lines = f.read_text().splitlines()[1:]
            monitor += list(csv.DictReader(lines))
        counts = json.loads((train / "training_safety.json").read_text())
        assert counts["steps"] == 256 and counts["episodes"] == len(monitor) > 0
        assert counts["hard_violations"] == sum(m["hard_violation"] == "True" for m in monitor)
        # the run's budget is 0.06 s: overspent = used more than Q + 1 ms
        assert counts["over_budget"] == sum(float(m["budget_used"]) > 0.06 + OVER_BUDGET_MARGIN for m in monitor)
        row = next(r for r in rows if r["run_id"] == run.run_id)
        assert float(row["train_hard_per_100k"]) == pytest.approx(counts["hard_violations"] * 100_000 / 256)
    cfg = json.loads((out / "runs" / spec.runs()[2].run_id / "train" / "config.json").read_text())
    assert cfg["method"]["name"] == "saute" and cfg["method"]["saute_scale"] == pytest.approx(0.06)
    assert (out / "plots" / "violations_vs_return.png").is_file()
    assert res["status"]["done"] == 6
