"""``softreach demo``: the whole mission in one command.

1. solve a small point-mass ``W_eps`` table of the sampled-data game (``--held``; cached: an existing table file
   is reused), which ranks the filter's candidates (the filter's cells certify, whatever the table);
2. train a PPO landing policy without the filter, keeping the checkpoint whose periodic evaluation (by itself,
   where a crash costs 100) scored best, and repeating each evaluation under the filter to record how much the
   filter had to do (skipped with ``--policy``);
3. evaluate that checkpoint (``best_model.zip``) with the filter, the same policy without it, and the
   table-optimal controller ``a*``, from the starts the filter certifies (``--starts certified``), under
   adversarial (and by default random) wind, for several budgets ``Q``;
4. write ``report.md`` (led by the comparison on safety and on performance: landing, hard violations, budget,
   interventions, control effort, touchdown sink rate, time to land), ``report.json`` (every evaluation's
   aggregates) and the plots into ``--out``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from .evaluate import EvalSpec, EvaluationResult, evaluate
from .report import comparison_table, evaluation_document, summary_lines, write_plots
from .report_text import task_words

#: the demo's table: coarser than the model's default (101 x 101 x 111), so that the whole demo fits the time the
#: README states
DEMO_GRID = (61, 61)
DEMO_BUDGET_POINTS = 67
DEMO_TIMESTEPS = 200_000


@dataclass
class CompareSpec:
    """A comparison matrix: policies x winds x budgets, all from the same starts (paired).

    :param model: ``"pointmass"`` or ``"glider"``
    :param table: the ``W_eps`` table (filter, optimal controller, adversarial wind, starts)
    :param policy: a trained policy (path), evaluated with and without the filter; ``None``: optimal only
    :param winds: winds to evaluate under
    :param budgets: budgets ``Q``
    :param episodes: episodes per cell
    :param starts: start distribution
    :param rule: the filter's rule
    :param seed: evaluation seed (the same for every cell)
    """

    model: str = "pointmass"
    table: str = ""
    policy: str | None = None
    winds: Sequence[str] = ("adversarial", "random")
    budgets: Sequence[float] = (0.0, 0.3, 0.6)
    episodes: int = 50
    starts: str = "inside"
    rule: str = "switch"
    seed: int = 0
    labels: dict[str, str] = field(default_factory=lambda: {"filtered": "trained + filter",
                                                            "unfiltered": "trained, no filter",
                                                            "optimal": "table-optimal a*"})


def compare(spec: CompareSpec, progress: bool = True) -> list[tuple[str, str, EvaluationResult]]:
    """Run the matrix; returns ``[(key, label, result), ...]`` with ``key`` in filtered/unfiltered/optimal."""
    out = []
    policy_obj = None
    if spec.policy is not None:
        from .train import load_policy

        policy_obj = load_policy(spec.policy)
    for wind in spec.winds:
        for q in spec.budgets:
            runs = []
            if spec.policy is not None:
                runs += [("filtered", spec.policy, spec.table), ("unfiltered", spec.policy, None)]
            runs.append(("optimal", "optimal", None))
            for key, policy, filt in runs:
                es = EvalSpec(model=spec.model, policy=policy, filter=filt, rule=spec.rule, budget=float(q), wind=wind,
                              table=spec.table, episodes=spec.episodes, starts=spec.starts, seed=spec.seed)
                res = evaluate(es, policy_obj=policy_obj if key != "optimal" else None, progress=progress)
                out.append((key, spec.labels[key], res))
    return out


def solve_demo_table(path: Path, progress: bool = True) -> Path:
    """Solve the demo's point-mass table into ``path`` unless it exists already (then it is reused)."""
    if path.is_file():
        return path
    from softreach.reach import SolveConfig, SolverSettings, get_model, solve_table

    path.parent.mkdir(parents=True, exist_ok=True)
    model = get_model("pointmass")
    # the sampled-data game at the env's period: the table ranks the filter's candidates and blows the wind
    cfg = SolveConfig(shape=DEMO_GRID, budget_points=DEMO_BUDGET_POINTS, control_period=model.control_period,
                      settings=SolverSettings.from_accuracy("very_high", dtype="float32"))
    solve_table(model, cfg, path, progress=progress)
    return path


