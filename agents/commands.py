"""The ``train``, ``evaluate``, ``demo`` and ``sweep`` (:mod:`.sweep_cli`) subcommands of ``softreach``."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from softreach.reach.registry import model_argument, model_metavar

from .config import ALGOS, METHODS

WIND_CHOICES = ("none", "random", "adversarial")
RULE_CHOICES = ("switch", "smooth")
START_CHOICES = ("certified", "inside", "paper", "uniform", "env")


def _budget(text: str) -> float | tuple[float, float]:
    """``Q`` or ``LOW:HIGH`` (seconds)."""
    try:
        if ":" in text:
            lo, hi = text.split(":", 1)
            return (float(lo), float(hi))
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"budget must be Q or LOW:HIGH in seconds, got {text!r}") from None


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``train``, ``evaluate`` and ``demo`` on the ``softreach`` parser's subparsers."""
    p = sub.add_parser("train", help="train a landing policy with Stable-Baselines3 (optionally under the safety filter)",
                       description="Train a PPO or SAC landing policy. With --filter the environment executes the "
                                   "filtered action (see docs/agents.md for what the learner is told). Defaults: "
                                   "softreach.agents.config.")
    p.add_argument("model", type=model_argument, metavar=model_metavar(),
                   help="a registered model or the module:Class path of your own Model subclass")
    p.add_argument("--algo", choices=ALGOS, default="ppo",
                   help="learning algorithm: ppo (Proximal Policy Optimisation, on-policy; default, tuned) or sac "
                        "(Soft Actor-Critic, off-policy; wired up, not tuned)")
    p.add_argument("--method", choices=METHODS, default="plain",
                   help="training method: plain (the algorithm as it is; default), lag (PPO-Lagrangian: a learned "
                        "multiplier prices the expected episode cost over Q) or saute (PPO-Saute: the remaining "
                        "budget joins the observation, the reward is -1 per step once it is spent); lag and saute "
                        "are the constrained-RL baselines, PPO only and without --filter (docs/agents.md)")
    p.add_argument("--filter", metavar="TABLE", default=None,
                   help="W_eps table of the safety filter, solved with --held (default: no filter)")
    p.add_argument("--rule", choices=RULE_CHOICES, default="switch",
                   help="filter rule where the policy's action fails the filter's test: switch (the best held "
                        "candidate; default) or smooth (the closest point to the policy's action towards it)")
    p.add_argument("--budget", type=_budget, default=None, metavar="Q|LO:HI",
                   help="budget Q of every episode, or a range (default: the environment's, point mass 0:0.6)")
    p.add_argument("--wind", choices=WIND_CHOICES, default=None, help="training wind (default random)")
    p.add_argument("--table", metavar="TABLE", default=None, help="table of the adversarial wind (default: --filter's)")
    p.add_argument("--timesteps", type=int, default=None, help="environment steps (default: the model's, see config)")
    p.add_argument("--n-envs", type=int, default=None, help="environments stepped together (default 8 for PPO)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the network's initial weights, the environments' starts and gusts and the "
                        "periodic evaluations (default 0)")
    p.add_argument("--intervention-penalty", type=float, default=None,
                   help="reward subtracted per step in which the filter acted (default: the model's, see "
                        "softreach.agents.config; 1.0 for the point mass)")
    p.add_argument("--action-label", choices=("policy", "applied"), default=None,
                   help="SAC: store the policy's or the applied action in the replay buffer (default policy)")
    p.add_argument("--eval-freq", type=int, default=None, help="steps between periodic evaluations (0: none)")
    p.add_argument("--pretrain-steps", type=int, default=None,
                   help="with --filter: steps learned without the filter first (a curriculum; default: the "
                        "model's, see softreach.agents.config)")
    p.add_argument("--eval-filter", metavar="TABLE", default=None,
                   help="repeat every periodic evaluation under this filter and record the share of steps it acted "
                        "(eval/interventions.npz); best_model.zip is still chosen by the policy's own evaluations")
    p.add_argument("--init", metavar="POLICY", default=None,
                   help="start from this saved policy's weights (same model and algorithm), e.g. one trained "
                        "without the filter; a new run counts its steps from 0")
    p.add_argument("--resume", metavar="POLICY", default=None,
                   help="continue an interrupted run from the model.zip it saved (or its run directory): the same "
                        "weights, optimiser state and step count, up to --timesteps in all; give the interrupted "
                        "command's other options again")
    p.add_argument("--out", metavar="DIR", default=None,
                   help="output directory (default runs/train/<model>-<algo>-<filtered|unfiltered>-s<seed>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run_train)

    p = sub.add_parser("evaluate", help="evaluate a policy (trained, table-optimal or random), filtered or not",
                       description="Run episodes and report landings, hard violations, budget use and interventions "
                                   "with 95% confidence intervals.")
    p.add_argument("model", type=model_argument, metavar=model_metavar(),
                   help="a registered model or the module:Class path of your own Model subclass")
    p.add_argument("--policy", required=True, metavar="PATH|optimal|random",
                   help="a saved policy (model.zip or its run directory), 'optimal' (the table's a*) or 'random'")
    p.add_argument("--filter", metavar="TABLE", default=None, help="apply the safety filter of this table")
    p.add_argument("--rule", choices=RULE_CHOICES, default="switch",
                   help="filter rule where the policy's action fails the filter's one-period test: switch (apply "
                        "the passing held candidate action whose next table value is lowest; default) or smooth (the "
                        "point closest to the policy's action on the segment to such a candidate)")
    p.add_argument("--budget", type=float, default=None, metavar="Q",
                   help="budget Q of every episode (default: drawn from the environment's range)")
    p.add_argument("--wind", choices=WIND_CHOICES, default="adversarial",
                   help="wind during the episodes: adversarial (the table's worst case b*; default, needs a table), "
                        "random (the environment's gusts) or none")
    p.add_argument("--table", metavar="TABLE", default=None,
                   help="table for 'optimal', the adversarial wind and inside/paper starts (default: --filter's)")
    p.add_argument("--episodes", type=int, default=100, help="number of episodes (default 100)")
    p.add_argument("--starts", choices=START_CHOICES, default="inside",
                   help="certified by the filter (inside RA~_Q and a held action passes: the starts of the guarantee; needs a "
                        "--held table), inside RA~_Q (sampled from the table), the paper's representative points, uniform over C1 "
                        "(outside the guarantee too), or the environment's own reset distribution "
                        "(default inside)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the starts, the budgets, the gusts and the random policy; episode i resets with "
                        "seed + i, so policies evaluated with the same seed are compared on the same episodes "
                        "(default 0)")
    p.add_argument("--json", dest="json_path", metavar="PATH", default=None, help="write aggregates and episodes here")
    p.add_argument("--plots", metavar="DIR", default=None, help="write the plots into this directory")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run_evaluate)

    p = sub.add_parser("demo", help="the whole mission: table, training, evaluation under the filter, report",
                       description="Solve a small point-mass table of the sampled-data game (cached), train PPO "
                                   "briefly (without the filter: the recipe measured best), evaluate its best checkpoint "
                                   "with and without the filter and the table-optimal controller from the starts the "
                                   "filter certifies, under adversarial and random wind, and write report.md with the "
                                   "plots.")
    p.add_argument("--out", metavar="DIR", default="runs/demo",
                   help="directory of the table, the training run, report.md and the plots (default runs/demo)")
    p.add_argument("--table", metavar="TABLE", default=None, help="use this table instead of solving the demo's")
    p.add_argument("--policy", metavar="PATH", default=None, help="evaluate this policy instead of training one")
    p.add_argument("--timesteps", type=int, default=None, help="training steps (default 200000)")
    p.add_argument("--n-envs", type=int, default=None,
                   help="environments stepped together in training (default 8, PPO's rollout is n_steps x n_envs)")
    p.add_argument("--episodes", type=int, default=30, help="episodes per row of the report (default 30)")
    p.add_argument("--budgets", type=float, nargs="+", default=[0.0, 0.3, 0.6], metavar="Q",
                   help="budgets Q [s] evaluated, one row each (default 0 0.3 0.6)")
    p.add_argument("--winds", choices=("random", "adversarial", "none"), nargs="+", default=["adversarial", "random"],
                   help="winds evaluated, one block of rows each (default adversarial random)")
    p.add_argument("--seed", type=int, default=0,
                   help="training seed; also the evaluation seed (the episodes' starts and gusts) unless --eval-seed "
                        "is given (default 0)")
    p.add_argument("--eval-seed", type=int, default=None,
                   help="evaluation seed: the starts and gusts of every row (default: --seed); fix it to compare "
                        "training seeds on the same episodes")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run_demo)

    from .sweep_cli import add_sweep_command  # the grid of runs: its own module

    add_sweep_command(sub)


