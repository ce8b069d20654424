"""Default hyperparameters of ``softreach train``: the one place where they live.

One frozen dataclass per algorithm (:class:`PPOConfig`, :class:`SACConfig`) holds what Stable-Baselines3 gets;
:class:`RunConfig` holds what the training loop does around it (steps, vectorised environments, evaluation,
checkpoints, reward scale). :func:`defaults` returns the defaults of a model and algorithm, and
:func:`algo_kwargs` turns an algorithm config into the keyword arguments of ``PPO(...)`` / ``SAC(...)``.

The point-mass PPO defaults were chosen so that ``softreach train pointmass`` finishes in about five minutes
on a 2-core CPU and lands most episodes (measured numbers: ``docs/agents.md``). The glider defaults are the
same settings. The SAC defaults keep Stable-Baselines3's entropy, discount and update settings;
``benchmarks/sac_study.py`` compares them with the fields of :class:`SACConfig` that decide whether SAC learns
to land (the entropy coefficient's start, gradient steps per environment step, the horizon stored as terminal;
``docs/agents.md``, "SAC").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

from softreach.reach.registry import env_ids, model_class, model_names

ALGOS = ("ppo", "sac")
#: the training methods of :mod:`~softreach.agents.safe_rl`: ``plain`` (SB3 PPO, softreach's recipes), ``lag``
#: (PPO-Lagrangian), ``saute`` (PPO-Saute)
METHODS = ("plain", "lag", "saute")
#: the registered models and their environment ids when this module was imported (from
#: :mod:`softreach.reach.registry`, the one place they live; a ``"module:Class"`` model is accepted too)
MODELS = tuple(model_names())
ENV_IDS = env_ids()


@dataclass(frozen=True)
class PPOConfig:
    """Proximal Policy Optimisation (SB3 ``PPO``, ``MlpPolicy``).

    :param learning_rate: Adam step size
    :param n_steps: steps per environment per rollout (the rollout holds ``n_steps * n_envs`` transitions)
    :param batch_size: minibatch size
    :param n_epochs: passes over each rollout
    :param gamma: discount (an episode is 100 control periods)
    :param gae_lambda: GAE parameter
    :param clip_range: PPO ratio clip
    :param ent_coef: entropy bonus
    :param vf_coef: value-loss weight
    :param max_grad_norm: gradient clip
    :param log_std_init: initial log standard deviation of the Gaussian policy
    :param net_arch: hidden layers of the policy and of the value network
    :param activation: ``"tanh"`` or ``"relu"``
    """

    learning_rate: float = 3e-4
    n_steps: int = 256
    batch_size: int = 256
    n_epochs: int = 10
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    log_std_init: float = -0.5
    net_arch: tuple[int, ...] = (64, 64)
    activation: str = "tanh"


@dataclass(frozen=True)
class SACConfig:
    """Soft Actor-Critic (SB3 ``SAC``, ``MlpPolicy``).

    :param learning_rate: Adam step size (actor, critics, entropy coefficient)
    :param buffer_size: replay buffer capacity
    :param learning_starts: random steps before the first update
    :param batch_size: minibatch size
    :param tau: target-network soft update
    :param gamma: discount
    :param train_freq: environment steps (per environment) between updates
    :param gradient_steps: gradient steps per update
    :param ent_coef: ``"auto"`` (learned, starting at 1), ``"auto_<init>"`` (learned, starting at ``<init>``) or
        a number. The entropy bonus is paid per step in the learner's reward units (``reward_scale``)
    :param target_entropy: the entropy the learned coefficient steers to, ``"auto"`` (``-action_dim``) or a number
    :param n_steps: ``n``-step returns in the critic's target (1: SAC's one-step target)
    :param use_sde: generalised state-dependent exploration (gSDE) instead of independent Gaussian noise per step
    :param horizon_terminal: store the step that reaches the horizon ``T`` as terminal (no bootstrap past it). The
        observation carries the time left, so ``T`` ends the decision process; SB3's default (``False``) treats
        the time-limit truncation as a cut-off episode and bootstraps from ``Q`` at a time left of 0, a state
        no transition starts from
    :param net_arch: hidden layers of the actor and of each critic
    :param action_label: what the replay buffer stores as the action of a transition: ``"policy"`` (the
        policy's own action; the filter is part of the environment) or ``"applied"`` (the action the filter let
        through, i.e. what the environment executed). See ``docs/agents.md``.
    """

    learning_rate: float = 3e-4
    buffer_size: int = 200_000
    learning_starts: int = 2_000
    batch_size: int = 256
    tau: float = 0.005
    gamma: float = 0.99
    train_freq: int = 1
    gradient_steps: int = 1
    ent_coef: str | float = "auto"
    target_entropy: str | float = "auto"
    n_steps: int = 1
    use_sde: bool = False
    horizon_terminal: bool = False
    net_arch: tuple[int, ...] = (128, 128)
    action_label: str = "policy"


@dataclass(frozen=True)
class RunConfig:
    """What the training loop does around the algorithm.

    :param timesteps: total environment steps (all environments together)
    :param n_envs: environments stepped together (``DummyVecEnv``: one process, batched policy calls)
    :param eval_freq: environment steps between evaluations (``EvalCallback``); 0 disables them
    :param eval_episodes: episodes per evaluation (deterministic policy, same filter and wind as training)
    :param checkpoint_freq: environment steps between checkpoints; 0 disables them
    :param reward_scale: the learner sees ``reward_scale * reward`` (the environment's rewards are about
        ``+-100`` at the end of an episode); logged returns and evaluations stay in the environment's units
    :param intervention_penalty: subtracted from the (unscaled) reward of each step in which the filter
        changed the action (only when training with a filter; 0 leaves the reward alone). Without it a
        policy trained under the filter learns to let the filter fly (measured: it then lands 0 % of
        episodes on its own); with 1.0 it learns to land by itself too.
    :param wind: the training wind (``"none"``, ``"random"``, ``"adversarial"``)
    :param budget: the budget ``Q`` of each training episode: ``None`` for the environment's default
        distribution (point mass ``U[0, 0.6]`` s), a number, or a ``(low, high)`` range
    :param pretrain_steps: with a filter, steps learned **without** it first (a curriculum: the policy learns
        to fly by itself, with crashes costing reward, then ``timesteps`` more steps under the filter); the
        periodic evaluations run the deployed closed loop (with the filter) throughout. 0: all under the filter
    """

    timesteps: int = 500_000
    n_envs: int = 8
    eval_freq: int = 25_000
    eval_episodes: int = 20
    checkpoint_freq: int = 100_000
    reward_scale: float = 0.01
    intervention_penalty: float = 1.0
    wind: str = "random"
    budget: float | tuple[float, float] | None = None
    pretrain_steps: int = 0


@dataclass(frozen=True)
class Defaults:
    """The defaults of one model and algorithm."""

    run: RunConfig
    algo: PPOConfig | SACConfig

    def to_dict(self) -> dict[str, Any]:
        return {"run": asdict(self.run), "algo": asdict(self.algo)}


#: tuned defaults; every other model (dubins, a user's) trains with the generic ones of :func:`defaults`
_DEFAULTS: dict[tuple[str, str], Defaults] = {
    ("pointmass", "ppo"): Defaults(RunConfig(), PPOConfig()),
    ("pointmass", "sac"): Defaults(RunConfig(timesteps=60_000, n_envs=4, eval_freq=10_000,
                                             checkpoint_freq=20_000), SACConfig()),
    ("glider", "ppo"): Defaults(RunConfig(timesteps=500_000), PPOConfig()),
    ("glider", "sac"): Defaults(RunConfig(timesteps=100_000, n_envs=4, eval_freq=10_000,
                                          checkpoint_freq=25_000), SACConfig()),
}


def defaults(model: str, algo: str = "ppo") -> Defaults:
    """The default run and algorithm settings of ``model`` trained with ``algo``: the tuned ones of the landings,
    the dataclasses' own defaults for every other model (PPO) or the point mass's SAC run settings (SAC).

    :param model: a registered short name or ``"module:Class"``
    :raises ValueError: an unknown model or algorithm (the message names it)
    """
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; choose from {list(ALGOS)}")
    model_class(model)  # raises, naming an unknown model
    found = _DEFAULTS.get((model, algo))
    if found is not None:
        return found
    return Defaults(RunConfig(), PPOConfig()) if algo == "ppo" else _DEFAULTS[("pointmass", "sac")]


def with_overrides(cfg: Any, **overrides: Any) -> Any:
    """``cfg`` with the given fields replaced; ``None`` values are ignored (an unset command-line option)."""
    return replace(cfg, **{k: v for k, v in overrides.items() if v is not None})


def algo_kwargs(cfg: PPOConfig | SACConfig) -> dict[str, Any]:
    """Keyword arguments of ``stable_baselines3.PPO`` / ``SAC`` for ``cfg`` (without ``env``, ``seed``...)."""
    import torch.nn as nn

    if isinstance(cfg, PPOConfig):
        act = {"tanh": nn.Tanh, "relu": nn.ReLU}.get(cfg.activation)
        if act is None:
            raise ValueError(f"activation must be 'tanh' or 'relu', got {cfg.activation!r}")
        return {
            "learning_rate": cfg.learning_rate, "n_steps": cfg.n_steps, "batch_size": cfg.batch_size,
            "n_epochs": cfg.n_epochs, "gamma": cfg.gamma, "gae_lambda": cfg.gae_lambda,
            "clip_range": cfg.clip_range, "ent_coef": cfg.ent_coef, "vf_coef": cfg.vf_coef,
            "max_grad_norm": cfg.max_grad_norm,
            "policy_kwargs": {"net_arch": {"pi": list(cfg.net_arch), "vf": list(cfg.net_arch)},
                              "activation_fn": act, "log_std_init": cfg.log_std_init},
        }
    if isinstance(cfg, SACConfig):
        if cfg.action_label not in ("policy", "applied"):
            raise ValueError(f"action_label must be 'policy' or 'applied', got {cfg.action_label!r}")
        return {
            "learning_rate": cfg.learning_rate, "buffer_size": cfg.buffer_size,
            "learning_starts": cfg.learning_starts, "batch_size": cfg.batch_size, "tau": cfg.tau,
            "gamma": cfg.gamma, "train_freq": cfg.train_freq, "gradient_steps": cfg.gradient_steps,
            "ent_coef": cfg.ent_coef, "target_entropy": cfg.target_entropy, "n_steps": cfg.n_steps,
            "use_sde": cfg.use_sde,
            "replay_buffer_kwargs": {"handle_timeout_termination": not cfg.horizon_terminal},
            "policy_kwargs": {"net_arch": list(cfg.net_arch)},
        }
    raise TypeError(f"expected a PPOConfig or SACConfig, got {type(cfg).__name__}")


def learn_unit(cfg: PPOConfig | SACConfig, n_envs: int) -> int:
    """Environment steps SB3 takes between two looks at its total: PPO collects whole rollouts of
    ``n_steps * n_envs`` transitions, SAC ``train_freq * n_envs`` steps between updates."""
    if isinstance(cfg, PPOConfig):
        return int(cfg.n_steps) * int(n_envs)
    freq = cfg.train_freq[0] if isinstance(cfg.train_freq, (tuple, list)) else cfg.train_freq
    return int(freq) * int(n_envs)


def planned_steps(requested: int, cfg: PPOConfig | SACConfig, n_envs: int) -> int:
    """The steps SB3 learns when asked for ``requested``: the first multiple of :func:`learn_unit` at or above it."""
    unit = learn_unit(cfg, n_envs)
    return -(-int(requested) // unit) * unit


__all__ = ["ALGOS", "Defaults", "ENV_IDS", "MODELS", "PPOConfig", "RunConfig", "SACConfig", "algo_kwargs",
           "defaults", "learn_unit", "planned_steps", "with_overrides"]
