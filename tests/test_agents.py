"""softreach.agents: training under the filter, evaluation, the JSON schema, the CLI and the demo (short runs)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402
torch.set_num_threads(1)
import stable_baselines3  # noqa: E402, F401

from softreach.agents.config import PPOConfig, RunConfig, SACConfig, algo_kwargs, defaults  # noqa: E402
from softreach.agents.envs import make_env, unwrap_filter  # noqa: E402
from softreach.agents.evaluate import EvalSpec, evaluate, mean_ci, wilson  # noqa: E402
from softreach.agents.report import (AGGREGATE_FIELDS, EPISODE_FIELDS, EVAL_SCHEMA, evaluation_document,  # noqa: E402
                                     validate_evaluation, write_json, write_plots)
from softreach.agents.tables import (TableOracle, in_set, paper_starts, sample_inside, sample_uniform,  # noqa: E402
                                     uniform_box)
from softreach.agents.train import TrainSpec, load_policy, resolve, train  # noqa: E402

#: the paper's proxy for a budget kept (spec §2, paper §VI-A: ``W_eps + 1e-3 <= 0``): one millisecond, in seconds
BUDGET_TOL = 1e-3

DOCS = Path(__file__).resolve().parents[1] / "docs" / "agents.md"

#: tiny PPO settings: one update of 2 x 64 steps
TINY_PPO = {"n_steps": 64, "batch_size": 64, "n_epochs": 1}
TINY_RUN = {"eval_freq": 128, "eval_episodes": 1, "checkpoint_freq": 128}


# --------------------------------------------------------------------------------------------- statistics

def test_wilson_interval_known_values():
    r = wilson(5, 10)
    assert r["value"] == 0.5
    assert r["low"] == pytest.approx(0.2366, abs=1e-4)
    assert r["high"] == pytest.approx(0.7634, abs=1e-4)
    z = wilson(0, 10)
    assert z["value"] == 0.0 and z["low"] == 0.0
    assert z["high"] == pytest.approx(0.2775, abs=1e-4)
    assert wilson(10, 10)["high"] == 1.0 and wilson(10, 10)["low"] == pytest.approx(0.7225, abs=1e-4)
    assert wilson(0, 0)["value"] is None


def test_mean_ci_student_t():
    m = mean_ci([1.0, 2.0, 3.0, 4.0])
    # t_{0.975, 3} = 3.1824, s = 1.29099, half = 3.1824 * 1.29099 / 2
    assert m["mean"] == 2.5
    assert m["high"] - m["mean"] == pytest.approx(3.182446 * 1.290994 / 2, rel=1e-5)
    assert m["min"] == 1.0 and m["max"] == 4.0 and m["n"] == 4
    assert mean_ci([None, float("nan")])["mean"] is None
    one = mean_ci([3.0])
    assert one["low"] == one["high"] == 3.0


# --------------------------------------------------------------------------------------------- config

def test_defaults_and_kwargs():
    d = defaults("pointmass", "ppo")
    assert isinstance(d.run, RunConfig) and isinstance(d.algo, PPOConfig)
    kw = algo_kwargs(d.algo)
    assert kw["n_steps"] == d.algo.n_steps and kw["policy_kwargs"]["net_arch"]["pi"] == list(d.algo.net_arch)
    assert isinstance(defaults("glider", "sac").algo, SACConfig)
    with pytest.raises(ValueError, match="'dqn'"):
        defaults("pointmass", "dqn")
    with pytest.raises(ValueError, match="'plane'"):
        defaults("plane")


def test_resolve_rejects_bad_input(pointmass_table_path):
    with pytest.raises(ValueError, match="'gusty'"):
        resolve(TrainSpec(wind="gusty"))
    with pytest.raises(ValueError, match="1.5"):
        resolve(TrainSpec(budget=1.5))
    with pytest.raises(ValueError, match="adversarial"):
        resolve(TrainSpec(wind="adversarial"))  # no table for b*
    with pytest.raises(ValueError, match="filter"):
        resolve(TrainSpec(run_overrides={"intervention_penalty": 1.0}))
    with pytest.raises(FileNotFoundError, match="nope.srt"):
        resolve(TrainSpec(filter="nope.srt"))
    with pytest.raises(ValueError, match="timesteps"):
        resolve(TrainSpec(timesteps=0))
    run, algo, env = resolve(TrainSpec(filter=str(pointmass_table_path), budget=0.3, wind="adversarial"))
    assert env["budget"] == 0.3 and env["wind"] == "adversarial"


# --------------------------------------------------------------------------------------------- tables

def test_oracle_matches_table(pointmass_table):
    oracle = TableOracle(pointmass_table)
    rng = np.random.default_rng(1)
    agree = 0
    for _ in range(60):
        x = np.array([rng.uniform(-14, 14), rng.uniform(0.5, 17)])
        t, z = rng.uniform(0, 1), rng.uniform(0, 0.9)
        a = oracle.optimal_control(t, x, z)
        b = oracle.worst_disturbance(t, x[None], [z])[0]
        a_ref = pointmass_table.optimal_control(t, x, z)[0]
        b_ref = pointmass_table.worst_disturbance(t, x, z)[0]
        v_ref = float(pointmass_table.value(t, x, z)[0])
        assert oracle.value(t, x, z) == pytest.approx(v_ref, rel=1e-9, abs=1e-9)
        # identical up to ties of a bang-bang switching function (gradient 0 up to rounding: midpoint 0)
        agree += bool(np.allclose(a, a_ref) and np.allclose(b, b_ref))
    assert agree >= 55


def test_start_distributions(pointmass_table):
    rng = np.random.default_rng(0)
    for q in (0.0, 0.3):
        for _ in range(10):
            x = sample_inside(pointmass_table, q, rng)
            assert in_set(pointmass_table, x, q)
    pts = paper_starts(pointmass_table, [0.0, 0.3, 0.6])
    assert [q for _, q in pts] == [0.0, 0.3, 0.6]
    for x, q in pts:
        assert in_set(pointmass_table, x, q)
    # the points need their budget: the Q=0.6 point is not in RA~_0
    assert not in_set(pointmass_table, pts[-1][0], 0.0)
    lo, hi = uniform_box(pointmass_table.model)
    assert lo.tolist() == [-15.0, 0.0] and hi.tolist() == [15.0, 18.0]
    u = np.array([sample_uniform(pointmass_table.model, rng) for _ in range(50)])
    assert np.all(u >= lo) and np.all(u <= hi)


def test_shared_filter_core_decides_like_a_fresh_filter(pointmass_table):
    from softreach.filters import SafetyFilter

    a = make_env("pointmass", filter_table=pointmass_table)
    b = make_env("pointmass", filter_table=pointmass_table)
    fa, fb = unwrap_filter(a), unwrap_filter(b)
    assert fa.value_filter is fb.value_filter  # one margin field for both
    import gymnasium as gym

    fresh = SafetyFilter(gym.make("softreach/PointMassLanding-v0"), pointmass_table)
    rng = np.random.default_rng(3)
    for env in (b, fresh):
        env.reset(seed=5, options={"state": [-2.0, 6.0], "budget": 0.3})
    for _ in range(30):
        act = rng.uniform(-1, 1, size=1).astype(np.float32)
        _, _, t1, tr1, i1 = b.step(act)
        _, _, t2, tr2, i2 = fresh.step(act)
        assert i1["filter_active"] == i2["filter_active"]
        np.testing.assert_array_equal(i1["applied_action"], i2["applied_action"])
        assert i1["margin"] == pytest.approx(i2["margin"])
        if t1 or tr1:
            break


def test_filtered_env_executes_the_filtered_action(pointmass_table):
    """Outside the safe set the filter replaces the policy's action, and that is what the plant gets."""
    env = make_env("pointmass", filter_table=pointmass_table, intervention_penalty=2.0)
    env.reset(seed=0, options={"state": [-14.0, 16.0], "budget": 0.0})  # far outside RA~_0
    _, reward, _, _, info = env.step(np.array([-1.0], dtype=np.float32))
    assert info["filter_active"]
    assert info["applied_action"][0] != pytest.approx(-1.0)
    np.testing.assert_allclose(info["action_physical"], 60.0 * info["applied_action"], rtol=1e-6)
    base = info["reward_landing"] + info["reward_failure"] + info["reward_shaping"]
    assert reward == pytest.approx(base - 2.0)  # the learner is told about the intervention