def headline(results: list[tuple[str, str, EvaluationResult]], training_seeds: int = 1) -> list[str]:
    """The report's lead: one sentence of result (hard violations and overspends of the filtered rows against
    the unfiltered ones, what reached the target), then what the sample can and cannot show.

    :param results: ``(key, label, result)`` with keys ``filtered``, ``unfiltered``, ``optimal``
    :param training_seeds: the number of training seeds behind the policy
    """
    def total(key: str, field: str) -> tuple[int, int]:
        rows = [r for k, _, r in results if k == key]
        return (sum(r.aggregates[field]["count"] for r in rows), sum(r.aggregates[field]["n"] for r in rows))

    if not results:
        return []
    words = task_words(results[0][2])
    hard_f, n_f = total("filtered", "hard_violation_rate")
    over_f, _ = total("filtered", "over_budget_rate")
    reached_f, _ = total("filtered", "landing_rate")
    lines = []
    if n_f:
        sentence = (f"**Under the filter the learned policy had {hard_f} hard violations and {over_f} overspends in "
                    f"{n_f} episodes ({words.reached}: {reached_f} of {n_f})")
        hard_u, n_u = total("unfiltered", "hard_violation_rate")
        if n_u:
            sentence += f"; without the filter, {hard_u} of {n_u} episodes left `C1`"
        reached_o, n_o = total("optimal", "landing_rate")
        if n_o:
            sentence += f"; the table's `a*` {words.reached} in {reached_o} of {n_o}"
        lines += [sentence + ".**", ""]
    worst = 3.0 / n_f if n_f else float("nan")
    lines += ["The safety claim rests on the filter's proof (`docs/filters.md`), not on this sample: "
              f"{n_f} episodes with no violation only bound the violation rate below {worst:.2g} at 95 % (the rule "
              "of three). Differences between rows whose intervals overlap are not shown by this sample.", ""]
    if training_seeds < 2:
        lines += ["The policy comes from one training seed: how much the performance columns (effort, time) vary "
                  "between seeds is not shown here (`softreach sweep` trains several seeds).", ""]
    return lines


