"""Build the environments the agents train and are evaluated in: landing env, wind, safety filter, wrappers.

The wrapper stack, inside out::

    gymnasium.make(env_id, wind=..., wind_table=<TableOracle>, budget=...)   # TimeLimit included
    Monitor            # (training) logs the environment's own return, length, landed, hard violation, budget
    SafetyFilter       # (with a filter table) replaces the policy's action where the table says so
    InterventionPenalty  # (optional) -penalty on each step in which the filter acted
    ScaleReward        # (training) the learner sees reward_scale * reward

so the Monitor's episode returns and the evaluation numbers are in the environment's own units, whatever the
learner is shown.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

import softreach.envs  # noqa: F401  (registers the environment ids)
from softreach.filters.background import filter_code_cached
from softreach.reach.registry import make_env as make_model_env, model_class

from .tables import TableOracle, as_table, safety_filter, sample_certified

WINDS = ("none", "random", "adversarial")
RULES = ("switch", "smooth")


class InterventionPenalty(gym.Wrapper):
    """Subtract ``penalty`` from the reward of every step in which the safety filter changed the action
    (``info["filter_active"]``), so that a learner is told, in its reward, that it needed correcting."""

    def __init__(self, env: gym.Env, penalty: float):
        super().__init__(env)
        if not (math.isfinite(penalty) and penalty >= 0):
            raise ValueError(f"intervention penalty must be a finite number >= 0, got {penalty!r}")
        self.penalty = float(penalty)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info.get("filter_active"):
            reward = float(reward) - self.penalty
        return obs, reward, terminated, truncated, info


class CertifiedStarts(gym.Wrapper):
    """Start every episode from a state the filter certifies: ``reset`` draws ``Q`` from the environment's budget
    range and a state of ``RA~_Q`` that the wrapped :class:`~softreach.filters.SafetyFilter` certifies
    (:func:`~softreach.agents.tables.sample_certified`), so an evaluation measures the filter where its guarantee
    holds. Explicit ``options`` win.

    :raises TypeError: no ``SafetyFilter`` in the wrapper stack
    """

    def __init__(self, env: gym.Env):
        super().__init__(env)
        filt = unwrap_filter(env)
        if filt is None:
            raise TypeError("CertifiedStarts needs a SafetyFilter in the wrapper stack (it certifies the starts)")
        self.filter = filt
        self.rng = np.random.default_rng()

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        options = dict(options or {})
        if "state" not in options:
            lo, hi = self.env.unwrapped.budget_range
            q = float(options.get("budget", lo if lo == hi else self.rng.uniform(lo, hi)))
            x = sample_certified(self.filter.table, self.filter.value_filter, q, self.rng)
            options.update(state=[float(v) for v in x], budget=q)
        return self.env.reset(seed=seed, options=options)


class ScaleReward(gym.RewardWrapper):
    """``reward * scale`` (what the learner sees; the Monitor inside logs the unscaled return)."""

    def __init__(self, env: gym.Env, scale: float):
        super().__init__(env)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"reward scale must be a finite number > 0, got {scale!r}")
        self.scale = float(scale)

    def reward(self, reward):
        return self.scale * float(reward)


def check_choice(name: str, value: Any, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise ValueError(f"unknown {name} {value!r}; choose from {list(choices)}")
    return value


def check_budget(budget: Any, horizon: float) -> float | tuple[float, float] | None:
    """``None``, a budget ``Q`` in ``[0, T]`` or a ``(low, high)`` pair, checked (ValueError naming the value)."""
    if budget is None:
        return None
    if isinstance(budget, (tuple, list)):
        if len(budget) != 2:
            raise ValueError(f"budget range must be (low, high), got {budget!r}")
        lo, hi = (check_budget(b, horizon) for b in budget)
        if lo > hi:
            raise ValueError(f"budget range must have low <= high, got {budget!r}")
        return (lo, hi)
    try:
        q = float(budget)
    except (TypeError, ValueError):
        raise ValueError(f"budget must be a number of seconds, got {budget!r}") from None
    if not (math.isfinite(q) and 0.0 <= q <= horizon):
        raise ValueError(f"budget Q={budget!r} must lie in [0, T] = [0, {horizon:g}] s")
    return q


def make_env(model: str, *, wind: str = "none", wind_table: Any = None, budget: Any = None,
             filter_table: Any = None, rule: str = "switch", margin: float | None = None,
             monitor: bool = False, monitor_file: str | None = None, reward_scale: float = 1.0,
             intervention_penalty: float = 0.0, env_kwargs: dict[str, Any] | None = None,
             certified_starts: bool = False, monitor_append: bool = False) -> gym.Env:
    """One landing environment with its wind, optional safety filter and training wrappers.

    :param model: a registered short name (``"pointmass"``, ``"glider"``, ``"dubins"``) or ``"module:Class"``
    :param wind: ``"none"``, ``"random"`` (the environment's gust) or ``"adversarial"`` (the table's ``b*``)
    :param wind_table: table (path, :class:`~softreach.reach.Table` or :class:`TableOracle`) whose ``b*`` blows
        under ``wind="adversarial"``; defaults to ``filter_table``
    :param budget: ``Q`` of every episode, a ``(low, high)`` range, or ``None`` for the environment's default
    :param filter_table: the safety filter's table (path or Table); ``None`` for no filter
    :param rule: the filter's rule, ``"switch"`` or ``"smooth"``
    :param margin: the filter's margin (``None``: computed from the table)
    :param monitor: wrap in SB3's ``Monitor`` (inside the filter: it logs the environment's own return)
    :param monitor_file: the Monitor's CSV file (``None``: kept in memory)
    :param reward_scale: the learner's reward scale (1 for evaluation)
    :param intervention_penalty: reward subtracted per filter intervention (0 for evaluation)
    :param env_kwargs: more keyword arguments of the environment
    :param certified_starts: start every episode from a state the filter certifies (needs ``filter_table``)
    :param monitor_append: append to an existing ``monitor_file`` (a resumed training run) instead of replacing it
    """
    model_class(model)  # raises, naming an unknown model
    check_choice("wind", wind, WINDS)
    check_choice("rule", rule, RULES)
    kwargs = dict(env_kwargs or {})
    kwargs["wind"] = wind
    if wind == "adversarial":
        source = wind_table if wind_table is not None else filter_table
        if source is None:
            raise ValueError("wind 'adversarial' needs a table (its worst-case wind b*): give --filter or --table")
        kwargs["wind_table"] = source if isinstance(source, TableOracle) else TableOracle(source)
    if budget is not None:
        kwargs["budget"] = budget
    env = make_model_env(model, **kwargs)
    if monitor:
        from stable_baselines3.common.monitor import Monitor

        env = Monitor(env, filename=monitor_file, info_keywords=("landed", "hard_violation", "budget_used"),
                      override_existing=not monitor_append)
    if filter_table is not None:
        table = filter_table.table if isinstance(filter_table, TableOracle) else as_table(filter_table)
        env = safety_filter(env, table, rule=rule, margin=margin)
        announce_filter_compile(env)
        if certified_starts:
            env = CertifiedStarts(env)
        if intervention_penalty:
            env = InterventionPenalty(env, intervention_penalty)
    elif certified_starts:
        raise ValueError("certified starts need a safety filter (--filter TABLE)")
    elif intervention_penalty:
        raise ValueError("an intervention penalty needs a safety filter (--filter TABLE)")
    if reward_scale != 1.0:
        env = ScaleReward(env, reward_scale)
    return env


#: CPU seconds the safety filter's first decision, certificate and start-plan search take to compile with an empty
#: compile cache, as ``benchmarks/first_compile.py filter`` measures them (docs/agents.md quotes the measurement):
#: the notice's estimate of the wall time on an idle core
FILTER_COMPILE_S = 60
_announced = False


def announce_filter_compile(env: gym.Env) -> None:
    """Say on stderr, once per process, that the first filtered decision will compile the filter (about
    :data:`FILTER_COMPILE_S` s, once per installed version), where the cache lacks the filter's compiled code: a step
    that would otherwise sit silently at 0 %."""
    global _announced
    filt = unwrap_filter(env)
    if _announced or filt is None or filter_code_cached() is not False:
        return
    _announced = True
    import sys

    print(f"softreach: the safety filter's first decision compiles it with numba, once per installed version: about "
          f"{FILTER_COMPILE_S:.0f} s on an idle core, longer on a busy machine; `softreach solve` does it in the "
          f"background and `softreach compile TABLE` ahead", file=sys.stderr)


def unwrap_filter(env: gym.Env) -> Any:
    """The :class:`~softreach.filters.SafetyFilter` in ``env``'s wrapper stack, or ``None``."""
    from softreach.filters import SafetyFilter

    e = env
    while isinstance(e, gym.Wrapper):
        if isinstance(e, SafetyFilter):
            return e
        e = e.env
    return None


def normalized_action(env: gym.Env, physical: np.ndarray) -> np.ndarray:
    """The environment's normalised action for a physical control, clipped to ``[-1, 1]``."""
    return np.clip(env.unwrapped.normalized_action(np.asarray(physical, dtype=np.float64)), -1.0, 1.0).astype(np.float32)


__all__ = ["CertifiedStarts", "FILTER_COMPILE_S", "InterventionPenalty", "RULES", "ScaleReward", "WINDS",
           "announce_filter_compile", "check_budget", "check_choice", "filter_code_cached", "make_env",
           "normalized_action", "unwrap_filter"]