# --------------------------------------------------------------------------------------------- training

def test_train_with_filter_end_to_end(tmp_path, pointmass_table_path):
    out = tmp_path / "run"
    res = train(TrainSpec(model="pointmass", algo="ppo", filter=str(pointmass_table_path), wind="adversarial",
                          timesteps=256, n_envs=2, seed=1, out=str(out), progress=True,
                          run_overrides=TINY_RUN, algo_overrides=TINY_PPO))
    assert res.model_path.is_file() and res.timesteps >= 256
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["status"] == "done" and cfg["filter"]["table"] == str(pointmass_table_path)
    assert cfg["run"]["intervention_penalty"] == 1.0 and cfg["algo_config"]["n_steps"] == 64
    assert (out / "eval" / "evaluations.npz").is_file()
    assert list((out / "checkpoints").glob("model_*_steps.zip"))
    assert list((out / "monitor").glob("train-*.monitor.csv"))
    model = load_policy(res.model_path)
    assert type(model).__name__ == "PPO"
    obs = np.array([0.0, 5.0, 0.3, 1.0], dtype=np.float32)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (1,) and np.all(np.abs(action) <= 1.0)
    assert load_policy(out).num_timesteps == res.timesteps  # a run directory works too


def test_sac_applied_action_labels(tmp_path, pointmass_table_path):
    """With action_label='applied' the replay buffer holds what the filter let through (a* is bang-bang, so
    exact +-1 entries appear; SAC's own tanh-squashed samples are never exactly +-1)."""
    res = train(TrainSpec(model="pointmass", algo="sac", filter=str(pointmass_table_path), timesteps=200, n_envs=2,
                          out=str(tmp_path / "sac"), progress=False,
                          run_overrides={"eval_freq": 0, "checkpoint_freq": 0},
                          algo_overrides={"action_label": "applied", "learning_starts": 50, "batch_size": 32,
                                          "buffer_size": 1000}))
    from stable_baselines3 import SAC

    model = SAC.load(res.model_path)  # loads as a plain SAC
    assert model.num_timesteps == 200


