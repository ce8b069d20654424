"""``softreach train``: a landing policy with Stable-Baselines3, optionally under the safety filter.

What the learner is told when the filter is on (see ``docs/agents.md``):

* The environment executes the **filtered** action; observations, rewards and episode ends are those of the
  filtered closed loop. The filter is a deterministic function of ``(t, x, z)``, which the observation holds
  (state, remaining budget, time left), so "environment + filter" is again a Markov decision process and PPO
  and SAC learn in it without modification.
* **PPO** stores the policy's own (unclipped Gaussian) sample and its log-probability in the rollout buffer: the
  ratio ``pi_new(a) / pi_old(a)`` stays well defined. Storing the applied action instead would make the
  ratio meaningless (``a*`` may have almost no probability under the policy), so PPO always learns
  "in the filtered environment": where the filter overrides, the policy's action has no effect on what
  follows, and its advantage there is pure noise around zero.
* **SAC** stores ``(obs, action, reward, next_obs)`` in a replay buffer. With ``action_label="policy"``
  (default) it is the policy's action, as for PPO. With ``action_label="applied"`` it is the action the
  filter let through, i.e. the transition the plain environment actually made: the critic then learns the
  unfiltered dynamics' Q-function on the actions that were executed.
* With ``intervention_penalty > 0`` (default 1.0 per step, against +100 for a landing) each step in which the
  filter acted costs that much reward, so the policy is pushed to stay where the filter need not act and to
  land by itself. With 0 it is told nothing beyond the consequences of the filtered actions, and it learns to
  let the filter fly (measured on the point mass: it then lands in 0 % of episodes without the filter).
  ``info["filter_active"]`` is in every step's info either way.

Outputs under ``--out DIR``: ``model.zip`` (final policy), ``best_model.zip`` (best periodic evaluation),
``checkpoints/``, ``eval/evaluations.npz`` (``EvalCallback``), ``monitor/*.monitor.csv`` (training episodes),
``progress.csv`` (SB3 logger), ``config.json`` (everything needed to reproduce and to evaluate the run).
"""

from __future__ import annotations

import contextlib
import json
import math
import platform
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from softreach.reach.registry import env_id, model_class

from .config import ALGOS, PPOConfig, SACConfig, algo_kwargs, defaults, with_overrides
from .envs import RULES, WINDS, check_budget, check_choice, make_env
from .callbacks import progress_callback  # noqa: F401  (public here too)
from .policies import TRAIN_SCHEMA, load_policy, run_config_of  # noqa: F401  (public here too)
from .resume import load_for_resume, remaining, restore_evaluations, resume_point, save_interrupted
from .tables import TableOracle, as_table


@dataclass
class TrainSpec:
    """What ``softreach train`` was asked to do. ``None`` fields take the model's defaults (:mod:`.config`).

    :param model: a registered short name (``"pointmass"``, ``"glider"``, ``"dubins"``) or ``"module:Class"``
    :param algo: ``"ppo"`` or ``"sac"``
    :param filter: the safety filter's table (path); ``None`` trains without a filter
    :param rule: the filter's rule
    :param budget: ``Q`` of each episode, a ``(low, high)`` range, or ``None`` (the environment's default)
    :param wind: ``"none"``, ``"random"`` or ``"adversarial"``
    :param table: the table of ``wind="adversarial"`` (default: the filter's)
    :param timesteps: total environment steps
    :param n_envs: environments stepped together
    :param seed: seed of the algorithm and the environments
    :param out: output directory (default ``runs/train/<model>-<algo>-<filtered|unfiltered>-s<seed>``)
    :param progress: show a progress bar
    :param init: a saved policy (``model.zip`` of the same model and algorithm) whose weights the run starts
        from: a curriculum, e.g. learn to fly without the filter (fast: no filter decisions), then learn under
        it; the run's own hyperparameters apply
    :param eval_filter: a filter table under which every periodic evaluation is repeated and recorded (the closed
        loop the policy will be deployed in: ``eval/interventions.npz``, the filter's share of the steps); the
        policy's own evaluations still choose ``best_model.zip``. For a policy that learns without the filter,
        the recipe measured best on the point mass (``docs/agents.md``)
    :param run_overrides: fields of :class:`~softreach.agents.config.RunConfig` to replace
    :param algo_overrides: fields of the algorithm's config to replace
    :param resume: an interrupted run's ``model.zip`` (or directory) to continue (:mod:`.resume`): its weights,
        optimiser state and step count, learning up to ``timesteps`` in all, in its directory unless ``out`` is given
    """

    model: str = "pointmass"
    algo: str = "ppo"
    filter: str | None = None
    rule: str = "switch"
    budget: Any = None
    wind: str | None = None
    table: str | None = None
    timesteps: int | None = None
    n_envs: int | None = None
    seed: int = 0
    out: str | None = None
    progress: bool = True
    init: str | None = None
    eval_filter: str | None = None
    run_overrides: dict[str, Any] = field(default_factory=dict)
    algo_overrides: dict[str, Any] = field(default_factory=dict)
    resume: str | None = None