def _threads() -> None:
    """One torch thread unless the user set OMP_NUM_THREADS (small MLPs gain nothing from more)."""
    import torch

    if "OMP_NUM_THREADS" not in os.environ:
        torch.set_num_threads(1)


def run_train(args: argparse.Namespace) -> int:
    from .resume import TrainingInterrupted
    from .safe_train import check_method, train_method
    from .train import TrainSpec, default_out

    _threads()
    run_over: dict[str, Any] = {}
    if args.intervention_penalty is not None:
        run_over["intervention_penalty"] = args.intervention_penalty
    if args.eval_freq is not None:
        run_over["eval_freq"] = args.eval_freq
    if args.pretrain_steps is not None:
        run_over["pretrain_steps"] = args.pretrain_steps
    algo_over: dict[str, Any] = {}
    if args.action_label is not None:
        if args.algo != "sac":
            raise ValueError(f"--action-label is a SAC option (PPO must store its own action), got --algo {args.algo}")
        algo_over["action_label"] = args.action_label
    spec = TrainSpec(model=args.model, algo=args.algo, filter=args.filter, rule=args.rule, budget=args.budget,
                     wind=args.wind, table=args.table, timesteps=args.timesteps, n_envs=args.n_envs, seed=args.seed,
                     out=args.out, progress=not args.quiet, init=args.init, eval_filter=args.eval_filter,
                     run_overrides=run_over, algo_overrides=algo_over, resume=args.resume)
    check_method(args.method, spec)
    if args.method == "lag" and args.resume:
        raise ValueError("--resume with --method lag would restart its cost critic and multiplier (they are not "
                         "saved with the policy): train the run again")
    if args.method != "plain" and spec.out is None and spec.resume is None:
        spec.out = str(default_out(spec, args.method))
    for line in train_notes(spec):
        print(f"softreach: {line}", file=sys.stderr)
    try:
        res, safety = train_method(spec, args.method)
    except TrainingInterrupted as stop:
        target = f" of {stop.target:,}" if stop.target else ""
        print(f"\nsoftreach: interrupted after {stop.timesteps:,}{target} steps; the policy so far is saved in "
              f"{stop.model_path}. Run the same command with --resume {stop.model_path} to continue from it.",
              file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("\nsoftreach: interrupted outside learning (while setting up or saving): no policy of this run was "
              "saved", file=sys.stderr)
        return 130
    before = int(res.config.get("timesteps_at_start", 0))
    print(f"trained {res.timesteps - before} steps in {res.wall_time_s:.0f} s "
          f"({(res.timesteps - before) / max(res.wall_time_s, 1e-9):.0f} steps/s)"
          + (f", resumed from {spec.resume} at step {before}: {res.timesteps} in all" if spec.resume else ""))
    print(f"training episodes of these {safety['steps']:,} steps: {safety['episodes']}, landed {safety['landed']}, "
          f"hard violations {safety['hard_violations']}, over Q {safety['over_budget']} (training_safety.json)")
    cert = safety.get("certified_starts")
    if cert is not None:
        print(f"  of them from starts the filter certified: {cert['episodes']}, landed {cert['landed']}, "
              f"hard violations {cert['hard_violations']}, over Q {cert['over_budget']}")
    print(f"policy: {res.model_path}" + (f"  best: {res.best_model_path}" if res.best_model_path else ""))
    print(f"evaluate: softreach evaluate {args.model} --policy {res.model_path}"
          + (f" --filter {args.filter}" if args.filter else "") + " --plots " + str(res.out_dir / "plots"))
    return 0


def train_notes(spec: Any) -> list[str]:
    """What ``softreach train`` says before it starts: a step count SB3 will round up (its whole rollouts).

    :raises ValueError: a filter table whose model the safety filter cannot decide for (no cells, no compiled
        enclosure), naming what to add, before any training
    """
    from softreach.reach import load_table
    from softreach.reach.proof.enclosure_check import lacking

    from .config import learn_unit, planned_steps
    from .train import resolve

    run, algo, _ = resolve(spec)  # raises, naming the first bad value
    notes = []
    for option, path in (("--filter", spec.filter), ("--eval-filter", spec.eval_filter)):
        if path is None:
            continue
        missing = lacking(load_table(path).model)
        if missing is not None:
            raise ValueError(f"{option} {path}: the safety filter cannot decide for this model: {missing}")
    pretrain = run.pretrain_steps if spec.filter else 0
    unit = learn_unit(algo, run.n_envs)
    for what, asked in (("--pretrain-steps", pretrain), ("--timesteps", run.timesteps)):
        if asked and planned_steps(asked, algo, run.n_envs) != asked:
            how = (f"whole rollouts of n_steps x n_envs = {algo.n_steps} x {run.n_envs}" if spec.algo == "ppo"
                   else f"updates every train_freq x n_envs = {unit // run.n_envs} x {run.n_envs}")
            notes.append(f"note: {spec.algo.upper()} learns in {how} = {unit:,} steps, so {what} {asked:,} trains "
                         f"{planned_steps(asked, algo, run.n_envs):,} steps (give a multiple of {unit:,} to train "
                         f"exactly that many)")
    return notes


def run_evaluate(args: argparse.Namespace) -> int:
    from .evaluate import EvalSpec, evaluate
    from .report import summary_lines, write_json, write_plots

    _threads()
    if args.json_path:
        jp = Path(args.json_path)
        if str(jp.parent) and not jp.parent.is_dir():
            raise ValueError(f"--json directory {jp.parent} does not exist")
    spec = EvalSpec(model=args.model, policy=args.policy, filter=args.filter, rule=args.rule, budget=args.budget,
                    wind=args.wind, table=args.table, episodes=args.episodes, starts=args.starts, seed=args.seed)
    try:
        res = evaluate(spec, progress=not args.quiet)
    except KeyboardInterrupt:
        print("\nsoftreach: evaluation interrupted; nothing was written", file=sys.stderr)
        return 130
    print("\n".join(summary_lines(res)))
    if args.json_path:
        print(f"wrote {write_json(res, args.json_path)}")
    if args.plots:
        from softreach.reach import load_table

        from .train import run_config_of

        table_path = args.table or args.filter
        table = load_table(table_path) if table_path else None
        cfg = run_config_of(args.policy) if args.policy not in ("optimal", "random") else None
        files = write_plots(res, args.plots, table=table, run_dir=cfg["_dir"] if cfg else None)
        print("wrote " + ", ".join(str(f) for f in files))
    return 0


def run_demo(args: argparse.Namespace) -> int:
    from .demo import DEMO_TIMESTEPS, run_demo as demo

    _threads()
    from .resume import TrainingInterrupted

    eval_seed = args.seed if args.eval_seed is None else args.eval_seed
    try:
        out = demo(out=args.out, table=args.table, policy=args.policy, timesteps=args.timesteps or DEMO_TIMESTEPS,
                   episodes=args.episodes, budgets=args.budgets, winds=args.winds, seed=args.seed,
                   progress=not args.quiet, n_envs=args.n_envs, eval_seed=eval_seed)
    except KeyboardInterrupt as stop:
        saved = (f" The policy trained so far is in {stop.model_path} (--policy {stop.model_path} evaluates it)."
                 if isinstance(stop, TrainingInterrupted) else "")
        print(f"\nsoftreach: demo interrupted; its table, finished or partly solved, is reused by the same "
              f"command.{saved}", file=sys.stderr)
        return 130
    print((out["report"].read_text().split("## Plots")[0]).strip())
    trained = "no training (--policy given)" if args.policy else f"training seed {args.seed}"
    print(f"\nseeds: {trained}; evaluation seed {eval_seed} (the starts and gusts of every row"
          + (", from --seed; --eval-seed sets it apart)" if args.eval_seed is None else ")"))
    print(f"\nreport: {out['report']}")
    return 0


__all__ = ["add_commands", "run_demo", "run_evaluate", "run_train"]