def test_sac_buffer_holds_applied_actions(pointmass_table_path):
    from stable_baselines3.common.vec_env import DummyVecEnv

    from softreach.agents.config import SACConfig
    from softreach.agents.train import _sac_class

    def run(label):
        venv = DummyVecEnv([lambda: make_env("pointmass", filter_table=pointmass_table_path,
                                             env_kwargs={"init_state_low": (-14.0, 14.0),
                                                         "init_state_high": (-12.0, 16.0)})])
        venv.seed(0)
        kw = algo_kwargs(SACConfig(learning_starts=1000, buffer_size=500, batch_size=16))
        model = _sac_class(label)("MlpPolicy", venv, seed=0, device="cpu", **kw)
        model.learn(120)
        acts = model.replay_buffer.actions[: model.replay_buffer.pos, 0, 0]
        return acts

    applied = run("applied")
    policy = run("policy")
    # starts far outside the set: the filter acts on most steps and applies its held candidates (5 levels over
    # [-60, 60] m/s^2 and the hover thrust g, normalised)
    candidates = np.r_[np.linspace(-1.0, 1.0, 5), 9.8 / 60.0]

    def among(acts):
        return np.abs(np.asarray(acts, dtype=float)[:, None] - candidates[None, :]).min(axis=1) < 1e-6

    assert np.mean(among(applied)) > 0.5
    assert np.mean(among(policy)) < 0.1


