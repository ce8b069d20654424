"""SACConfig reaches SB3's SAC: the horizon stored as terminal, the entropy coefficient's start, n-step returns.

Cheap (a few hundred environment steps, no gradient step): these check the wiring, not that SAC learns."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

import gymnasium as gym  # noqa: E402

from softreach.agents.config import SACConfig, algo_kwargs  # noqa: E402
from softreach.agents.envs import make_env  # noqa: E402


class _LateStart(gym.Wrapper):
    """Every episode starts 0.05 s before the horizon: 5 control periods, too short to land or crash from the
    start box below (speed changes by at most 0.05 s x 70 m/s^2 = 3.5 m/s, altitude by at most 0.5 m), so every
    episode ends by reaching ``T`` (truncated, with the late penalty)."""

    def reset(self, *, seed=None, options=None):
        return self.env.reset(seed=seed, options={**(options or {}), "time": 0.95})


def _collect(cfg: SACConfig, steps: int = 200):
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    venv = DummyVecEnv([lambda: _LateStart(make_env("pointmass", env_kwargs={"init_state_low": (-5.0, 5.0),
                                                                            "init_state_high": (5.0, 12.0)}))])
    venv.seed(0)
    model = SAC("MlpPolicy", venv, seed=0, device="cpu",
                **algo_kwargs(SACConfig(**{**cfg.__dict__, "learning_starts": 10_000, "buffer_size": 1_000})))
    model.learn(steps)  # all steps before learning_starts: random actions, no gradient step
    return model


@pytest.mark.parametrize("terminal", [True, False])
def test_horizon_terminal_reaches_the_replay_buffer(terminal):
    """With ``horizon_terminal`` the step that reaches ``T`` is stored as terminal (the critic's target does not
    bootstrap past it); without it SB3 treats it as a time-limit truncation and bootstraps."""
    model = _collect(SACConfig(horizon_terminal=terminal))
    rb = model.replay_buffer
    n = rb.pos
    samples = rb._get_samples(np.arange(n))
    ends = int(samples.dones.sum())
    episodes = int(rb.dones[:n].sum())  # every episode end, whatever its kind
    assert n == 200 and episodes == 40  # 5 steps per episode
    assert ends == (episodes if terminal else 0)


def test_entropy_coefficient_start_and_nstep():
    """``ent_coef="auto_0.01"`` starts the learned coefficient at 0.01; ``n_steps`` selects SB3's n-step buffer."""
    model = _collect(SACConfig(ent_coef="auto_0.01", n_steps=3), steps=10)
    assert math.isclose(float(model.log_ent_coef.detach().exp()), 0.01, rel_tol=1e-6)
    assert type(model.replay_buffer).__name__ == "NStepReplayBuffer" and model.replay_buffer.n_steps == 3
