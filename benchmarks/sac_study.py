"""Why SB3's SAC does or does not learn the point-mass landing: a small designed set of configurations.

Each configuration is ``softreach train pointmass --algo sac`` (no filter, random gusts, ``Q ~ U[0, 0.6]``) with
some fields of :class:`~softreach.agents.config.SACConfig` / ``RunConfig`` replaced, trained by
:func:`softreach.agents.train.train` itself. Recorded per run: the landing rate of every periodic evaluation (20
deterministic episodes every 10k steps, the training's own ``EvalCallback``), and a final evaluation of
``model.zip`` on 100 episodes (deterministic, the environment's own starts and random gusts, episode seeds
``10**6 + i``, the same for every run), with the wall time.

    OMP_NUM_THREADS=1 python benchmarks/sac_study.py run default alpha01 alpha01_rr1 --timesteps 50000
    OMP_NUM_THREADS=1 python benchmarks/sac_study.py run full --seeds 0 1 2 --timesteps 50000
    OMP_NUM_THREADS=1 python benchmarks/sac_study.py run full --seeds 0 1 --timesteps 100000
    python benchmarks/sac_study.py table                       # the table of every finished run
    python benchmarks/sac_study.py list                        # the configurations and what they change

The rows ``full_*`` past ``full`` (gamma, n-step returns, scaled observations, ``learning_starts``, gSDE, target
entropy) are defined for the next steps of the study.

A finished run (``<out>/<config>-s<seed>-<steps>/result.json``) is skipped when asked again, so a killed sweep
goes on where it stopped.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

OUT = Path("runs/sac_study")

#: every row starts from SACConfig's fields before this study (so a row means the same whatever the defaults are)
_BASE = {"ent_coef": "auto", "target_entropy": "auto", "gamma": 0.99, "gradient_steps": 1, "learning_starts": 2_000,
         "n_steps": 1, "use_sde": False, "horizon_terminal": False}
#: the step that makes SAC's entropy bonus small against the learner's rewards, shared by the later rows
_ALPHA = {**_BASE, "ent_coef": "auto_0.01"}
_FULL = {**_ALPHA, "gradient_steps": -1, "horizon_terminal": True}

#: name -> (what it changes, SACConfig fields, RunConfig fields, observations scaled to [-1, 1])
CONFIGS: dict[str, tuple[str, dict[str, Any], dict[str, Any], bool]] = {
    "default": ("the defaults before this study (ent_coef auto from 1, reward scale 0.01, 1 gradient step per 4 "
                "env steps)", _BASE, {}, False),
    "scale1": ("reward scale 1.0 (entropy bonus small against the rewards)", _BASE, {"reward_scale": 1.0}, False),
    "alpha01": ("ent_coef learned from 0.01 instead of 1", _ALPHA, {}, False),
    "alpha01_rr1": ("+ one gradient step per env step (gradient_steps -1)", {**_ALPHA, "gradient_steps": -1}, {},
                    False),
    "full": ("+ the horizon stored as terminal (no bootstrap at T)", _FULL, {}, False),
    "full_g999": ("+ gamma 0.999", {**_FULL, "gamma": 0.999}, {}, False),
    "full_nstep": ("+ 5-step returns", {**_FULL, "n_steps": 5}, {}, False),
    "full_norm": ("+ observations scaled to [-1, 1] by their bounds", _FULL, {}, True),
    "full_ls10k": ("+ learning_starts 10k", {**_FULL, "learning_starts": 10_000}, {}, False),
    "full_sde": ("+ gSDE exploration", {**_FULL, "use_sde": True}, {}, False),
    "full_h1": ("+ target entropy -1 -> 0 (wider)", {**_FULL, "target_entropy": 0.0}, {}, False),
}


def _scaled_observations(env, learner: bool):
    """Observations mapped affinely from the observation space's bounds onto ``[-1, 1]`` (a fixed map: the same
    for training and evaluation, nothing learned)."""
    import gymnasium as gym

    lo, hi = env.observation_space.low.astype(np.float64), env.observation_space.high.astype(np.float64)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    space = gym.spaces.Box(-1.0, 1.0, shape=lo.shape, dtype=np.float32)
    return gym.wrappers.TransformObservation(env, lambda o: ((o - mid) / half).astype(np.float32), space)


def final_eval(model, normalize: bool, episodes: int = 100) -> dict[str, float]:
    """Landing rate and mean return of ``model`` (deterministic) on ``episodes`` episodes of the training's
    environment (random gusts, the environment's starts and budgets), episode ``i`` seeded ``10**6 + i``."""
    from softreach.agents.envs import make_env

    env = make_env("pointmass", wind="random")
    if normalize:
        env = _scaled_observations(env, False)
    landed, crashed, returns = 0, 0, []
    for i in range(episodes):
        obs, _ = env.reset(seed=10**6 + i)
        ret, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, info = env.step(action)
            ret += float(r)
            done = term or trunc
        landed += bool(info["landed"])
        crashed += bool(info["hard_violation"])
        returns.append(ret)
    return {"landed": landed / episodes, "hard_violations": crashed / episodes, "return": float(np.mean(returns))}


def run_one(name: str, seed: int, timesteps: int, out: Path, eval_freq: int = 10_000) -> dict[str, Any]:
    from softreach.agents.train import TrainSpec, train

    _, algo, run, normalize = CONFIGS[name]
    run_dir = out / f"{name}-s{seed}-{timesteps}"
    result_path = run_dir / "result.json"
    if result_path.is_file():
        return json.loads(result_path.read_text())
    spec = TrainSpec(model="pointmass", algo="sac", timesteps=timesteps, seed=seed, out=str(run_dir),
                     progress=False, algo_overrides=dict(algo),
                     run_overrides={"eval_freq": eval_freq, "checkpoint_freq": 0, **run})
    t0 = time.perf_counter()
    res = train(spec, wrap_env=_scaled_observations if normalize else None)
    wall = time.perf_counter() - t0
    found = run_dir / "eval" / "interventions.npz"
    evals = dict(np.load(found)) if found.is_file() else {"timesteps": np.zeros(0), "landing_rate": np.zeros(0)}
    from stable_baselines3 import SAC

    final = final_eval(SAC.load(res.model_path, device="cpu"), normalize)
    result = {"config": name, "seed": seed, "timesteps": res.timesteps, "wall_s": wall,
              "eval_steps": evals["timesteps"].tolist(), "eval_landed": evals["landing_rate"].tolist(),
              "final": final, "algo_config": res.config["algo_config"], "run": res.config["run"],
              "normalize": normalize, "load_average": os.getloadavg()[0]}
    result_path.write_text(json.dumps(result, indent=1))
    return result


def _last_logged(run_dir: Path, key: str) -> float:
    """The last value of ``key`` in the run's ``progress.csv`` (SB3's logger), NaN if never logged."""
    import csv

    value = math.nan
    with open(run_dir / "progress.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row.get(key):
                value = float(row[key])
    return value


def table(out: Path) -> str:
    """The markdown table of every finished run under ``out`` (``ent_coef``: the learned entropy coefficient at
    the end, to set against the learner's rewards per step, ``reward_scale`` times the environment's)."""
    rows = [json.loads(p.read_text()) for p in sorted(out.glob("*/result.json"))]
    order = list(CONFIGS)
    rows.sort(key=lambda r: (r["timesteps"], order.index(r["config"]) if r["config"] in order else 99, r["seed"]))
    lines = ["| config | seed | steps | periodic evaluations: landed (20 ep. every 10k) | final: landed, hard "
             "violations, return (100 ep.) | ent_coef at the end | wall |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        ev = " ".join(f"{x:.0%}" for x in r["eval_landed"])
        f = r["final"]
        alpha = _last_logged(out / f"{r['config']}-s{r['seed']}-{r['timesteps']}", "train/ent_coef")
        lines.append(f"| {r['config']} | {r['seed']} | {r['timesteps'] // 1000}k | {ev} | {f['landed']:.0%}, "
                     f"{f['hard_violations']:.0%}, {f['return']:.1f} | {alpha:.2g} | {r['wall_s']:.0f} s |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="train and evaluate configurations, one after the other")
    r.add_argument("configs", nargs="+", choices=list(CONFIGS))
    r.add_argument("--seeds", type=int, nargs="+", default=[0])
    r.add_argument("--timesteps", type=int, default=50_000)
    r.add_argument("--eval-freq", type=int, default=10_000, help="steps between periodic evaluations")
    r.add_argument("--out", type=Path, default=OUT)
    t = sub.add_parser("table", help="print the table of the finished runs")
    t.add_argument("--out", type=Path, default=OUT)
    sub.add_parser("list", help="the configurations")
    args = p.parse_args(argv)
    if args.cmd == "list":
        for name, (what, algo, run, norm) in CONFIGS.items():
            print(f"{name:12s} {what}: {algo} {run}{' obs scaled' if norm else ''}")
        return
    if args.cmd == "table":
        print(table(args.out))
        return
    for name in args.configs:
        for seed in args.seeds:
            res = run_one(name, seed, args.timesteps, args.out, args.eval_freq)
            print(f"{name} s{seed}: periodic {res['eval_landed']}, final {res['final']}, {res['wall_s']:.0f} s",
                  flush=True)


if __name__ == "__main__":
    main()
