"""softreach.agents: train landing policies with Stable-Baselines3 under the safety filter, evaluate them against
the unfiltered policy and the table-optimal controller, and report (numbers and plots).

* :mod:`.config` — the default hyperparameters (one dataclass per algorithm);
* :mod:`.train` — :func:`train` (PPO / SAC, vectorised envs, periodic evaluation, checkpoints, progress bar);
* :mod:`.evaluate` — :func:`evaluate` (per-episode metrics, aggregates with confidence intervals);
* :mod:`.report` — the JSON schema and the plots;
* :mod:`.demo` — the one-command demo;
* :mod:`.sweep` (grid and ids), :mod:`.sweep_exec` (local processes or Ray, resume), :mod:`.sweep_report` (the
  table, report and plots), :mod:`.sweep_cli` (:func:`run_sweep`) — ``softreach sweep``;
* :mod:`.commands` — the ``softreach train | evaluate | demo | sweep`` subcommands.

The functions ``train`` and ``evaluate`` share their modules' names: import them as
``from softreach.agents.train import train`` and ``from softreach.agents.evaluate import evaluate``. The names
below are imported lazily, so that ``softreach --help`` (which registers the subcommands) does not pay
for gymnasium, Stable-Baselines3 and torch.
"""

from __future__ import annotations

from softreach import lazy_exports

_EXPORTS = {
    "ALGOS": ".config", "MODELS": ".config", "PPOConfig": ".config", "RunConfig": ".config", "SACConfig": ".config",
    "defaults": ".config",
    "TrainSpec": ".train", "TrainResult": ".train", "load_policy": ".train",
    "EvalSpec": ".evaluate", "EvaluationResult": ".evaluate",
    "EVAL_SCHEMA": ".report", "validate_evaluation": ".report", "write_json": ".report", "write_plots": ".report",
    "run_demo": ".demo",
    "SweepSpec": ".sweep", "load_sweep_file": ".sweep", "run_sweep": ".sweep_cli",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(globals(), _EXPORTS)
