"""Saved policies of ``softreach train``: the run a policy belongs to (its ``config.json``), loading it, and
checking that it fits the environment it is to fly in."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

TRAIN_SCHEMA = "softreach.train/1"


def run_config_of(policy_path: str | Path) -> dict[str, Any] | None:
    """The ``config.json`` of the run a saved policy belongs to (its directory or the one above), if any."""
    p = Path(policy_path)
    for d in ([p] if p.is_dir() else []) + [p.parent, p.parent.parent]:
        cfg = d / "config.json"
        if cfg.is_file():
            try:
                data = json.loads(cfg.read_text())
            except (OSError, ValueError):
                continue
            if data.get("schema") == TRAIN_SCHEMA:
                return {**data, "_dir": str(d)}
    return None


def load_policy(path: str | Path, algo: str | None = None):
    """Load a saved SB3 policy (``model.zip`` or a run directory); the algorithm is read from the run's
    ``config.json`` when ``algo`` is not given, else PPO and SAC are tried in turn.

    :raises FileNotFoundError: no such file
    :raises ValueError: the file is not a PPO or SAC model
    """
    from stable_baselines3 import PPO, SAC

    p = Path(path)
    if p.is_dir():
        p = p / "model.zip"
    if not p.is_file():
        raise FileNotFoundError(f"policy {path} does not exist (train one with `softreach train`)")
    cfg = run_config_of(p)
    algo = algo or (cfg or {}).get("algo")
    classes = {"ppo": [PPO], "sac": [SAC]}.get(algo, [PPO, SAC])
    errors = []
    for cls in classes:
        try:
            return cls.load(p, device="cpu")
        except Exception as exc:  # noqa: BLE001 - try the next class, report all if none fits
            errors.append(f"{cls.__name__}: {exc}")
    raise ValueError(f"{path} is not a saved PPO or SAC policy ({'; '.join(errors)})")


def trained_for(policy: Any, path: str | Path | None = None) -> str | None:
    """The model a saved policy was trained for: recorded in the policy itself (``softreach_model``, saved by
    ``softreach train``), else in its run's ``config.json``; ``None`` when neither says."""
    name = getattr(policy, "softreach_model", None)
    if name is None and path is not None:
        name = (run_config_of(path) or {}).get("model")
    return name


def check_fits(policy: Any, env: Any, model: str, path: str | Path | None = None) -> None:
    """Refuse, naming the model the policy was trained for, a policy whose observation or action space is not
    the environment's (SB3 would fail later with "Unexpected observation shape").

    :param policy: an SB3 model (``observation_space``, ``action_space``)
    :param env: the environment it is to act in
    :param model: how the environment's model was named (for the message)
    :raises ValueError: the spaces differ
    """
    import numpy as np

    mismatch = []
    for what in ("observation", "action"):
        mine, theirs = getattr(policy, f"{what}_space", None), getattr(env, f"{what}_space")
        if mine is None:
            continue
        if mine.shape != theirs.shape or not (np.array_equal(getattr(mine, "low", None), getattr(theirs, "low", None))
                                               and np.array_equal(getattr(mine, "high", None),
                                                                  getattr(theirs, "high", None))):
            mismatch.append(f"{what}s {_space(mine)} where {model}'s environment has {_space(theirs)}"
                            if mine.shape != theirs.shape else f"{what} bounds differ from {model}'s environment's")
    if mismatch:
        origin = trained_for(policy, path)
        name = f"policy {path}" if path is not None else "the policy"
        if origin == model:  # the right model, another observation: a method's wrapper (PPO-Saute appends one)
            raise ValueError(f"{name} was trained for {model} but does not fit its environment: "
                             + "; ".join(mismatch) + " (load it with softreach.agents.safe_train.load_method_policy)")
        who = f"was trained for {origin}" if origin else "was trained for another model"
        raise ValueError(f"{name} {who}, not {model}: " + "; ".join(mismatch))


def _space(space: Any) -> str:
    return f"{type(space).__name__}{tuple(space.shape)}" if space.shape is not None else type(space).__name__
