"""Deploying the budget comparison's policies: ``softreach train --method``, evaluating a Saute policy from the
command line, a sweep that resumes a run killed while it evaluated, and ``--eval-own-budget`` (policies trained at
one ``Q`` beside one policy for every budget)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softreach.agents.sweep import SweepSpec
from softreach.cli import main

TINY = {"run": {"eval_freq": 0, "checkpoint_freq": 0}, "ppo": {"n_steps": 64, "batch_size": 64, "n_epochs": 1}}


def _train(tmp_path, *extra: str) -> int:
    return main(["train", "pointmass", "--timesteps", "128", "--n-envs", "2", "--eval-freq", "0", "--quiet",
                 "--out", str(tmp_path / "run"), *extra])


def test_train_method_saute_trains_and_its_policy_evaluates_on_the_plain_env(tmp_path, capsys):
    """``--method saute`` trains PPO-Saute (its config says so, with the budget's scale) and counts its training
    episodes; ``softreach evaluate`` then flies the saved policy on the plain environment, whose observation lacks
    Saute's extra entry (loaded as a plain SB3 policy it would be refused: one observation short)."""
    assert _train(tmp_path, "--method", "saute", "--budget", "0.06") == 0
    out = capsys.readouterr().out
    run = tmp_path / "run"
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["method"]["name"] == "saute" and cfg["method"]["saute_scale"] == pytest.approx(0.06)
    safety = json.loads((run / "training_safety.json").read_text())
    assert safety["steps"] >= 128 and f"training episodes of these {safety['steps']:,} steps: {safety['episodes']}," in out
    assert main(["evaluate", "pointmass", "--policy", str(run / "model.zip"), "--budget", "0.06", "--wind", "random",
                 "--episodes", "2", "--starts", "env", "--quiet", "--json", str(tmp_path / "ev.json")]) == 0
    doc = json.loads((tmp_path / "ev.json").read_text())
    assert doc["aggregates"]["episodes"] == 2
    from softreach.agents.envs import make_env
    from softreach.agents.policies import check_fits, load_policy

    with pytest.raises(ValueError, match="trained for pointmass but does not fit its environment: observations "
                                         r"Box\(5,\) where pointmass's environment has Box\(4,\)"):
        check_fits(load_policy(run / "model.zip"), make_env("pointmass"), "pointmass", run / "model.zip")


def test_train_method_lag_names_its_default_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["train", "pointmass", "--method", "lag", "--timesteps", "128", "--n-envs", "2", "--eval-freq", "0",
                 "--quiet", "--seed", "3"]) == 0
    cfg = json.loads((tmp_path / "runs" / "train" / "pointmass-ppo-lag-s3" / "config.json").read_text())
    assert cfg["method"]["name"] == "lag" and cfg["method"]["cost_unit_s"] == pytest.approx(0.01)


@pytest.mark.parametrize("extra, words", [
    (["--method", "lag", "--filter", "TABLE"], "trains without the safety filter"),
    (["--method", "saute", "--algo", "sac"], "needs algo 'ppo'"),
    (["--method", "lag", "--resume", "x/model.zip"], "cost critic"),
])
def test_train_method_refuses_what_it_cannot_train(tmp_path, capsys, extra, words):
    """One line naming the problem, before any training (no run folder appears)."""
    table = tmp_path / "t.srt"
    table.touch()
    extra = [str(table) if e == "TABLE" else e for e in extra]
    assert _train(tmp_path, *extra) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()


def test_train_method_is_a_choice(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["train", "pointmass", "--method", "cpo"])
    assert exc.value.code == 2 and "'cpo'" in capsys.readouterr().err


def test_eval_own_budget_evaluates_a_fixed_q_run_only_at_its_q():
    spec = SweepSpec(budgets=(None, 0.3, "0:0.6"), rules=("none",), seeds=(0,), eval_budgets=(0.06, 0.3),
                     eval_winds=("random",), eval_own_budget=True)
    spec.check()
    by_budget = {r.budget: [ev.budget for ev in spec.run_evaluations(r)] for r in spec.runs()}
    assert by_budget == {None: [0.06, 0.3], 0.3: [0.3], (0.0, 0.6): [0.06, 0.3]}
    off = SweepSpec(budgets=(0.3,), rules=("none",), seeds=(0,), eval_budgets=(0.06, 0.3), eval_winds=("random",))
    assert [ev.budget for ev in off.run_evaluations(off.runs()[0])] == [0.06, 0.3]
    with pytest.raises(ValueError, match=r"Q=0\.45.*add 0\.45"):
        SweepSpec(budgets=(0.45,), rules=("none",), seeds=(0,), eval_budgets=(0.06, 0.3), eval_winds=("random",),
                  eval_own_budget=True).check()


