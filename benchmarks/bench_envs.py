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

Each figure is the best of ``--repeats`` runs, taken round robin over the environments (the machine may be
shared; interleaving keeps a change of load from favouring one of them). The headline ratio is the point-mass
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


def _time_single(env_id: str, steps: int, seed: int, unwrapped: bool) -> float:
    """Steps per second of one run of ``steps`` random-action steps of one env."""
    env = gym.make(env_id)
    if unwrapped:
        env = env.unwrapped
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(steps)]
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    elapsed = time.perf_counter() - t0
    env.close()
    return steps / elapsed


def _time_vector(env_id: str, vec_steps: int, seed: int, mode: str, num_envs: int = 16) -> float:
    """Environment steps per second of one run of ``num_envs`` vectorised envs."""
    venv = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode=mode)
    venv.action_space.seed(seed)
    actions = [venv.action_space.sample() for _ in range(vec_steps)]
    venv.reset(seed=seed)
    t0 = time.perf_counter()
    for a in actions:
        venv.step(a)
    elapsed = time.perf_counter() - t0
    venv.close()
    return num_envs * vec_steps / elapsed


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
    kinds = {"single": lambda e, r: _time_single(e, args.steps, r, unwrapped=False),
             "unwrapped": lambda e, r: _time_single(e, args.steps, r, unwrapped=True),
             "vector16_sync": lambda e, r: _time_vector(e, args.vec_steps, r, "sync")}
    if args.use_async:
        kinds["vector16_async"] = lambda e, r: _time_vector(e, args.vec_steps, r, "async")
    best = {e: {k: 0.0 for k in kinds} for e in ENVS}
    # round robin (every env once per repeat, in turn) so that a change of machine load hits all of them alike
    for rep in range(args.repeats):
        for kind, fn in kinds.items():
            for env_id in ENVS:
                best[env_id][kind] = max(best[env_id][kind], fn(env_id, rep))
    print(f"{'env':34s}" + "".join(f" {k:>15s}" for k in kinds) + "   (env steps/s, best of "
          f"{args.repeats})")
    for env_id in ENVS:
        results["envs"][env_id] = dict(best[env_id])
        print(f"{env_id:34s}" + "".join(f" {best[env_id][k]:15.0f}" for k in kinds), flush=True)
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
