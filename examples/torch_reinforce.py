"""Train on a registered softreach environment with plain PyTorch: REINFORCE with a learned value baseline.

Nothing from softreach is imported: ``gymnasium.make("softreach.envs:softreach/PointMassLanding-v0")`` imports
the package that registers the id, the way any Gymnasium environment is used. ``--filter TABLE`` wraps the
environment in the safety filter (the one softreach class used, and only then).

    python examples/torch_reinforce.py --steps 100000                      # point mass, random wind
    python examples/torch_reinforce.py --env-id softreach.envs:softreach/GliderLanding-v0
    python examples/torch_reinforce.py --filter pointmass-held.srt         # learn under the safety filter

Each update collects whole episodes (``--batch-steps`` steps at least), then takes one gradient step on
``-log pi(a|s) * (G - V(s))`` (the advantage normalised) plus the value loss ``(V(s) - G)^2``; ``G`` is the
discounted return-to-go of the scaled reward. Observations are mapped to ``[-1, 1]`` with the observation
space's bounds, actions are a Gaussian sample clipped to the action space (the unclipped sample is what the
log-probability is taken of).
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Callable

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

PM_ID = "softreach.envs:softreach/PointMassLanding-v0"


def make_env(env_id: str = PM_ID, filter_table: str | None = None, **kwargs: Any) -> gym.Env:
    """The registered environment, optionally under the safety filter of ``filter_table``."""
    env = gym.make(env_id, **kwargs)
    if filter_table is not None:
        from softreach.filters import SafetyFilter

        env = SafetyFilter(env, filter_table)
    return env


class Agent(nn.Module):
    """A Gaussian policy (mean from an MLP, one learned log standard deviation per action) and a value MLP."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int = 64):
        super().__init__()
        self.pi = nn.Sequential(nn.Linear(obs_dim, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                                nn.Linear(hidden, act_dim))
        self.v = nn.Sequential(nn.Linear(obs_dim, hidden), nn.Tanh(), nn.Linear(hidden, 1))
        self.log_std = nn.Parameter(torch.full((act_dim,), -0.5))

    def dist(self, obs: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.pi(obs), self.log_std.exp())


def scaler(space: gym.spaces.Box) -> Callable[[np.ndarray], torch.Tensor]:
    """Observation -> tensor in about ``[-1, 1]`` (the Box's bounds; unbounded axes are left as they are)."""
    lo, hi = space.low.astype(np.float64), space.high.astype(np.float64)
    finite = np.isfinite(lo) & np.isfinite(hi) & (hi > lo)
    mid = np.where(finite, (lo + hi) / 2, 0.0)
    half = np.where(finite, (hi - lo) / 2, 1.0)
    return lambda obs: torch.as_tensor((np.asarray(obs, dtype=np.float64) - mid) / half, dtype=torch.float32)


def returns_to_go(rewards: list[float], gamma: float) -> list[float]:
    out, g = [], 0.0
    for r in reversed(rewards):
        g = r + gamma * g
        out.append(g)
    return out[::-1]


def train(env_id: str = PM_ID, steps: int = 100_000, batch_steps: int = 2_000, seed: int = 0, lr: float = 3e-3,
          gamma: float = 0.99, reward_scale: float = 0.01, filter_table: str | None = None,
          env_kwargs: dict[str, Any] | None = None, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Train for ``steps`` environment steps; returns the per-update ``losses``, ``mean_returns``,
    ``landing_rates``, the ``info_keys`` the environment reported, the ``steps`` taken and the ``agent``.

    :param reward_scale: the learner sees ``reward_scale * reward`` (the landing and crash rewards are ``+-100``)
    """
    torch.manual_seed(seed)
    env = make_env(env_id, filter_table, **(env_kwargs or {}))
    low, high = env.action_space.low, env.action_space.high
    to_tensor = scaler(env.observation_space)
    agent = Agent(env.observation_space.shape[0], env.action_space.shape[0])
    opt = torch.optim.Adam(agent.parameters(), lr=lr)
    stats: dict[str, Any] = {"losses": [], "mean_returns": [], "landing_rates": [], "info_keys": set(), "steps": 0}
    episode = 0
    while stats["steps"] < steps:
        obs_b, act_b, ret_b, ep_returns, landed = [], [], [], [], []
        n = 0
        while n < min(batch_steps, steps - stats["steps"]) or not ep_returns:  # whole episodes only
            obs, _ = env.reset(seed=seed * 100_003 + episode)
            episode += 1
            rewards, done, total = [], False, 0.0
            while not done:
                x = to_tensor(obs)
                with torch.no_grad():
                    a = agent.dist(x).sample()
                obs, r, terminated, truncated, info = env.step(np.clip(a.numpy(), low, high))
                stats["info_keys"].update(info)
                obs_b.append(x)
                act_b.append(a)
                rewards.append(reward_scale * float(r))
                total += float(r)
                done = terminated or truncated
            ret_b += returns_to_go(rewards, gamma)
            ep_returns.append(total)
            landed.append(bool(info.get("landed", False)))
            n += len(rewards)
        obs_t, act_t = torch.stack(obs_b), torch.stack(act_b)
        ret_t = torch.tensor(ret_b, dtype=torch.float32)
        value = agent.v(obs_t).squeeze(-1)
        adv = (ret_t - value).detach()
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        logp = agent.dist(obs_t).log_prob(act_t).sum(-1)
        loss = -(logp * adv).mean() + 0.5 * ((value - ret_t) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(agent.parameters(), 0.5)
        opt.step()
        stats["steps"] += n
        stats["losses"].append(loss.item())
        stats["mean_returns"].append(float(np.mean(ep_returns)))
        stats["landing_rates"].append(float(np.mean(landed)))
        log(f"steps {stats['steps']:>7d}  episodes {len(ep_returns):>3d}  return {np.mean(ep_returns):8.1f}  "
            f"landed {np.mean(landed):5.0%}  loss {stats['losses'][-1]:.3f}")
    env.close()
    stats["agent"] = agent
    return stats


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--env-id", default=PM_ID, help=f"a registered id (default {PM_ID})")
    p.add_argument("--steps", type=int, default=100_000, help="environment steps (default 100000)")
    p.add_argument("--batch-steps", type=int, default=2_000, help="steps per update, whole episodes (default 2000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--lr", type=float, default=3e-3)
    p.add_argument("--filter", metavar="TABLE", default=None, help="train under the safety filter of this table")
    p.add_argument("--wind", default="random", help="the environment's wind (default random)")
    args = p.parse_args(argv)
    if args.steps < 1 or args.batch_steps < 1:
        p.error(f"--steps and --batch-steps must be positive, got {args.steps} and {args.batch_steps}")
    torch.set_num_threads(1)  # small networks: more threads only wait on each other
    stats = train(args.env_id, args.steps, args.batch_steps, args.seed, args.lr, filter_table=args.filter,
                  env_kwargs={"wind": args.wind})
    ok = all(math.isfinite(x) for x in stats["losses"])
    print(f"done: {stats['steps']} steps, {len(stats['losses'])} updates, losses finite: {ok}, "
          f"last landing rate {stats['landing_rates'][-1]:.0%}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