# --------------------------------------------------------------------------------------------- evaluation

@pytest.mark.parametrize("wind", ["adversarial", "random"])
def test_optimal_from_inside_is_safe(pointmass_table_path, wind):
    """The table-optimal controller from inside RA~_Q: no hard violation, budget within Q.

    On this coarse test table (41 x 41 x 45, target band ~one altitude cell) a* often stops just above the
    0.7 m target band by the horizon (timeout), so landing is not asserted here; the default table lands every
    episode (docs/agents.md)."""
    for q in (0.3, 0.6):
        res = evaluate(EvalSpec(policy="optimal", table=str(pointmass_table_path), budget=q, wind=wind, episodes=4,
                                starts="inside", seed=2))
        a = res.aggregates
        assert a["hard_violation_rate"]["count"] == 0
        assert a["budget_used"]["max"] <= q + BUDGET_TOL
        assert a["over_budget_rate"]["count"] == 0
        assert all(r["start_inside"] for r in res.episodes)


def test_optimal_from_inside_q0(pointmass_table):
    """Q = 0: no hard violation; the budget used is within one control period plus the table's budget
    resolution (RA~_0 is the set at half a budget cell, and the zero-order-hold a* chatters across v = -10 m/s
    for at most part of a period per switch)."""
    res = evaluate(EvalSpec(policy="optimal", table=str(pointmass_table.path), budget=0.0, wind="adversarial",
                            episodes=4, starts="inside", seed=3))
    assert res.aggregates["hard_violation_rate"]["count"] == 0
    assert res.aggregates["budget_used"]["max"] <= 0.01 + pointmass_table.budget_resolution


def test_filter_rescues_a_bad_policy(pointmass_table_path):
    """Full down-thrust crashes from inside the set without the filter and never with it."""

    class Dive:
        name = "dive"

        def act(self, env, obs):
            return np.array([-1.0], dtype=np.float32)

    spec = dict(table=str(pointmass_table_path), budget=0.3, wind="adversarial", episodes=4, starts="inside", seed=4)
    raw = evaluate(EvalSpec(policy="dive", **spec), policy_obj=Dive())
    safe = evaluate(EvalSpec(policy="dive", filter=str(pointmass_table_path), **spec), policy_obj=Dive())
    assert raw.aggregates["hard_violation_rate"]["count"] == 4
    assert safe.aggregates["hard_violation_rate"]["count"] == 0
    assert safe.aggregates["budget_used"]["max"] <= 0.3 + BUDGET_TOL
    assert safe.aggregates["intervention_rate"]["mean"] > 0
    assert raw.aggregates["intervention_rate"] is None
    # paired: the same starts in both
    assert [r["start_state"] for r in raw.episodes] == [r["start_state"] for r in safe.episodes]


def test_json_schema_round_trip(tmp_path, pointmass_table_path):
    res = evaluate(EvalSpec(policy="random", filter=str(pointmass_table_path), wind="random", episodes=3,
                            starts="uniform", seed=0))
    path = write_json(res, tmp_path / "eval.json")
    doc = json.loads(path.read_text())
    validate_evaluation(doc)
    assert doc["schema"] == EVAL_SCHEMA and len(doc["episodes"]) == 3
    assert set(EPISODE_FIELDS) <= set(doc["episodes"][0])
    assert set(AGGREGATE_FIELDS) <= set(doc["aggregates"])
    # broken documents are refused, naming the problem
    bad = json.loads(path.read_text())
    del bad["episodes"][1]["landed"]
    with pytest.raises(ValueError, match=r"episodes\[1\] lacks 'landed'"):
        validate_evaluation(bad)
    bad = json.loads(path.read_text())
    bad["aggregates"]["landing_rate"]["count"] += 1
    with pytest.raises(ValueError, match="landing_rate"):
        validate_evaluation(bad)
    bad = json.loads(path.read_text())
    bad["aggregates"]["hard_violation_rate"] = 0.5
    with pytest.raises(ValueError, match="hard_violation_rate"):
        validate_evaluation(bad)
    bad = json.loads(path.read_text())
    bad["schema"] = "softreach.evaluation/0"
    with pytest.raises(ValueError, match="schema"):
        validate_evaluation(bad)


