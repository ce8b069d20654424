"""``VecSafetyFilter``: a ``DummyVecEnv``'s ``SafetyFilter`` decisions in one batched call per step (a call's cost is
mostly fixed), each environment stepping as it would alone (docs/filters.md, 'Many environments at once')."""

from __future__ import annotations

from typing import Any

import numpy as np

from stable_baselines3.common.vec_env import DummyVecEnv, VecEnvWrapper

from .wrapper import SafetyFilter


def find_filter(env: Any) -> SafetyFilter | None:
    """The :class:`SafetyFilter` in ``env``'s wrapper stack, or ``None``."""
    while env is not None:
        if isinstance(env, SafetyFilter):
            return env
        env = getattr(env, "env", None)
    return None


class VecSafetyFilter(VecEnvWrapper):
    """Batch the safety filter's decisions over a ``DummyVecEnv``: one call per step for each shared ``ValueFilter``.

    :param venv: a ``DummyVecEnv`` (its states are read in this process), each environment holding a
        :class:`SafetyFilter` under wrappers that pass the action through unchanged
    :raises TypeError: ``venv`` is not a ``DummyVecEnv`` or an environment has no ``SafetyFilter``"""

    def __init__(self, venv: DummyVecEnv):
        if not isinstance(venv, DummyVecEnv):
            raise TypeError(f"VecSafetyFilter reads the environments' states in this process: it needs a "
                            f"DummyVecEnv, got {type(venv).__name__}")
        super().__init__(venv)
        self.filters = [find_filter(e) for e in venv.envs]
        missing = [i for i, f in enumerate(self.filters) if f is None]
        if missing:
            raise TypeError(f"environments {missing} have no SafetyFilter in their wrapper stack")
        groups: dict[int, list[int]] = {}
        for i, f in enumerate(self.filters):
            groups.setdefault(id(f.value_filter), []).append(i)
        self.groups = [np.array(rows) for rows in groups.values()]

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        for rows in self.groups:
            filters = [self.filters[i] for i in rows]
            bases = [f.env.unwrapped for f in filters]
            if any(b.state is None for b in bases):
                continue  # the environments raise ResetNeeded themselves
            t = np.array([b.time for b in bases], dtype=np.float64)
            x = np.stack([np.asarray(b.state, dtype=np.float64) for b in bases])
            z = np.array([b.budget for b in bases], dtype=np.float64)
            act = actions[rows].reshape(len(rows), -1)
            plans = np.stack([f._plan for f in filters])
            applied, info = filters[0].value_filter.filter(t, x, z, act, normalized=True, plan=plans)
            for k, f in enumerate(filters):
                f.expect(act[k], applied[k], {key: v[k] for key, v in info.items()})
        self.venv.step_async(actions)

    def step_wait(self):
        return self.venv.step_wait()

    def reset(self):
        return self.venv.reset()


__all__ = ["VecSafetyFilter", "find_filter"]
