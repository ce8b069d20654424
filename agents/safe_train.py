"""Training with a method of the budget comparison (``plain`` PPO, ``lag`` PPO-Lagrangian, ``saute`` PPO-Saute),
and what every training run reports about its own safety: the hard violations and overspends of its episodes.

:func:`train_method` runs :func:`softreach.agents.train.train` (the one training loop: environments, filter,
evaluations, checkpoints) with the method's model class and wrapper (:mod:`.safe_rl`) and a
:class:`TrainingSafetyCounter`, and writes ``training_safety.json`` beside the run's ``config.json``.
:func:`load_method_policy` loads a trained policy ready to act on the plain environment.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from .evaluate import BUDGET_TOL
from .safe_rl import METHODS, PPOLagrangian, SafeRLConfig, SautePolicy, SauteWrapper

SAFETY_FILE = "training_safety.json"
SAFETY_SCHEMA = "softreach.training-safety/1"
#: the counts are also given per this many environment steps
PER_STEPS = 100_000


class TrainingSafetyCounter(BaseCallback):
    """Counts, from the training environments' ``info`` at each episode end, the episodes that landed, left the
    hard constraint (``hard_violation``) and overspent (``budget < -BUDGET_TOL``: ``budget_used > Q + 1 ms``, the
    evaluations' rule), and the steps in which a safety filter acted (``filter_active``).

    Under a safety filter the same counts are also kept for the episodes whose start the filter certified
    (``info["filter_episode"]["certified_start"]``): its guarantee covers only those, and the environment's own
    starts (the glider's) need not lie in ``RA~_Q``.

    :attr:`ends` holds ``(environment steps so far, landed, hard, over, certified start)`` per episode, the last
    ``1``, ``0``, or ``-1`` without a filter, so the counts can be cut at any step (:meth:`summary`: cumulative
    and per :data:`PER_STEPS` steps)."""

    def __init__(self):
        super().__init__()
        self.ends: list[tuple[int, bool, bool, bool, int]] = []
        self.interventions = 0
        self.steps = 0

    def _on_step(self) -> bool:
        infos, dones = self.locals["infos"], self.locals["dones"]
        self.steps += len(infos)
        for info, done in zip(infos, dones):
            self.interventions += int(bool(info.get("filter_active", False)))
            if done:
                episode = info.get("filter_episode")
                certified = -1 if episode is None else int(bool(episode["certified_start"]))
                self.ends.append((self.steps, bool(info.get("landed", False)), bool(info.get("hard_violation", False)),
                                  float(info.get("budget", 0.0)) < -BUDGET_TOL, certified))
        return True

    def summary(self) -> dict[str, Any]:
        """``{"steps", "episodes", "landed", "hard_violations", "over_budget", "interventions", "per_100k":
        {...}, "curve": [[steps, cumulative hard, cumulative over], ...], "certified_starts"}`` (the curve at each
        10 % of training); ``"certified_starts"`` is ``None`` where no episode ran under a filter, else the
        ``episodes``, ``landed``, ``hard_violations`` and ``over_budget`` of the episodes from certified starts."""
        e = np.array(self.ends, dtype=np.int64).reshape(-1, 5)
        steps = max(self.steps, 1)
        tot = {"episodes": int(len(e)), "landed": int(e[:, 1].sum()), "hard_violations": int(e[:, 2].sum()),
               "over_budget": int(e[:, 3].sum()), "interventions": int(self.interventions)}
        marks = sorted({int(round(steps * k / 10)) for k in range(1, 11)})
        curve = [[m, int(e[e[:, 0] <= m, 2].sum()), int(e[e[:, 0] <= m, 3].sum())] for m in marks]
        certified = None
        if len(e) and (e[:, 4] >= 0).any():
            c = e[e[:, 4] == 1]
            certified = {"episodes": int(len(c)), "landed": int(c[:, 1].sum()), "hard_violations": int(c[:, 2].sum()),
                         "over_budget": int(c[:, 3].sum())}
        return {"schema": SAFETY_SCHEMA, "steps": int(self.steps), **tot,
                "per_100k": {k: v * PER_STEPS / steps for k, v in tot.items()}, "curve": curve,
                "certified_starts": certified}


def check_method(method: str, spec: Any) -> None:
    """``ValueError`` naming the problem when ``method`` cannot train ``spec`` (the baselines are PPO without the
    safety filter: what they are compared with is the filter)."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {list(METHODS)}")
    if method != "plain" and spec.algo != "ppo":
        raise ValueError(f"method {method!r} is PPO-based: it needs algo 'ppo', got {spec.algo!r}")
    if method != "plain" and spec.filter is not None:
        raise ValueError(f"method {method!r} trains without the safety filter: use rule 'none'")


def safe_config(overrides: dict[str, Any] | None) -> SafeRLConfig:
    """:class:`SafeRLConfig` with ``overrides``; an unknown field is a ``ValueError`` naming it."""
    try:
        return replace(SafeRLConfig(), **(overrides or {})).check()
    except TypeError as exc:
        raise ValueError(f"safe overrides {overrides!r}: {exc}") from None


def train_method(spec: Any, method: str = "plain", safe_overrides: dict[str, Any] | None = None):
    """Train ``spec`` (a :class:`~softreach.agents.train.TrainSpec`) with ``method``; returns ``(TrainResult,
    training-safety summary)``. The run's ``config.json`` gains ``"method"`` (name, settings, Saute's scale)."""
    from .train import resolve, train

    check_method(method, spec)
    safe = safe_config(safe_overrides)
    run, _, _ = resolve(spec)
    counter = TrainingSafetyCounter()
    kwargs: dict[str, Any] = {"callbacks": [counter]}
    info: dict[str, Any] = {"name": method, "safe": asdict(safe) if method != "plain" else None}
    if method == "lag":
        from softreach.reach.models import get_model

        dt = float(get_model(spec.model).control_period or 0.0)
        if not dt > 0:
            raise ValueError(f"PPO-Lagrangian needs the model's control period to measure costs; {spec.model} has none")

        class _Lag(PPOLagrangian):
            def __init__(self, *a: Any, **k: Any):
                super().__init__(*a, safe=safe, cost_unit=dt, **k)

        kwargs["model_class"] = _Lag
        info["cost_unit_s"] = dt
    elif method == "saute":
        scales: list[float] = []

        def wrap(env, learner: bool):
            w = SauteWrapper(env, safe.saute_penalty * (run.reward_scale if learner else 1.0))
            scales.append(w.scale)
            return w

        kwargs["wrap_env"] = wrap
    res = train(spec, **kwargs)
    if method == "saute":
        if len(set(scales)) != 1:
            raise RuntimeError(f"Saute environments normalised the budget differently: {sorted(set(scales))}")
        info["saute_scale"] = scales[0]
    cfg_path = Path(res.out_dir) / "config.json"
    cfg = json.loads(cfg_path.read_text())
    cfg["method"] = info
    cfg_path.write_text(json.dumps(cfg, indent=2))
    res.config["method"] = info
    summary = counter.summary()
    (Path(res.out_dir) / SAFETY_FILE).write_text(json.dumps(summary, indent=1))
    return res, summary


def load_method_policy(path: str | Path):
    """A saved policy that acts on the plain environment: SB3's model (:func:`~softreach.agents.train.load_policy`),
    wrapped in :class:`~softreach.agents.safe_rl.SautePolicy` when its run trained with Saute."""
    from .train import load_policy, run_config_of

    model = load_policy(path)
    method = ((run_config_of(path) or {}).get("method") or {})
    if method.get("name") == "saute":
        return SautePolicy(model, method["saute_scale"])
    return model


__all__ = ["PER_STEPS", "SAFETY_FILE", "TrainingSafetyCounter", "check_method", "load_method_policy", "safe_config",
           "train_method"]