def test_json_schema_is_documented():
    text = DOCS.read_text()
    missing = [k for k in list(EPISODE_FIELDS) + list(AGGREGATE_FIELDS) if f"`{k}`" not in text]
    assert not missing, f"docs/agents.md does not document {missing}"
    assert EVAL_SCHEMA in text


def test_plots_are_written(tmp_path, pointmass_table):
    res = evaluate(EvalSpec(policy="optimal", filter=str(pointmass_table.path), budget=0.3, wind="adversarial",
                            episodes=2, starts="paper", seed=0))
    assert [r["budget"] for r in res.episodes] == [0.3, 0.3]
    files = write_plots(res, tmp_path / "plots", table=pointmass_table)
    names = sorted(f.name for f in files)
    assert names == ["budget.png", "budget_hist.png", "interventions.png", "trajectories.png"]
    assert all(f.stat().st_size > 1000 for f in files)
    # json of a run with infinite values stays valid JSON
    doc = evaluation_document(res)
    json.dumps(doc, allow_nan=False)


# --------------------------------------------------------------------------------------------- CLI and demo

def test_cli_evaluate_and_errors(tmp_path, pointmass_table_path, capsys):
    from softreach.cli import main

    out = tmp_path / "e.json"
    rc = main(["evaluate", "pointmass", "--policy", "optimal", "--table", str(pointmass_table_path), "--budget", "0.3",
               "--episodes", "2", "--json", str(out), "--plots", str(tmp_path / "p"), "--quiet"])
    assert rc == 0
    validate_evaluation(json.loads(out.read_text()))
    assert (tmp_path / "p" / "trajectories.png").is_file()
    assert "landing rate" in capsys.readouterr().out
    assert main(["evaluate", "pointmass", "--policy", "optimal", "--table", str(pointmass_table_path),
                 "--budget", "1.5", "--quiet"]) == 2
    assert "1.5" in capsys.readouterr().err
    assert main(["evaluate", "pointmass", "--policy", "optimal", "--quiet"]) == 2
    assert "table" in capsys.readouterr().err
    assert main(["evaluate", "pointmass", "--policy", str(tmp_path / "missing.zip"), "--table",
                 str(pointmass_table_path), "--quiet"]) == 2
    assert main(["train", "pointmass", "--algo", "ppo", "--action-label", "applied", "--quiet"]) == 2
    assert "SAC" in capsys.readouterr().err


def test_cli_train_then_evaluate(tmp_path, pointmass_table_path):
    from softreach.cli import main

    run = tmp_path / "cli_run"
    rc = main(["train", "pointmass", "--filter", str(pointmass_table_path), "--timesteps", "128", "--n-envs", "2",
               "--eval-freq", "0", "--out", str(run), "--quiet"])
    assert rc == 0 and (run / "model.zip").is_file()
    rc = main(["evaluate", "pointmass", "--policy", str(run / "model.zip"), "--filter", str(pointmass_table_path),
               "--episodes", "2", "--plots", str(tmp_path / "plots"), "--quiet"])
    assert rc == 0
    assert (tmp_path / "plots" / "learning_curves.png").is_file()