@dataclass
class TrainResult:
    """Where a training run put its outputs."""

    out_dir: Path
    model_path: Path
    best_model_path: Path | None
    config: dict[str, Any]
    wall_time_s: float
    timesteps: int


def default_out(spec: TrainSpec, method: str = "plain") -> Path:
    """``runs/train/<model>-<algo>-<filtered|unfiltered>-s<seed>``; a baseline method (``lag``, ``saute``) is
    named in place of the filter: ``runs/train/<model>-<algo>-<method>-s<seed>``."""
    kind = method if method != "plain" else "filtered" if spec.filter else "unfiltered"
    return Path("runs") / "train" / f"{spec.model}-{spec.algo}-{kind}-s{spec.seed}"


def _check_positive_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def resolve(spec: TrainSpec) -> tuple[Any, PPOConfig | SACConfig, dict[str, Any]]:
    """Check ``spec`` and merge it with the defaults; returns ``(run config, algo config, env settings)``.

    :raises ValueError: naming the first bad value
    """
    model_class(spec.model)  # raises, naming an unknown model
    check_choice("algorithm", spec.algo, ALGOS)
    check_choice("rule", spec.rule, RULES)
    d = defaults(spec.model, spec.algo)
    run = with_overrides(d.run, timesteps=spec.timesteps, n_envs=spec.n_envs, wind=spec.wind,
                         **spec.run_overrides)
    if spec.budget is not None:
        run = with_overrides(run, budget=spec.budget)
    algo = with_overrides(d.algo, **spec.algo_overrides)
    check_choice("wind", run.wind, WINDS)
    _check_positive_int("timesteps", run.timesteps)
    _check_positive_int("n_envs", run.n_envs)
    for name in ("eval_freq", "checkpoint_freq", "eval_episodes", "pretrain_steps"):
        v = getattr(run, name)
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"{name} must be an integer >= 0, got {v!r}")
    if not (isinstance(spec.seed, (int, np.integer)) and not isinstance(spec.seed, bool)):
        raise ValueError(f"seed must be an integer, got {spec.seed!r}")
    from softreach.reach.models import get_model

    horizon = get_model(spec.model).horizon
    budget = check_budget(run.budget, horizon)
    if run.wind == "adversarial" and not (spec.table or spec.filter):
        raise ValueError("--wind adversarial needs a table for the worst-case wind: give --filter TABLE or --table TABLE")
    if spec.resume is not None:
        if spec.init is not None:
            raise ValueError("--resume continues a run with its own weights: drop --init")
        resume_point(spec.resume, spec.model, spec.algo)  # raises, naming a missing or mismatched run
    for name, path in (("init policy", spec.init), ("eval filter table", spec.eval_filter)):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"{name} {path} does not exist")
    if spec.run_overrides.get("pretrain_steps") and not spec.filter:
        raise ValueError("pretrain steps are learned before the filter is switched on: they need --filter TABLE")
    if spec.run_overrides.get("intervention_penalty") and not spec.filter:
        raise ValueError("an intervention penalty needs --filter TABLE (without a filter nothing intervenes)")
    if not (isinstance(run.intervention_penalty, (int, float)) and math.isfinite(run.intervention_penalty)
            and run.intervention_penalty >= 0):
        raise ValueError(f"intervention penalty must be a finite number >= 0, got {run.intervention_penalty!r}")
    if not (isinstance(run.reward_scale, (int, float)) and math.isfinite(run.reward_scale) and run.reward_scale > 0):
        raise ValueError(f"reward scale must be a finite number > 0, got {run.reward_scale!r}")
    algo_kwargs(algo)  # validates the algorithm's choices
    for path in (spec.filter, spec.table):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"table {path} does not exist (solve one with `softreach solve {spec.model}`)")
    env_settings = {"model": spec.model, "wind": run.wind, "budget": budget, "filter": spec.filter,
                    "rule": spec.rule, "table": spec.table}
    return run, algo, env_settings


