"""A training run interrupted (Ctrl-C) and resumed: ``softreach train ... --resume RUN/model.zip``.

On ``KeyboardInterrupt`` during learning, :func:`~softreach.agents.train.train` saves the policy so far
(``model.zip``: weights, optimiser state and step count; SAC's replay buffer beside it), marks ``config.json``
``"status": "interrupted"`` with the step reached and the phase (the unfiltered curriculum or the main phase), and
raises :class:`TrainingInterrupted`. A resumed run loads that policy and learns the steps still missing to the
same total (:func:`remaining`), appending to the run's monitor files and keeping its periodic evaluations.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: SAC's replay buffer, saved beside ``model.zip`` on an interruption (``model.zip`` does not hold it)
REPLAY_BUFFER = "replay_buffer.pkl"


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C during learning, after the policy so far was saved.

    :param model_path: the saved policy
    :param timesteps: environment steps learned so far
    :param target: steps the run was to learn in all
    """

    def __init__(self, model_path: Path, timesteps: int, target: int | None):
        super().__init__(f"training interrupted after {timesteps} steps; the policy is saved in {model_path}")
        self.model_path, self.timesteps, self.target = Path(model_path), int(timesteps), target


@dataclass(frozen=True)
class ResumePoint:
    """Where an interrupted run stopped: its directory, saved policy, steps, phase and the step count at the
    end of its unfiltered curriculum (``None`` while that was unfinished)."""

    run_dir: Path
    model_path: Path
    config: dict[str, Any]
    timesteps: int
    phase: str
    pretrain_end: int | None


def resume_point(path: str | Path, model: str, algo: str) -> ResumePoint:
    """The run to resume from ``path`` (its ``model.zip`` or its directory), checked against this run's model and
    algorithm.

    :raises FileNotFoundError: no such policy, or no ``config.json`` of a ``softreach train`` run beside it
    :raises ValueError: the run trained another model or algorithm
    """
    from .train import run_config_of

    p = Path(path)
    model_path = p / "model.zip" if p.is_dir() else p
    if not model_path.is_file():
        raise FileNotFoundError(f"--resume {path}: no saved policy {model_path}")
    cfg = run_config_of(model_path)
    if cfg is None:
        raise FileNotFoundError(f"--resume {path}: no config.json of a softreach train run beside {model_path}")
    if cfg.get("model") != model or cfg.get("algo") != algo:
        raise ValueError(f"--resume {path}: that run trained {cfg.get('model')} with {cfg.get('algo')}, this one "
                         f"{model} with {algo}")
    done = int(cfg.get("timesteps", 0))
    return ResumePoint(run_dir=Path(cfg["_dir"]), model_path=model_path, config=cfg, timesteps=done,
                       phase=str(cfg.get("phase", "train")), pretrain_end=cfg.get("pretrain_end"))


def remaining(point: ResumePoint | None, pretrain: int, timesteps: int) -> tuple[int, int]:
    """``(unfiltered curriculum steps, main-phase steps)`` still to learn: a fresh run learns ``pretrain`` then
    ``timesteps`` steps; a resumed one what its interrupted phase lacks, then the main phase's rest.

    SB3 counts a phase finished at the first whole rollout at or past its total, so a finished curriculum's end
    (``pretrain_end``) is the step count it really reached, not ``pretrain``.
    """
    if point is None:
        return pretrain, timesteps
    done = point.timesteps
    if pretrain and point.phase == "pretrain":
        return max(0, pretrain - done), timesteps
    start = point.pretrain_end if (pretrain and point.pretrain_end is not None) else 0
    return 0, max(0, start + timesteps - done)


def load_for_resume(point: ResumePoint, cls: Any, venv: Any) -> Any:
    """The saved policy of ``point`` attached to ``venv`` (and SAC's replay buffer, where one was saved)."""
    model = cls.load(point.model_path, env=venv, device="cpu")
    buffer = point.run_dir / REPLAY_BUFFER
    if hasattr(model, "load_replay_buffer") and buffer.is_file():
        model.load_replay_buffer(buffer)
    return model


def restore_evaluations(callback: Any, run_dir: Path) -> None:
    """Give a new ``EvalCallback`` the interrupted run's evaluations, so that ``eval/evaluations.npz`` keeps
    them and ``best_model.zip`` is replaced only by a better evaluation than the best so far."""
    f = Path(run_dir) / "eval" / "evaluations.npz"
    if not f.is_file():
        return
    with np.load(f) as data:
        callback.evaluations_timesteps = [int(v) for v in data["timesteps"]]
        callback.evaluations_results = [list(r) for r in data["results"]]
        callback.evaluations_length = [list(r) for r in data["ep_lengths"]]
        if "successes" in data:
            callback.evaluations_successes = [list(r) for r in data["successes"]]
    if callback.evaluations_results:
        callback.best_mean_reward = max(float(np.mean(r)) for r in callback.evaluations_results)
        callback.last_mean_reward = float(np.mean(callback.evaluations_results[-1]))
    records = Path(run_dir) / "eval" / "interventions.npz"
    if records.is_file() and hasattr(callback, "records"):
        with np.load(records) as data:
            callback.records = {k: [float(v) for v in data[k]] for k in callback.records if k in data}


def save_interrupted(model: Any, out: Path, config: dict[str, Any], phase: str, pretrain_end: int | None,
                     target: int | None) -> TrainingInterrupted:
    """Save the policy so far and mark the run interrupted; returns the exception to raise."""
    model_path = Path(out) / "model.zip"
    model.save(model_path)
    if hasattr(model, "save_replay_buffer"):
        model.save_replay_buffer(Path(out) / REPLAY_BUFFER)
    config.update(status="interrupted", timesteps=int(model.num_timesteps), phase=phase, pretrain_end=pretrain_end)
    (Path(out) / "config.json").write_text(json.dumps(config, indent=2))
    return TrainingInterrupted(model_path, int(model.num_timesteps), target)


__all__ = ["REPLAY_BUFFER", "ResumePoint", "TrainingInterrupted", "load_for_resume", "remaining", "restore_evaluations",
           "resume_point", "save_interrupted"]