def write_report(results: list[tuple[str, str, EvaluationResult]], out: Path, table_path: str,
                 run_dir: str | None, commands: Sequence[str], focus: tuple[str, float] | None = None,
                 wall: dict[str, float] | None = None, policy: str | None = None) -> Path:
    """``report.md`` + ``report.json`` + plots (for the ``focus`` wind and budget) into ``out``."""
    from softreach.reach import load_table

    out.mkdir(parents=True, exist_ok=True)
    table = load_table(table_path)
    plots_dir = out / "plots"
    plot_lines = []
    if focus is None and results:
        focus = (results[0][2].config["wind"], results[0][2].config["budget"])
    for key, label, res in results:
        c = res.config
        if focus is not None and (c["wind"], c["budget"]) == focus:
            files = write_plots(res, plots_dir, table=table, run_dir=run_dir if key == "filtered" else None,
                                prefix=f"{key}_")
            plot_lines.append(f"**{label}** ({c['wind']} wind, Q={c['budget']:g}): " +
                              ", ".join(f"[{f.name}](plots/{f.name})" for f in files))
    starts = results[0][2].config["starts"] if results else "inside"
    where = {"certified": "certified by the filter (inside `RA~_Q`, and a held action passes the one-period "
                          "test: the starts of the guarantee)",
             "inside": "inside `RA~_Q` (sampled from the table)"}
    doc = {"schema": "softreach.comparison/1", "table": str(table_path), "policy_run": run_dir, "policy": policy,
           "starts": starts,
           "commands": list(commands), "wall_time_s": wall or {},
           "evaluations": [{"key": k, "label": lab, **{x: y for x, y in evaluation_document(r).items()
                                                       if x != "episodes"}} for k, lab, r in results]}
    (out / "report.json").write_text(json.dumps(doc, indent=1))
    words = table.model.words
    lines = [f"# softreach: {table.model.name} under a soft-constrained safety filter", "",
             *headline(results),
             f"Table: `{table_path}`. Policy run: `{run_dir or '(none)'}`; evaluated checkpoint: `{policy}`. "
             f"Starts: {where.get(starts, starts)}; {results[0][2].config['episodes'] if results else 0} episodes "
             "per row, the same starts and gusts in every row of a (wind, Q) group.", "",
             "The comparison that matters: the learned policy with the filter against the table-optimal "
             f"controller `a*` and against itself without the filter, on safety ({words.success}, hard violations, budget) "
             "and on the task's performance terms. The reward optimises landing (+100), no crash or late landing "
             "(-100) and low control effort (mean squared normalised action), with a progress shaping term; "
             "the arrival speed and the time taken are reported, not rewarded. Control effort is the mean squared "
             "normalised action over the horizon; `a*` is bang-bang (every action at a bound), so its effort "
             "equals the time it flew (in units of the horizon).", "",
             "Rates are shown with Wilson 95% intervals; *hard violations* and *over Q* (budget used above "
             f"Q + {results[0][2].config['budget_tol'] if results else 0:g} s) are counts of episodes; "
             "*interventions* is the mean fraction of steps in which the filter replaced the action.", "",
             comparison_table([(lab, r) for _, lab, r in results]), "", "## Plots", ""]
    lines += [f"- {p}" for p in plot_lines]
    lines += ["", "## Details", ""]
    for _, lab, r in results:
        lines += ["```", *summary_lines(r), "```"]
    lines += ["", "## Commands", "", "```", *commands, "```"]
    if wall:
        lines += ["", "Wall time: " + ", ".join(f"{k} {v:.0f} s" for k, v in wall.items())]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def run_demo(out: str | Path = "runs/demo", table: str | None = None, policy: str | None = None,
             timesteps: int = DEMO_TIMESTEPS, episodes: int = 30, budgets: Sequence[float] = (0.0, 0.3, 0.6),
             winds: Sequence[str] = ("adversarial", "random"), seed: int = 0, progress: bool = True,
             n_envs: int | None = None, eval_seed: int | None = None) -> dict[str, Any]:
    """The demo (module docstring). Returns ``{"report", "table", "policy", "results"}``.

    :param seed: the training seed, and the evaluation seed unless ``eval_seed`` is given
    :param eval_seed: the evaluation seed (every row's starts and gusts); ``None``: ``seed``
    """
    eval_seed = seed if eval_seed is None else eval_seed
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    wall: dict[str, float] = {}
    commands = []
    t0 = time.perf_counter()
    if table is None:
        table_path = solve_demo_table(out / "pointmass_demo.srt", progress=progress)
        commands.append(f"softreach solve pointmass --held --grid {DEMO_GRID[0]} {DEMO_GRID[1]} --budget-points "
                        f"{DEMO_BUDGET_POINTS} --dtype float32 --out {table_path}")
    else:
        table_path = Path(table)
        if not table_path.is_file():
            raise FileNotFoundError(f"table {table} does not exist")
    from softreach.reach import load_table

    loaded = load_table(table_path)
    model = loaded.model.name  # a given table may be the glider's
    # the filter's guarantee is for the starts it certifies (its cells, whatever the table)
    starts = "certified"
    wall["table"] = time.perf_counter() - t0
    run_dir = None
    if policy is None:
        from .train import TrainSpec, train

        t0 = time.perf_counter()
        # learn to fly without the filter (a crash costs 100), keep the checkpoint that flies best by itself, and
        # deploy it under the filter: the recipe measured best (docs/agents.md: training under the filter taught
        # the policy to lean on it; choosing checkpoints by the filtered return chose one the filter flew)
        tr = train(TrainSpec(model=model, algo="ppo", filter=None, eval_filter=str(table_path), timesteps=timesteps,
                             seed=seed, n_envs=n_envs, out=str(out / "train"), progress=progress))
        wall["train"] = time.perf_counter() - t0
        # the checkpoint with the best periodic evaluation (a hard violation costs 100 of its return)
        policy = str(tr.best_model_path or tr.model_path)
        run_dir = str(tr.out_dir)
        commands.append(f"softreach train {model} --eval-filter {table_path} --timesteps {timesteps} --seed {seed} "
                        f"--out {tr.out_dir}")
    else:
        from .train import run_config_of

        cfg = run_config_of(policy)
        run_dir = cfg["_dir"] if cfg else None
    t0 = time.perf_counter()
    labels = CompareSpec().labels
    from .train import run_config_of

    cfg = run_config_of(policy)
    if cfg is not None:
        how = f"{cfg['algo'].upper()} trained {'with' if cfg.get('filter') else 'without'} filter"
        labels = {**labels, "filtered": f"{how}, + filter", "unfiltered": f"{how}, no filter"}
    cs = CompareSpec(model=model, table=str(table_path), policy=policy, winds=tuple(winds),
                     budgets=tuple(budgets), episodes=episodes, starts=starts, seed=eval_seed, labels=labels)
    results = compare(cs, progress=progress)
    wall["evaluate"] = time.perf_counter() - t0
    for w in winds:
        for q in budgets:
            for key, flag in (("filtered", f"--filter {table_path}"), ("unfiltered", f"--table {table_path}"),
                              ("optimal", f"--table {table_path}")):
                pol = "optimal" if key == "optimal" else policy
                commands.append(f"softreach evaluate {model} --policy {pol} {flag} --wind {w} --budget {q:g} "
                                f"--episodes {episodes} --starts {starts} --seed {eval_seed}")
    focus = ("adversarial", float(budgets[len(budgets) // 2])) if "adversarial" in winds and budgets else None
    report = write_report(results, out, str(table_path), run_dir, commands, focus=focus, wall=wall,
                          policy=policy)
    return {"report": report, "table": table_path, "policy": policy, "results": results}


__all__ = ["CompareSpec", "DEMO_BUDGET_POINTS", "DEMO_GRID", "DEMO_TIMESTEPS", "compare", "run_demo",
           "solve_demo_table", "write_report"]