def _sac_class(action_label: str):
    from stable_baselines3 import SAC

    if action_label == "policy":
        return SAC

    class AppliedActionSAC(SAC):
        """SAC whose replay buffer stores the action the safety filter applied (``info["applied_action"]``)."""

        def _store_transition(self, replay_buffer, buffer_action, new_obs, reward, dones, infos):
            applied = [info.get("applied_action") for info in infos]
            if all(a is not None for a in applied):
                buffer_action = self.policy.scale_action(np.stack([np.asarray(a, dtype=np.float32) for a in applied]))
            super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)

    return AppliedActionSAC


def _versions() -> dict[str, str]:
    import gymnasium
    import stable_baselines3
    import torch

    return {"python": platform.python_version(), "stable_baselines3": stable_baselines3.__version__,
            "gymnasium": gymnasium.__version__, "torch": torch.__version__, "numpy": np.__version__}


@contextlib.contextmanager
def _mixed_envs_quiet():
    """Silence SB3's warning that the evaluation and training environments differ in type: by design the
    evaluation runs the deployed closed loop (filtered) where the learner may fly unfiltered."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
        yield


def train(spec: TrainSpec, *, model_class: Any = None, wrap_env: Any = None, callbacks: Any = ()) -> TrainResult:
    """Train a policy as ``spec`` says and save it (see the module docstring for the outputs).

    The hooks of the constrained-RL baselines (:mod:`.safe_rl`): ``model_class`` replaces SB3's ``PPO``,
    ``wrap_env(env, learner)`` wraps every environment made (``learner``: a training one), ``callbacks`` are
    added to the training's."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import DummyVecEnv

    from .callbacks import FilterEvalCallback, progress_callback

    run, algo_cfg, env_settings = resolve(spec)
    point = resume_point(spec.resume, spec.model, spec.algo) if spec.resume is not None else None
    out = Path(spec.out) if spec.out else (point.run_dir if point else default_out(spec))
    out.mkdir(parents=True, exist_ok=True)
    (out / "monitor").mkdir(exist_ok=True)

    filt = as_table(spec.filter) if spec.filter else None
    wind_src = spec.table or spec.filter
    oracle = TableOracle(wind_src) if (run.wind == "adversarial") else None

    # the periodic evaluations run the deployed closed loop: the filter the policy will fly under
    eval_filt = as_table(spec.eval_filter) if spec.eval_filter else filt

    def env_fn(rank: int, learner: bool, filtered: bool = True, table=None):
        use = (table if table is not None else filt) if filtered else None
        # the deployed closed loop: the evaluation filter's table
        deployed = table is not None
        name = ("train" if filtered else "pretrain") if learner else ("deployed" if deployed else "eval")
        def thunk():
            # the deployed loop is measured where the filter's guarantee holds: from the starts it certifies
            return make_env(spec.model, wind=run.wind, wind_table=oracle, budget=env_settings["budget"],
                            filter_table=use, rule=spec.rule, monitor=True,
                            monitor_file=str(out / "monitor" / f"{name}-{rank}"), monitor_append=point is not None,
                            reward_scale=run.reward_scale if learner else 1.0,
                            intervention_penalty=run.intervention_penalty if (learner and use is not None) else 0.0,
                            certified_starts=deployed)
        return (lambda: wrap_env(thunk(), learner)) if wrap_env is not None else thunk

    def training_envs(filtered: bool):
        v = DummyVecEnv([env_fn(i, True, filtered) for i in range(run.n_envs)])
        # a resumed run does not replay the starts and gusts its first part began with
        v.seed(spec.seed + (point.timesteps if point else 0))
        if filtered and filt is not None:
            from softreach.filters import VecSafetyFilter

            # one filter decision for all environments per step: the same decisions, several times faster
            v = VecSafetyFilter(v)
        return v

    # curriculum: learn to fly without the filter first (no filter decisions: several times faster per step)
    pretrain = run.pretrain_steps if filt is not None else 0
    pretrain_left, main_left = remaining(point, pretrain, run.timesteps)
    venv = training_envs(filtered=not pretrain_left)
    kwargs = algo_kwargs(algo_cfg)
    cls = (model_class or PPO) if spec.algo == "ppo" else _sac_class(algo_cfg.action_label)
    if point is not None:
        model = load_for_resume(point, cls, venv)
    else:
        model = cls("MlpPolicy", venv, seed=spec.seed, verbose=0, device="cpu", **kwargs)
    # saved with every policy of the run (model.zip, best_model.zip, checkpoints): evaluate names it on a mismatch
    model.softreach_model = spec.model
    if spec.init is not None:
        try:
            model.set_parameters(str(spec.init), exact_match=True, device="cpu")
        except (ValueError, KeyError, RuntimeError) as err:
            raise ValueError(f"init policy {spec.init} does not fit this run's {spec.algo.upper()} network "
                             f"({err})") from None
    if point is not None and (out / "progress.csv").is_file():  # SB3's logger starts its file afresh
        (out / "progress.csv").rename(out / f"progress-to-{point.timesteps}.csv")
    logger = configure(str(out), ["csv"])
    model.set_logger(logger)

    callbacks = list(callbacks)
    eval_env = deployed_env = None
    if run.eval_freq > 0:
        from softreach.filters import VecSafetyFilter

        eval_env = DummyVecEnv([env_fn(0, False)])
        eval_env.seed(spec.seed + 10_000)
        if filt is not None:
            eval_env = VecSafetyFilter(eval_env)  # the type EvalCallback expects: the training env's
        if eval_filt is not None and eval_filt is not filt:
            deployed_env = VecSafetyFilter(DummyVecEnv([env_fn(0, False, table=eval_filt)]))
            deployed_env.seed(spec.seed + 10_000)
        callbacks.append(FilterEvalCallback(eval_env, deployed_env=deployed_env,
                                            n_eval_episodes=max(1, run.eval_episodes),
                                            eval_freq=max(1, run.eval_freq // run.n_envs),
                                            log_path=str(out / "eval"), best_model_save_path=str(out),
                                            deterministic=True, verbose=0))
        if point is not None:
            restore_evaluations(callbacks[-1], out)
    if run.checkpoint_freq > 0:
        callbacks.append(CheckpointCallback(save_freq=max(1, run.checkpoint_freq // run.n_envs),
                                            save_path=str(out / "checkpoints"), name_prefix="model"))
    if spec.progress:
        callbacks.append(progress_callback(f"train {spec.model} {spec.algo}{' +filter' if filt else ''}"))

    config = {
        "schema": TRAIN_SCHEMA,
        "model": spec.model,
        "algo": spec.algo,
        "env_id": env_id(spec.model),
        "filter": {"table": str(spec.filter), "rule": spec.rule} if spec.filter else None,
        "wind": run.wind,
        "wind_table": str(wind_src) if run.wind == "adversarial" else None,
        "budget": env_settings["budget"],
        "seed": spec.seed,
        "init": str(spec.init) if spec.init else None,
        "eval_filter": str(spec.eval_filter) if spec.eval_filter else None,
        "run": asdict(run),
        "algo_config": asdict(algo_cfg),
        "versions": _versions(),
        "status": "running",
        "resumed_from": str(point.model_path) if point else None,
        "timesteps_at_start": point.timesteps if point else 0,
    }
    (out / "config.json").write_text(json.dumps(config, indent=2))
    t0 = time.perf_counter()
    phase, pretrain_end = ("pretrain", None) if pretrain_left else ("train", point.pretrain_end if point else None)
    try:
        if pretrain_left:
            with _mixed_envs_quiet():
                model.learn(total_timesteps=pretrain_left, callback=CallbackList(callbacks), progress_bar=False,
                            reset_num_timesteps=point is None)
            phase, pretrain_end = "train", int(model.num_timesteps)
            venv.close()
            venv = training_envs(filtered=True)
            model.set_env(venv)
        if main_left:
            with _mixed_envs_quiet():
                model.learn(total_timesteps=main_left, callback=CallbackList(callbacks), progress_bar=False,
                            reset_num_timesteps=not (pretrain or point))
    except KeyboardInterrupt:
        # Ctrl-C: keep what was learned and say how to go on (softreach train --resume)
        target = (pretrain_end or pretrain) + run.timesteps if pretrain else run.timesteps
        raise save_interrupted(model, out, config, phase, pretrain_end, target) from None
    finally:
        venv.close()
        for env in (eval_env, deployed_env):
            if env is not None:
                env.close()
        logger.close()  # progress.csv: left open, the garbage collector closes it later with a ResourceWarning
    wall = time.perf_counter() - t0
    model_path = out / "model.zip"
    model.save(model_path)
    best = out / "best_model.zip"
    config.update(status="done", wall_time_s=wall, timesteps=int(model.num_timesteps), phase="train",
                  pretrain_end=pretrain_end,
                  steps_per_s=(model.num_timesteps - config["timesteps_at_start"]) / wall if wall > 0 else math.nan)
    (out / "config.json").write_text(json.dumps(config, indent=2))
    return TrainResult(out_dir=out, model_path=model_path, best_model_path=best if best.exists() else None,
                       config=config, wall_time_s=wall, timesteps=int(model.num_timesteps))


__all__ = ["TRAIN_SCHEMA", "TrainResult", "TrainSpec", "default_out", "load_policy", "progress_callback", "resolve",
           "run_config_of", "train"]