def test_eval_own_budget_from_the_command_line():
    from softreach.agents.sweep_cli import spec_from_args
    from softreach.cli import build_parser

    args = build_parser().parse_args(["sweep", "--rules", "none", "--budgets", "default", "0.3", "--eval-own-budget"])
    assert spec_from_args(args).eval_own_budget is True
    args = build_parser().parse_args(["sweep", "--rules", "none"])
    assert spec_from_args(args).eval_own_budget is False


def test_sweep_keeps_a_training_and_evaluations_whose_worker_was_killed(tmp_path, monkeypatch):
    """A worker killed while it evaluated leaves the finished training and the evaluations before the one in
    flight: the rerun trains nothing and evaluates only what is missing."""
    import softreach.agents.safe_train as safe_train
    import softreach.agents.sweep_exec as sweep_exec

    spec = SweepSpec(rules=("none",), budgets=(0.3,), seeds=(0,), timesteps=128, n_envs=2, overrides=TINY,
                     eval_winds=("random",), eval_budgets=(0.06, 0.3), episodes=1)
    run = spec.runs()[0]
    evals = spec.run_evaluations(run)
    run_dir = tmp_path / "runs" / run.run_id
    real = sweep_exec._evaluate
    seen: list[str] = []

    def dies_on_the_second(r, ev, trained, d, cache):
        seen.append(ev.eval_id)
        if len(seen) == 2:
            raise KeyboardInterrupt  # stands for the worker's death: nothing after this point is written
        return real(r, ev, trained, d, cache)

    monkeypatch.setattr(sweep_exec, "_evaluate", dies_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        sweep_exec.run_one(run, evals, str(run_dir))
    left = json.loads((run_dir / "result.json").read_text())
    assert left["status"] == "running" and list(left["evaluations"]) == [evals[0].eval_id]
    assert not sweep_exec.is_done(left, evals)

    def no_training(*a, **k):
        raise AssertionError("trained again")

    monkeypatch.setattr(safe_train, "train_method", no_training)
    monkeypatch.setattr(sweep_exec, "_evaluate", lambda *a: (seen.append(a[1].eval_id), real(*a))[1])
    seen.clear()
    res = sweep_exec.run_one(run, evals, str(run_dir))  # the record says: evaluate the second only
    assert res["status"] == "done" and seen == [evals[1].eval_id] and sweep_exec.is_done(res, evals)
    assert res["evaluations"][evals[0].eval_id] == left["evaluations"][evals[0].eval_id]

    (run_dir / "result.json").unlink()  # a worker that died before writing any record: config.json says done
    seen.clear()
    res = sweep_exec.run_one(run, evals, str(run_dir))
    assert res["status"] == "done" and seen == [ev.eval_id for ev in evals]
    assert res["train"]["model_path"] == left["train"]["model_path"]
    assert res["train"]["safety"] == left["train"]["safety"]


def test_pooled_mean_is_the_mean_and_interval_of_every_episode():
    """From the seeds' (mean, std, n) alone, the pooled mean and its t interval equal those of the raw episodes."""
    from scipy import stats

    from softreach.agents.sweep_methods import pooled_mean

    rng = np.random.default_rng(5)
    seeds = [rng.normal(loc, 3.0, n) for loc, n in ((10.0, 20), (14.0, 17), (7.0, 25))]
    rows = [{"return_mean": float(v.mean()), "return_std": float(v.std(ddof=1)), "return_n": len(v)} for v in seeds]
    every = np.concatenate(seeds)
    got = pooled_mean(rows, "return")
    low, high = stats.t.interval(0.95, len(every) - 1, loc=every.mean(), scale=stats.sem(every))
    assert got["n"] == 62 and got["mean"] == pytest.approx(every.mean(), rel=1e-12)
    assert (got["low"], got["high"]) == (pytest.approx(low, rel=1e-10), pytest.approx(high, rel=1e-10))
    assert pooled_mean([{"return_mean": None, "return_std": None, "return_n": 0}], "return") is None


def test_method_table_pools_the_seeds_of_each_recipe_and_deployment():
    from softreach.agents.sweep_methods import method_lines, paired_lines

    def row(method, rule, budget, filt, seed, landed, hard, over, ret):
        r = {"status": "done", "method": method, "rule": rule, "algo": "ppo", "budget": budget, "seed": seed,
             "eval_wind": "adversarial", "eval_budget": 0.3, "eval_filter": filt,
             "landing_rate_count": landed, "landing_rate_n": 20, "hard_violation_rate_count": hard,
             "hard_violation_rate_n": 20, "over_budget_rate_count": over, "over_budget_rate_n": 20,
             "intervention_rate_mean": 0.02 if filt == "on" else None, "train_hard_per_100k": 400.0 + seed,
             "train_over_per_100k": 200.0}
        for name, m in (("return", ret), ("control_effort", 0.3), ("time_to_land", 0.7)):
            r.update({f"{name}_mean": m, f"{name}_std": 1.0, f"{name}_n": landed if name == "time_to_land" else 20})
        return r

    rows = [row("lag", "none", "default", "off", s, 18 + s, 2 - s, 3, 140.0 + s) for s in (0, 1)] + \
           [row("lag", "none", "default", "on", s, 20, 0, 0, 150.0) for s in (0, 1)] + \
           [row("plain", "switch", "0.3", "on", 0, 20, 0, 0, 155.0)]
    rows[2]["control_effort_mean"], rows[3]["control_effort_mean"] = 0.2, 0.95  # two seeds far apart
    lines = method_lines(rows)
    assert len(lines) == 2 + 3
    lag_alone = next(x for x in lines if "PPO-Lagrangian, Q drawn per episode | alone" in x)
    cells = [c.strip() for c in lag_alone.split("|")]
    assert cells[1] == "adversarial, 0.3" and cells[4] == "2"
    assert cells[5].startswith("92% [") and cells[6] == "3/40" and cells[7] == "6/40"  # 37 of 40 landed
    assert cells[8].startswith("140.5 [") and cells[-2] == "400, 200"
    assert any("PPO trained under the filter (switch), trained at Q = 0.3 | + filter | 1 | 100%" in x for x in lines)
    paired = paired_lines(rows)
    assert len(paired) == 2 + 2
    cells = [c.strip() for c in next(x for x in paired if "PPO-Lagrangian" in x).split("|")]
    assert cells[3] == "2" and cells[4].startswith("92% [") and " / 100% [" in cells[4]
    assert cells[5] == "3/40 / 0/40" and cells[6] == "6/40 / 0/40" and cells[7].startswith("140.5 [")
    assert " / 150.0 [" in cells[7] and cells[-3] == "2.0 %"
    # the effort is a mean squared normalised action, in [0, 1]: the seeds' t interval (0.575 +- 12.7 x 0.375)
    # is cut there, as the episodes' is
    assert cells[8].startswith("0.575 [") and cells[8].endswith("[0.000, 1.000]")
    cells = [c.strip() for c in next(x for x in paired if "switch" in x).split("|")]
    assert cells[4].startswith("— / 100%") and cells[5] == "— / 0/20"
    assert method_lines([]) == paired_lines([]) == []


def test_deployed_figure_draws_one_point_per_run_and_deployment(tmp_path):
    from softreach.agents.sweep_methods import plot_deployed

    def row(run_id, filt, q, hard, ret):
        return {"status": "done", "run_id": run_id, "method": "plain", "rule": "none", "algo": "ppo", "budget": "default",
                "seed": 0, "eval_wind": "random", "eval_budget": q, "eval_filter": filt, "hard_violation_rate_count": hard,
                "over_budget_rate_count": 0, "return_mean": ret, "return_std": 1.0, "return_n": 20}

    rows = [row("a", f, q, 0 if f == "on" else 2, 150.0) for f in ("off", "on") for q in (0.06, 0.3)]
    path = plot_deployed(rows, tmp_path / "d.png")
    assert path.stat().st_size > 10_000
    import matplotlib.image

    h, w = matplotlib.image.imread(path).shape[:2]
    assert w / h == pytest.approx((2 * 4.2 + 4.0) / 4.4, rel=0.02)  # one panel per Q (two here) and the legend's
    assert plot_deployed([{**rows[0], "status": "failed"}], tmp_path / "none.png") is None