def test_demo_end_to_end(tmp_path, pointmass_table_path):
    from softreach.agents.demo import run_demo

    out = run_demo(out=tmp_path / "demo", table=str(pointmass_table_path), timesteps=128, episodes=2,
                   budgets=[0.3], winds=["adversarial"], progress=False, n_envs=2)
    text = out["report"].read_text()
    assert "| PPO trained without filter, + filter | adversarial | 0.3 |" in text
    assert "| PPO trained without filter, no filter | adversarial | 0.3 |" in text
    assert "| table-optimal a* | adversarial | 0.3 |" in text
    doc = json.loads((tmp_path / "demo" / "report.json").read_text())
    assert len(doc["evaluations"]) == 3
    filt = next(e for e in doc["evaluations"] if e["key"] == "filtered")
    assert filt["aggregates"]["hard_violation_rate"]["count"] == 0
    assert (tmp_path / "demo" / "plots" / "filtered_trajectories.png").is_file()
    assert math.isfinite(out["results"][0][2].aggregates["return"]["mean"])


# --------------------------------------------------------------------------------------------- curricula

def test_train_unfiltered_evaluated_as_deployed(tmp_path, pointmass_held_table):
    """No filter in training, each periodic evaluation repeated under the filter: its intervention rates are
    recorded (and plotted) and the learner never met the filter."""
    from softreach.agents.report_plots import learning_data, plot_learning_curves

    out = tmp_path / "dep"
    res = train(TrainSpec(model="pointmass", eval_filter=str(pointmass_held_table.path), timesteps=256, n_envs=2,
                          seed=0, out=str(out), progress=False,
                          run_overrides={**TINY_RUN, "eval_freq": 128, "eval_episodes": 2},
                          algo_overrides=TINY_PPO))
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["filter"] is None and cfg["eval_filter"] == str(pointmass_held_table.path)
    iv = np.load(out / "eval" / "interventions.npz")
    assert len(iv["timesteps"]) == len(np.load(out / "eval" / "evaluations.npz")["timesteps"]) >= 2
    # an untrained policy from the environment's starts: the filter acts in some steps, not in all
    assert np.all((iv["intervention_rate"] > 0) & (iv["intervention_rate"] < 1))
    assert np.all((iv["landing_rate"] >= 0) & (iv["landing_rate"] <= 1))
    # the policy's own evaluations (unfiltered) choose the checkpoint; the deployed loop runs beside them
    assert list((out / "monitor").glob("eval-*.monitor.csv")) and list((out / "monitor").glob("deployed-*.monitor.csv"))
    assert "interventions" in learning_data(out)
    assert plot_learning_curves(out, tmp_path / "curves.png").is_file()
    assert res.best_model_path is not None


def test_pretrain_then_filter_and_init(tmp_path, pointmass_held_table):
    table = str(pointmass_held_table.path)
    out = tmp_path / "pre"
    res = train(TrainSpec(model="pointmass", filter=table, timesteps=128, n_envs=2, seed=0, out=str(out),
                          progress=False, run_overrides={**TINY_RUN, "pretrain_steps": 128},
                          algo_overrides=TINY_PPO))
    assert res.timesteps == 256  # both stages counted
    assert list((out / "monitor").glob("pretrain-*.monitor.csv")) and list((out / "monitor").glob("train-*.monitor.csv"))
    # init: with a zero learning rate the weights that come out are the ones that went in
    res2 = train(TrainSpec(model="pointmass", init=str(res.model_path), timesteps=128, n_envs=2, seed=5,
                           out=str(tmp_path / "init"), progress=False, run_overrides=TINY_RUN,
                           algo_overrides={**TINY_PPO, "learning_rate": 0.0}))
    a, b = load_policy(res.model_path).policy.state_dict(), load_policy(res2.model_path).policy.state_dict()
    assert all(np.array_equal(a[k].numpy(), b[k].numpy()) for k in a)
    with pytest.raises(ValueError, match="pretrain"):
        train(TrainSpec(model="pointmass", timesteps=128, out=str(tmp_path / "x"), progress=False,
                        run_overrides={"pretrain_steps": 64}))
    with pytest.raises(FileNotFoundError, match="init policy"):
        train(TrainSpec(model="pointmass", timesteps=128, init=str(tmp_path / "missing.zip"),
                        out=str(tmp_path / "y"), progress=False))
