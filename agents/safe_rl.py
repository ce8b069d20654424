"""The constrained-RL baselines of the budget comparison: PPO-Lagrangian and PPO-Saute on Stable-Baselines3.

OmniSafe (the reference implementations) cannot be installed beside softreach: every release of its
dependency safety-gymnasium pins ``gymnasium==0.28.1`` (0.2.0: ``0.26.3``) and softreach needs
``gymnasium>=1.0`` (``pip install omnisafe==0.5.0 'gymnasium>=1.0'``: ``ResolutionImpossible``). So both are
implemented here on SB3's PPO, each update rule following the cited source:

* **PPO-Lagrangian** (:class:`PPOLagrangian`): Ray, Achiam & Amodei 2019, "Benchmarking Safe Exploration in Deep
  RL", Section 5.2 (Lagrangian methods); OmniSafe ``omnisafe/algorithms/on_policy/naive_lagrange/ppo_lag.py``
  and ``omnisafe/common/lagrange.py``. A second critic learns the cost value; before each policy update the
  multiplier takes one Adam step on ``-lambda * (J_c - d)`` and is clipped at 0 (:class:`LagrangeMultiplier`);
  the policy's advantage is ``(A_r - lambda * A_c) / (1 + lambda)`` with ``A_r`` standardised and ``A_c``
  centred over the rollout (OmniSafe ``omnisafe/common/buffer/onpolicy_buffer.py``, ``get``). Defaults are
  OmniSafe's ``configs/on-policy/PPOLag.yaml``: ``lambda_lr = 0.035``, ``lagrangian_multiplier_init = 0.001``,
  Adam, GAE ``lam_c = 0.95``.
* **Saute** (:class:`SauteWrapper`): Sootla et al. ICML 2022, "Saute RL: Almost Surely Safe Reinforcement Learning
  Using State Augmentation", Section 4 (the safety state ``z_{t+1} = (z_t - c_t) / gamma_c``, ``z_0 = d``, the
  reward replaced by ``-n`` once ``z`` is spent) and OmniSafe ``omnisafe/adapter/saute_adapter.py`` (the
  normalised safety state appended to the observation). ``gamma_c = 1``: the budget here is undiscounted.

The environment's cost is ``info["cost"]``, the time outside ``C2`` in the step [s]; an episode's constraint is
``sum(cost) <= Q`` with ``Q`` the episode's budget. With the budget drawn per episode the Lagrangian's
``J_c - d`` is the mean over finished episodes of ``sum(cost) - Q`` (for a fixed ``Q``, OmniSafe's
``mean episode cost - cost_limit``). Costs are measured in control periods (``cost / dt``): a step spent wholly
outside ``C2`` costs 1, safety-gymnasium's per-step indicator scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

from .config import METHODS

#: the observation's entries after the physical state: remaining budget ``z``, then time left ``T - t``
Z_INDEX = -2


@dataclass(frozen=True)
class SafeRLConfig:
    """Settings of the baselines (the ``safe`` section of a sweep's overrides).

    :param lambda_lr: the multiplier's Adam step size (OmniSafe PPOLag: 0.035)
    :param lambda_init: its initial value (OmniSafe: 0.001)
    :param lambda_max: its upper clip, ``None`` for none (OmniSafe's ``lagrangian_upper_bound``)
    :param cost_gamma: the cost critic's discount
    :param cost_lam: GAE parameter of the cost advantage (OmniSafe ``lam_c``: 0.95)
    :param saute_penalty: Saute's ``n``: the reward of every step once the budget is spent, ``-n`` (environment
        units, before the learner's reward scale: 1 per step, so a spent budget over a whole episode costs as
        much as a crash)
    """

    lambda_lr: float = 0.035
    lambda_init: float = 0.001
    lambda_max: float | None = None
    cost_gamma: float = 0.99
    cost_lam: float = 0.95
    saute_penalty: float = 1.0

    def check(self) -> SafeRLConfig:
        """``self``, or ``ValueError`` naming the first bad value."""
        for name in ("lambda_lr", "saute_penalty"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"safe.{name} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.lambda_init, (int, float)) and math.isfinite(self.lambda_init) and self.lambda_init >= 0):
            raise ValueError(f"safe.lambda_init must be a finite number >= 0, got {self.lambda_init!r}")
        if self.lambda_max is not None and not (isinstance(self.lambda_max, (int, float)) and self.lambda_max > 0):
            raise ValueError(f"safe.lambda_max must be None or a number > 0, got {self.lambda_max!r}")
        for name in ("cost_gamma", "cost_lam"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise ValueError(f"safe.{name} must lie in [0, 1], got {v!r}")
        return self


# --------------------------------------------------------------------------------------------- PPO-Lagrangian

class LagrangeMultiplier:
    """The multiplier ``lambda >= 0`` of OmniSafe's ``Lagrange`` (``omnisafe/common/lagrange.py``): one Adam step
    on the loss ``-lambda * (J_c - d)`` per update (so ``lambda`` rises while the mean episode cost ``J_c``
    exceeds the limit ``d`` and falls below it), then clipped to ``[0, upper]``."""

    def __init__(self, init: float = 0.001, lr: float = 0.035, upper: float | None = None):
        self.param = nn.Parameter(torch.as_tensor(max(float(init), 1e-5), dtype=torch.float32))
        self.optimizer = torch.optim.Adam([self.param], lr=lr)
        self.upper = upper

    @property
    def value(self) -> float:
        return float(self.param.item())

    def update(self, excess: float) -> float:
        """One step with ``excess = J_c - d``; returns the new ``lambda``."""
        if not math.isfinite(excess):
            raise ValueError(f"the mean episode cost excess must be finite, got {excess!r}")
        self.optimizer.zero_grad()
        loss = -self.param * float(excess)
        loss.backward()
        self.optimizer.step()
        self.param.data.clamp_(0.0, self.upper)
        return self.value


def combine_advantages(adv_r: np.ndarray, adv_c: np.ndarray, lam: float) -> np.ndarray:
    """OmniSafe PPOLag's surrogate advantage ``(A_r - lambda A_c) / (1 + lambda)`` with ``A_r`` standardised and
    ``A_c`` centred over the rollout (OmniSafe's ``standardized_adv_r`` / ``standardized_adv_c``)."""
    r = (adv_r - adv_r.mean()) / (adv_r.std() + 1e-8)
    c = adv_c - adv_c.mean()
    return (r - lam * c) / (1.0 + lam)


def gae(rewards: np.ndarray, values: np.ndarray, episode_starts: np.ndarray, last_values: np.ndarray,
        last_dones: np.ndarray, gamma: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation over a rollout of shape ``(n_steps, n_envs)`` (the recursion of SB3's
    ``RolloutBuffer.compute_returns_and_advantage``); returns ``(advantages, returns)``."""
    adv = np.zeros_like(rewards)
    last = np.zeros(rewards.shape[1], dtype=rewards.dtype)
    n = rewards.shape[0]
    for t in reversed(range(n)):
        if t == n - 1:
            nonterminal, next_v = 1.0 - last_dones.astype(rewards.dtype), last_values
        else:
            nonterminal, next_v = 1.0 - episode_starts[t + 1], values[t + 1]
        delta = rewards[t] + gamma * next_v * nonterminal - values[t]
        last = delta + gamma * lam * nonterminal * last
        adv[t] = last
    return adv, adv + values


class _CostRecorder(BaseCallback):
    """Records each step's cost (in control periods), the cost critic's value and each finished episode's
    ``sum(cost) - Q`` into the :class:`PPOLagrangian` being trained; called by SB3 after ``env.step`` and before
    the step enters the rollout buffer."""

    def __init__(self, algo: PPOLagrangian):
        super().__init__()
        self.algo = algo

    def _on_step(self) -> bool:
        a = self.algo
        infos, dones = self.locals["infos"], self.locals["dones"]
        pos = self.locals["rollout_buffer"].pos
        cost = np.array([float(i.get("cost", 0.0)) / a.cost_unit for i in infos], dtype=np.float32)
        a._ep_cost += cost
        for k, done in enumerate(dones):
            info = infos[k]
            if done and info.get("terminal_observation") is not None and info.get("TimeLimit.truncated", False):
                cost[k] += a.safe.cost_gamma * a.cost_value(info["terminal_observation"][None])[0]
            if done:
                q = float(info["budget_used"]) + float(info["budget"])  # the episode's Q (used + left)
                a._excess.append(float(a._ep_cost[k]) - q / a.cost_unit)
                a._ep_cost[k] = 0.0
        a._costs[pos] = cost
        a._cost_values[pos] = a.cost_value(a._last_obs)
        return True


class PPOLagrangian(PPO):
    """PPO-Lagrangian (see the module docstring for the sources of each rule).

    :param safe: the multiplier's and the cost critic's settings
    :param cost_unit: the cost's unit [s] (the environment's control period, set by :func:`train_method`)
    """

    def __init__(self, *args: Any, safe: SafeRLConfig | None = None, cost_unit: float = 0.01, **kwargs: Any):
        self.safe = (safe or SafeRLConfig()).check()
        self.cost_unit = float(cost_unit)
        kwargs.setdefault("normalize_advantage", False)  # the advantages are standardised over the rollout
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        obs_dim = int(np.prod(self.observation_space.shape))
        self.cost_net = nn.Sequential(nn.Linear(obs_dim, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(),
                                      nn.Linear(64, 1))
        lr = self.learning_rate if isinstance(self.learning_rate, float) else 3e-4
        self.cost_optimizer = torch.optim.Adam(self.cost_net.parameters(), lr=lr)
        self.lagrange = LagrangeMultiplier(self.safe.lambda_init, self.safe.lambda_lr, self.safe.lambda_max)
        self.lagrange_multiplier = self.lagrange.value
        shape = (self.n_steps, self.n_envs)
        self._costs = np.zeros(shape, dtype=np.float32)
        self._cost_values = np.zeros(shape, dtype=np.float32)
        self._ep_cost = np.zeros(self.n_envs, dtype=np.float32)
        self._excess: list[float] = []

    def _excluded_save_params(self) -> list[str]:
        # the saved policy is PPO's (it loads with PPO.load); the multiplier's value is kept as a number
        return super()._excluded_save_params() + ["cost_net", "cost_optimizer", "lagrange", "_costs",
                                                  "_cost_values", "_ep_cost", "_excess"]

    def cost_value(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.cost_net(torch.as_tensor(np.asarray(obs), dtype=torch.float32)).squeeze(-1).numpy()

    def collect_rollouts(self, env, callback, rollout_buffer, n_rollout_steps: int) -> bool:
        recorder = _CostRecorder(self)
        recorder.init_callback(self)
        chain = CallbackList([recorder, callback])
        # the user's callbacks are initialised already: bind the list alone (init_callback would redo theirs)
        chain.model = self
        ok = super().collect_rollouts(env, chain, rollout_buffer, n_rollout_steps)
        if ok:
            self._cost_adv, self._cost_ret = gae(self._costs, self._cost_values, rollout_buffer.episode_starts,
                                                 self.cost_value(self._last_obs), np.asarray(self._last_episode_starts),
                                                 self.safe.cost_gamma, self.safe.cost_lam)
        return ok

    def train(self) -> None:
        # OmniSafe PPOLag._update: the multiplier first, from the episodes finished since the last update
        if self._excess:
            excess = float(np.mean(self._excess))
            self.lagrange_multiplier = self.lagrange.update(excess)
            self.logger.record("lag/episode_cost_excess", excess)
            self._excess = []
        self.logger.record("lag/multiplier", self.lagrange_multiplier)
        buf = self.rollout_buffer
        buf.advantages = combine_advantages(buf.advantages, self._cost_adv, self.lagrange_multiplier).astype(np.float32)
        super().train()
        # the cost critic: mean squared error to the cost returns, PPO's epochs and minibatches
        obs = torch.as_tensor(buf.observations.reshape(buf.buffer_size * buf.n_envs, -1), dtype=torch.float32)
        target = torch.as_tensor(self._cost_ret.reshape(-1), dtype=torch.float32)
        gen = torch.Generator().manual_seed(int(self.num_timesteps))
        for _ in range(self.n_epochs):
            for idx in torch.randperm(len(target), generator=gen).split(self.batch_size):
                loss = ((self.cost_net(obs[idx]).squeeze(-1) - target[idx]) ** 2).mean()
                self.cost_optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(self.cost_net.parameters(), self.max_grad_norm)
                self.cost_optimizer.step()
        self.logger.record("lag/cost_value_loss", float(loss.item()))


# --------------------------------------------------------------------------------------------- Saute

def saute_observation(obs: np.ndarray, scale: float) -> np.ndarray:
    """The observation with Saute's normalised safety state appended: ``z / scale`` (``z``, the remaining budget,
    is the observation's entry :data:`Z_INDEX`); works on one observation or a batch."""
    obs = np.asarray(obs, dtype=np.float32)
    return np.concatenate([obs, obs[..., Z_INDEX:Z_INDEX + 1] / np.float32(scale)], axis=-1)


def saute_scale(env: gym.Env) -> float:
    """The normaliser of the safety state: the largest budget of the environment's range (for a fixed ``Q``, ``Q``
    itself: the state starts at 1, OmniSafe's ``safety_obs``), or the control period when that is 0."""
    base = env.unwrapped
    hi = float(base.budget_range[1])
    return hi if hi > 0 else float(base.dt)


class SauteWrapper(gym.Wrapper):
    """Saute RL (Sootla et al. 2022, Section 4; OmniSafe ``SauteAdapter``) on a landing environment.

    * Observation: the environment's, plus ``z / scale`` (:func:`saute_observation`); ``z = Q - sum(cost)`` is
      the environment's own remaining budget, Saute's safety state with ``gamma_c = 1``.
    * Reward: the environment's while ``z >= 0``, ``-penalty`` on every step that ends with ``z < 0`` (the budget
      spent: the environment's ``budget_exceeded``). OmniSafe tests ``safety_obs > 0``; the budget here is a
      closed constraint (``z = 0`` is within it), which differs only where ``z`` is exactly 0, as at ``Q = 0``.
      ``info["saute_penalised"]`` says whether the step's reward was replaced.

    :param penalty: Saute's ``n`` in the units of the rewards this wrapper sees
    :param scale: the safety state's normaliser (default :func:`saute_scale`)
    """

    def __init__(self, env: gym.Env, penalty: float, scale: float | None = None):
        super().__init__(env)
        if not (math.isfinite(penalty) and penalty > 0):
            raise ValueError(f"Saute penalty must be a finite number > 0, got {penalty!r}")
        self.penalty = float(penalty)
        self.scale = float(scale) if scale is not None else saute_scale(env)
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"Saute scale must be a finite number > 0, got {self.scale!r}")
        space = env.observation_space
        self.observation_space = gym.spaces.Box(saute_observation(space.low, self.scale) if np.all(np.isfinite(
            space.low)) else np.full(space.shape[0] + 1, -np.inf, dtype=np.float32),
            saute_observation(space.high, self.scale) if np.all(np.isfinite(space.high))
            else np.full(space.shape[0] + 1, np.inf, dtype=np.float32), dtype=np.float32)

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        return saute_observation(obs, self.scale), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        spent = float(info["budget"]) < 0.0
        info["saute_penalised"] = spent
        return (saute_observation(obs, self.scale), -self.penalty if spent else reward, terminated, truncated, info)


class SautePolicy:
    """A trained Saute policy deployed on the plain environment: ``predict`` appends the safety state to the
    observation (:func:`saute_observation`, the wrapper's rule), so evaluation needs no wrapper."""

    def __init__(self, model: Any, scale: float):
        self.model = model
        self.scale = float(scale)

    @property
    def observation_space(self) -> gym.spaces.Box:
        """The plain environment's observation space: the model's without the appended safety state."""
        space = self.model.observation_space
        return gym.spaces.Box(space.low[:-1], space.high[:-1], dtype=space.dtype)

    @property
    def action_space(self) -> gym.spaces.Space:
        return self.model.action_space

    def predict(self, obs: np.ndarray, deterministic: bool = True, **kwargs: Any):
        return self.model.predict(saute_observation(obs, self.scale), deterministic=deterministic, **kwargs)


__all__ = ["LagrangeMultiplier", "METHODS", "PPOLagrangian", "SafeRLConfig", "SautePolicy", "SauteWrapper",
           "Z_INDEX", "combine_advantages", "gae", "saute_observation", "saute_scale"]
