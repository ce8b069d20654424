"""Steps per second of the softreach landing environments, next to Gymnasium's Pendulum-v1 on the same machine.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_envs.py [--steps 20000] [--vec-steps 1000] [--repeats 3]
                                                      [--async] [--json out.json]

Protocol (the same for every environment, in one process, one after the other):

* **single env**: ``gymnasium.make(id)`` (Gymnasium's default wrappers: TimeLimit, OrderEnforcing,
  PassiveEnvChecker), uniformly random actions drawn beforehand from the action space, ``reset()`` whenever an
  episode ends (resets are part of the cost, as in training). Steps per second of ``env.step`` + resets.
* **unwrapped**: the same loop on ``env.unwrapped`` (``step`` and ``reset`` of the class itself).
* **16 vectorised envs**: ``gymnasium.make_vec(id, num_envs=16, vectorization_mode="sync")`` (autoreset),
  random batched actions; reported as environment steps per second (16 per ``step`` call). ``--async`` adds
  ``AsyncVectorEnv`` (one process per env; on a 2-core machine that mostly measures process switching).

Each figure is the best of ``--repeats`` runs (the machine may be shared). The headline ratio is the point-mass
env's single-env rate over Pendulum-v1's, measured in this run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

import gymnasium as gym

import softreach.envs  # noqa: F401  (registers the ids)

ENVS = ["softreach/PointMassLanding-v0", "softreach/GliderLanding-v0", "Pendulum-v1"]


def bench_single(env_id: str, steps: int, repeats: int, unwrapped: bool) -> float:
    """Best steps per second of one env over ``repeats`` runs of ``steps`` random-action steps."""
    best = 0.0
    for rep in range(repeats):
        env = gym.make(env_id)
        if unwrapped:
            env = env.unwrapped
        env.action_space.seed(rep)
        actions = [env.action_space.sample() for _ in range(steps)]
        env.reset(seed=rep)
        t0 = time.perf_counter()
        for a in actions:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        elapsed = time.perf_counter() - t0
        env.close()
        best = max(best, steps / elapsed)
    return best


def bench_vector(env_id: str, vec_steps: int, repeats: int, mode: str, num_envs: int = 16) -> float:
    """Best environment steps per second of ``num_envs`` vectorised envs."""
    best = 0.0
    for rep in range(repeats):
        venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode)
        venv.action_space.seed(rep)
        actions = [venv.action_space.sample() for _ in range(vec_steps)]
        venv.reset(seed=rep)
        t0 = time.perf_counter()
        for a in actions:
            venv.step(a)
        elapsed = time.perf_counter() - t0
        venv.close()
        best = max(best, num_envs * vec_steps / elapsed)
    return best


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--steps", type=int, default=20000, help="steps per single-env run")
    parser.add_argument("--vec-steps", type=int, default=1000, help="vector steps per run (x16 env steps)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure; the best is kept")
    parser.add_argument("--async", dest="use_async", action="store_true", help="also time AsyncVectorEnv")
    parser.add_argument("--json", help="write the results to this JSON file")
    args = parser.parse_args(argv)

    results: dict = {"machine": {"python": platform.python_version(), "processor": platform.processor(),
                                 "cpu_count": os.cpu_count(), "numpy": np.__version__,
                                 "gymnasium": gym.__version__,
                                 "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS")},
                     "envs": {}}
    header = f"{'env':34s} {'single':>10s} {'unwrapped':>10s} {'16 sync':>10s}"
    if args.use_async:
        header += f" {'16 async':>10s}"
    print(header + "   (steps/s)")
    for env_id in ENVS:
        row = {
            "single": bench_single(env_id, args.steps, args.repeats, unwrapped=False),
            "unwrapped": bench_single(env_id, args.steps, args.repeats, unwrapped=True),
            "vector16_sync": bench_vector(env_id, args.vec_steps, args.repeats, "sync"),
        }
        if args.use_async:
            row["vector16_async"] = bench_vector(env_id, args.vec_steps, args.repeats, "async")
        results["envs"][env_id] = row
        line = f"{env_id:34s} {row['single']:10.0f} {row['unwrapped']:10.0f} {row['vector16_sync']:10.0f}"
        if args.use_async:
            line += f" {row['vector16_async']:10.0f}"
        print(line, flush=True)
    pend = results["envs"]["Pendulum-v1"]
    for env_id in ENVS[:2]:
        mine = results["envs"][env_id]
        ratio = {k: mine[k] / pend[k] for k in mine}
        results["envs"][env_id]["ratio_to_pendulum"] = ratio
        print(f"{env_id} / Pendulum-v1: " + ", ".join(f"{k} {v:.2f}" for k, v in ratio.items()))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return results


if __name__ == "__main__":
    main()
