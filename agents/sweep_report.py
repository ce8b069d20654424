"""A sweep's tidy table (``results.csv``: one row per run and evaluation), its report and its plots.

Columns, in order: :data:`CONFIG_COLUMNS` (the run: id, status, error, each grid field), :data:`EVAL_COLUMNS`
(the evaluation), :data:`RUN_COLUMNS` (timings) and the metrics: every aggregate of
:data:`softreach.agents.report.AGGREGATE_FIELDS` flattened as ``<name>_<key>``, a rate with its Wilson interval
(``landing_rate_value, _low, _high, _count, _n``), a mean with its Student-t interval (``return_mean, _low,
_high, _std, _min, _max, _n``; ``budget_used`` also ``_p50, _p90, _excess_max``), and ``outcomes_<outcome>``.
Empty cells where there is no value: a failed run, no filter, nothing landed.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .evaluate import wilson
from .report import AGGREGATE_FIELDS, MEAN, RATE
from .report_plots import _plt, _save
from .sweep import EvalSetting, SweepRun, budget_text
from .sweep_methods import method_lines, paired_lines, plot_deployed

CONFIG_COLUMNS = ("run_id", "status", "error", "model", "algo", "method", "rule", "budget", "wind", "variant", "seed",
                  "timesteps", "n_envs", "table")
EVAL_COLUMNS = ("eval_id", "eval_wind", "eval_budget", "eval_filter", "eval_rule", "episodes", "starts",
                "eval_seed", "checkpoint")
RUN_COLUMNS = ("train_timesteps", "train_wall_s", "eval_wall_s")
#: what the training episodes did (:class:`~softreach.agents.safe_train.TrainingSafetyCounter`): counts over the
#: whole training and per 100k environment steps; ``train_certified_*``: the episodes from starts the training's
#: safety filter certified (empty for a run trained without one)
TRAIN_SAFETY_COLUMNS = ("train_episodes", "train_landed", "train_hard_violations", "train_over_budget",
                        "train_hard_per_100k", "train_over_per_100k", "train_certified_episodes",
                        "train_certified_hard_violations", "train_certified_over_budget")
RATE_KEYS = ("value", "low", "high", "count", "n")
MEAN_KEYS = ("mean", "low", "high", "std", "min", "max", "n")
OUTCOMES = ("landed", "hard_violation", "timeout")
#: the fields that tell configurations apart in the report (the seed is pooled over)
GROUP_FIELDS = ("model", "algo", "method", "rule", "budget", "wind", "variant")


def metric_columns() -> list[str]:
    """The metric columns, in :data:`AGGREGATE_FIELDS` order."""
    cols = []
    for name, (kind, _) in AGGREGATE_FIELDS.items():
        kind = kind.rstrip("?")
        if kind == RATE:
            cols += [f"{name}_{k}" for k in RATE_KEYS]
        elif kind == MEAN:
            cols += [f"{name}_{k}" for k in MEAN_KEYS]
            if name == "budget_used":
                cols += [f"{name}_{k}" for k in ("p50", "p90", "excess_max")]
        elif name == "outcomes":
            cols += [f"outcomes_{k}" for k in OUTCOMES]
        elif name not in EVAL_COLUMNS:  # "episodes" is already an evaluation column
            cols.append(name)
    return cols


COLUMNS = CONFIG_COLUMNS + EVAL_COLUMNS + RUN_COLUMNS + TRAIN_SAFETY_COLUMNS + tuple(metric_columns())


def _flatten(aggregates: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, (kind, _) in AGGREGATE_FIELDS.items():
        value = aggregates.get(name)
        kind = kind.rstrip("?")
        if kind in (RATE, MEAN) or name == "outcomes":
            keys = RATE_KEYS if kind == RATE else MEAN_KEYS if kind == MEAN else OUTCOMES
            if name == "budget_used":
                keys = keys + ("p50", "p90", "excess_max")
            prefix = "outcomes" if name == "outcomes" else name
            for k in keys:
                out[f"{prefix}_{k}"] = None if value is None else value.get(k)
        else:
            out[name] = value
    return out


def table_rows(items: Sequence[tuple[SweepRun, list[EvalSetting], dict[str, Any] | None]]) -> list[dict[str, Any]]:
    """One row per run and evaluation, in grid order; a run without a result (never run) is ``"missing"``.

    :param items: ``(run, its evaluations, its result.json or None)``
    """
    rows = []
    for run, evals, result in items:
        result = result or {"status": "missing", "error": "no result (the run did not finish)", "train": {},
                            "evaluations": {}}
        train = result.get("train", {})
        safety = train.get("safety") or {}
        per = safety.get("per_100k") or {}
        certified = safety.get("certified_starts") or {}
        base = {"run_id": run.run_id, "model": run.model, "algo": run.algo, "method": run.method, "rule": run.rule,
                "budget": budget_text(run.budget), "wind": run.wind, "variant": run.variant, "seed": run.seed,
                "timesteps": run.timesteps, "n_envs": run.n_envs, "table": run.table,
                "train_timesteps": train.get("timesteps"), "train_wall_s": train.get("wall_time_s"),
                "train_episodes": safety.get("episodes"), "train_landed": safety.get("landed"),
                "train_hard_violations": safety.get("hard_violations"), "train_over_budget": safety.get("over_budget"),
                "train_hard_per_100k": per.get("hard_violations"), "train_over_per_100k": per.get("over_budget"),
                "train_certified_episodes": certified.get("episodes"),
                "train_certified_hard_violations": certified.get("hard_violations"),
                "train_certified_over_budget": certified.get("over_budget")}
        for ev in evals:
            e = result.get("evaluations", {}).get(ev.eval_id)
            row = {**base, "eval_id": ev.eval_id, "eval_wind": ev.wind, "eval_budget": ev.budget,
                   "eval_filter": ev.filter, "episodes": ev.episodes, "starts": ev.starts, "eval_seed": ev.seed}
            if e is None:  # the run failed (or was killed) before this evaluation
                row.update(status=result["status"] if result["status"] != "done" else "missing",
                           error=result.get("error") or "evaluation missing")
            else:
                row.update(status=e["status"], error=e.get("error"), eval_rule=e.get("rule"),
                           checkpoint=e.get("checkpoint"), eval_wall_s=e.get("wall_time_s"),
                           **_flatten(e.get("aggregates") or {}))
            rows.append({c: row.get(c) for c in COLUMNS})
    return rows


def write_table(rows: list[dict[str, Any]], path: str | Path) -> Path:
    """``rows`` as CSV with the :data:`COLUMNS` header (``None`` as an empty cell)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    tmp.replace(path)
    return path


def read_table(path: str | Path) -> list[dict[str, str]]:
    """The rows of a ``results.csv`` (strings, as CSV holds them)."""
    with Path(path).open(newline="") as fh:
        return list(csv.DictReader(fh))


# --------------------------------------------------------------------------------------------- grouping

METHOD_NAMES = {"lag": "Lagrangian", "saute": "Saute"}


def _label(row: dict[str, Any]) -> str:
    method = row.get("method") or "plain"
    algo = row["algo"] if method == "plain" else f"{row['algo'].upper()}-{METHOD_NAMES.get(method, method)}"
    parts = [row["model"], algo, "no filter" if row["rule"] == "none" else f"filter {row['rule']}",
             f"Q {row['budget']}", f"{row['wind']} wind"]
    if row["variant"] != "default":
        parts.append(row["variant"])
    return ", ".join(parts)


def _eval_label(row: dict[str, Any]) -> str:
    q = "drawn" if row["eval_budget"] is None else f"{row['eval_budget']:g}"
    return f"eval: {row['eval_wind']} wind, Q={q}, filter {row['eval_filter']}"


def _groups(rows: list[dict[str, Any]], keys: Sequence[str]) -> dict[tuple, list[dict[str, Any]]]:
    out: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        out.setdefault(tuple(r[k] for k in keys), []).append(r)
    return out


def _pct(count: int, n: int) -> str:
    w = wilson(count, n)
    if w["value"] is None:
        return "—"
    return f"{100 * w['value']:.0f}% [{100 * w['low']:.0f}, {100 * w['high']:.0f}]"


def _seed_mean(rows: list[dict[str, Any]], key: str) -> str:
    """The mean over seeds of a per-seed mean, with the seeds' range: ``mean (min-max)``."""
    vals = [float(r[key]) for r in rows if r.get(key) not in (None, "")]
    if not vals:
        return "—"
    return f"{np.mean(vals):.3f} ({min(vals):.3f}-{max(vals):.3f})"


def pooled_lines(rows: list[dict[str, Any]]) -> list[str]:
    """A markdown table: per configuration and evaluation, the seeds' episodes pooled (Wilson intervals of the
    pooled counts) and the per-seed landing rates, so the seeds' spread shows; the performance terms as the mean
    of the seeds' means with their range."""
    head = ["| configuration | evaluation | seeds done | landing rate (pooled) | per seed | hard violations | "
            "over Q | interventions (mean of seeds) | return (mean of seeds) | control effort | touchdown sink rate "
            "[m/s] | time to land [s] | training: hard violations, overspends per 100k steps (mean of seeds) |",
            "|---" * 13 + "|"]
    lines = []
    for _, rs in _groups(rows, GROUP_FIELDS + ("eval_id",)).items():
        ok = [r for r in rs if r["status"] == "done"]
        n = sum(r["landing_rate_n"] for r in ok)
        landed = sum(r["landing_rate_count"] for r in ok)
        hard = sum(r["hard_violation_rate_count"] for r in ok)
        over = sum(r["over_budget_rate_count"] for r in ok)
        per_seed = ", ".join(f"s{r['seed']}: {100 * r['landing_rate_value']:.0f}%" for r in ok) or "—"
        inter = [r["intervention_rate_mean"] for r in ok if r["intervention_rate_mean"] is not None]
        ret = [r["return_mean"] for r in ok if r["return_mean"] is not None]
        perf = [_seed_mean(ok, k) for k in ("control_effort_mean", "touchdown_sink_rate_mean", "time_to_land_mean")]
        trained = [(r["train_hard_per_100k"], r["train_over_per_100k"]) for r in ok
                   if r.get("train_hard_per_100k") not in (None, "")]
        perf.append(f"{np.mean([h for h, _ in trained]):.0f}, {np.mean([o for _, o in trained]):.0f}" if trained else "—")
        lines.append(f"| {_label(rs[0])} | {_eval_label(rs[0])} | {len(ok)}/{len(rs)} | {_pct(landed, n)} | "
                     f"{per_seed} | {hard}/{n} | {over}/{n} | "
                     f"{f'{100 * np.mean(inter):.1f}%' if inter else '—'} | "
                     f"{f'{np.mean(ret):.1f}' if ret else '—'} | " + " | ".join(perf) + " |")
    return head + lines


# --------------------------------------------------------------------------------------------- plots

def plot_metric(rows: list[dict[str, Any]], metric: str, out: str | Path, ylabel: str) -> Path | None:
    """One panel per evaluation setting; per configuration one point per seed with its 95 % interval
    (``<metric>_value|mean``, ``_low``, ``_high``) and a bar at the mean of the seeds. ``None`` if no run
    finished."""
    done = [r for r in rows if r["status"] == "done"]
    if not done:
        return None
    centre = f"{metric}_value" if f"{metric}_value" in done[0] else f"{metric}_mean"
    evals = _groups(done, ("eval_id",))
    configs = list(_groups(done, GROUP_FIELDS))
    plt = _plt()
    fig, axs = plt.subplots(len(evals), 1, figsize=(max(6.0, 1.6 * len(configs) + 3), 2.8 * len(evals)),
                            squeeze=False)
    for ax, (_, rs) in zip(axs[:, 0], evals.items()):
        for i, key in enumerate(configs):
            pts = [r for r in rs if tuple(r[k] for k in GROUP_FIELDS) == key and r[centre] is not None]
            for j, r in enumerate(pts):
                x = i + (j - (len(pts) - 1) / 2) * 0.08
                ax.errorbar(x, r[centre], yerr=[[r[centre] - r[f"{metric}_low"]], [r[f"{metric}_high"] - r[centre]]],
                            fmt="o", color=f"C{r['seed'] % 10}", ms=4, capsize=2,
                            label=f"seed {r['seed']}" if i == 0 else None)
            if pts:
                ax.hlines(np.mean([r[centre] for r in pts]), i - 0.3, i + 0.3, color="k", lw=1.5)
        ax.set_xticks(range(len(configs)))
        ax.set_xticklabels([_label(dict(zip(GROUP_FIELDS, k))).replace(", ", "\n", 2) for k in configs], fontsize=7)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.set_title(_eval_label(rs[0]), fontsize=8)
        if ax is axs[0, 0]:
            ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{ylabel}: each seed with its 95% interval, black bar = mean of seeds", fontsize=9)
    return _save(fig, out)


def plot_learning(results: Sequence[tuple[SweepRun, dict[str, Any] | None]], out: str | Path) -> Path | None:
    """One panel per configuration, one line per seed: the periodic evaluations' mean return over training
    (running mean of the training episodes where a run has no periodic evaluation)."""
    from .report import learning_data

    groups: dict[tuple, list[tuple[SweepRun, dict[str, Any]]]] = {}
    for run, res in results:
        rd = ((res or {}).get("train") or {}).get("run_dir")
        if rd:
            key = (run.model, run.algo, run.method, run.rule, budget_text(run.budget), run.wind, run.variant)
            groups.setdefault(key, []).append((run, learning_data(rd)))
    groups = {k: v for k, v in groups.items() if any(d for _, d in v)}
    if not groups:
        return None
    plt = _plt()
    fig, axs = plt.subplots(len(groups), 1, figsize=(7, 2.8 * len(groups)), squeeze=False)
    for ax, (key, runs) in zip(axs[:, 0], groups.items()):
        for run, data in runs:
            if "eval" in data:
                ax.plot(data["eval"]["timesteps"], data["eval"]["returns"].mean(axis=1), "o-", ms=3,
                        color=f"C{run.seed % 10}", label=f"seed {run.seed} (evaluations)")
            elif "train" in data:
                tr = data["train"]
                k = max(1, len(tr["returns"]) // 10)
                ax.plot(tr["timesteps"][k - 1:], np.convolve(tr["returns"], np.ones(k) / k, mode="valid"),
                        color=f"C{run.seed % 10}", label=f"seed {run.seed} (training episodes)")
        ax.set_title(_label(dict(zip(GROUP_FIELDS, key))), fontsize=8)
        ax.set_xlabel("environment steps", fontsize=8)
        ax.set_ylabel("episode return", fontsize=8)
        ax.legend(fontsize=7)
    return _save(fig, out)


def plot_violations_return(rows: list[dict[str, Any]], out: str | Path) -> Path | None:
    """The comparison at a glance: per run (one point per seed and configuration), the hard violations plus
    overspends of its training episodes per 100k steps (x) against the mean return of its deployed evaluations
    (y), one panel without and one with the filter at deployment; the label counts the deployed hard violations
    and overspends. ``None`` if no run has both."""
    done = [r for r in rows if r["status"] == "done" and r.get("train_hard_per_100k") not in (None, "")]
    if not done:
        return None
    plt = _plt()
    filters = [f for f in ("off", "on") if any(r["eval_filter"] == f for r in done)]
    configs = list(_groups(done, GROUP_FIELDS))
    markers = "osD^v<>P*X"
    fig, axs = plt.subplots(1, len(filters), figsize=(5.5 * len(filters), 4.2), squeeze=False, sharey=True)
    for ax, f in zip(axs[0], filters):
        for i, key in enumerate(configs):
            runs = _groups([r for r in done if r["eval_filter"] == f and tuple(r[k] for k in GROUP_FIELDS) == key],
                           ("run_id",))
            xs, ys, hard, over, n = [], [], 0, 0, 0
            for rs in runs.values():
                xs.append(float(rs[0]["train_hard_per_100k"]) + float(rs[0]["train_over_per_100k"]))
                ys.append(float(np.mean([r["return_mean"] for r in rs if r["return_mean"] is not None])))
                hard += sum(r["hard_violation_rate_count"] for r in rs)
                over += sum(r["over_budget_rate_count"] for r in rs)
                n += sum(r["hard_violation_rate_n"] for r in rs)
            if xs:
                ax.scatter(xs, ys, marker=markers[i % len(markers)], color=f"C{i % 10}", s=40,
                           label=f"{_label(dict(zip(GROUP_FIELDS, key)))}\n deployed: {hard} hard, {over} over Q of {n}")
        ax.set_xlabel("training: hard violations + overspends per 100k steps", fontsize=8)
        ax.set_title(f"deployed {'with' if f == 'on' else 'without'} the filter (mean return over its evaluations)",
                     fontsize=8)
        ax.legend(fontsize=6, loc="best")
    axs[0, 0].set_ylabel("deployed mean return", fontsize=8)
    fig.suptitle("violations during training against return at deployment: one point per seed and method", fontsize=9)
    return _save(fig, out)


# --------------------------------------------------------------------------------------------- report

def write_report(rows: list[dict[str, Any]], results: Sequence[tuple[SweepRun, dict[str, Any] | None]],
                 out: str | Path, command: str, counts: dict[str, int], wall_s: float) -> Path:
    """``report.md`` and ``plots/`` in ``out``: counts, the pooled table, failures with their errors, plots.

    :param rows: the table's rows (:func:`table_rows`)
    :param results: each run with its ``result.json`` (for the learning curves)
    :param out: the sweep's output folder
    :param command: the command that reruns or resumes the sweep
    :param counts: ``runs``, ``skipped`` and ``ran``
    :param wall_s: wall time of this invocation
    """
    out = Path(out)
    (out / "plots").mkdir(parents=True, exist_ok=True)
    plots = [p for p in (plot_metric(rows, "landing_rate", out / "plots" / "landing_rate.png", "landing rate"),
                         plot_metric(rows, "return", out / "plots" / "return.png", "mean return"),
                         plot_learning(results, out / "plots" / "learning_curves.png"),
                         plot_violations_return(rows, out / "plots" / "violations_vs_return.png"),
                         plot_deployed(rows, out / "plots" / "deployed_violations_vs_return.png"))
             if p is not None]
    status = {s: sum(1 for r in rows if r["status"] == s) for s in ("done", "failed", "killed", "missing")}
    checkpoints: dict[str, int] = {}
    for r in rows:
        if r["checkpoint"]:
            checkpoints[r["checkpoint"]] = checkpoints.get(r["checkpoint"], 0) + 1
    lines = ["# softreach sweep", "", f"Rerun or resume (finished runs are skipped): `{command}`", "",
             f"Runs: {counts.get('runs', 0)} ({counts.get('skipped', 0)} already done and skipped, "
             f"{counts.get('ran', 0)} run now); wall time of this invocation {wall_s:.0f} s.", "",
             "Table rows (run x evaluation): " + ", ".join(f"{v} {k}" for k, v in status.items() if v) +
             ". The full table with every interval: [results.csv](results.csv).", "",
             "Evaluated checkpoint: " + (", ".join(f"`{k}` in {v} rows" for k, v in checkpoints.items()) or "none") +
             " (`best_model.zip`: the best periodic evaluation of the training run).", "",
             "Seeds pooled: counts summed over the finished seeds (Wilson 95 % intervals); the per-seed landing "
             "rates show their spread.", "", *pooled_lines(rows), ""]
    compared = paired_lines(rows)
    if compared:
        lines += ["## Recipes compared", "",
                  "Per evaluation setting, each recipe deployed alone and with the filter, its seeds pooled. Rates: "
                  "Wilson 95 % intervals of the pooled episodes; return, effort and time to land: the mean of every "
                  "episode, the 95 % interval over the episodes, then over the seeds' means.", "", *compared, "",
                  "Every deployment with its effort and time to land:", "", *method_lines(rows), ""]
    bad = [r for r in rows if r["status"] != "done"]
    if bad:
        lines += ["## Runs that did not finish", "", "| run | evaluation | status | error |", "|---|---|---|---|"]
        lines += [f"| {r['run_id']} | {r['eval_id']} | {r['status']} | {str(r['error']).replace('|', '/')} |"
                  for r in bad]
        lines += ["", "Rerun the same command to retry them (finished runs are skipped).", ""]
    lines += ["## Plots", ""] + [f"- [{p.name}](plots/{p.name})" for p in plots]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


__all__ = ["COLUMNS", "CONFIG_COLUMNS", "EVAL_COLUMNS", "RUN_COLUMNS", "TRAIN_SAFETY_COLUMNS", "metric_columns",
           "plot_learning", "plot_metric", "plot_violations_return", "pooled_lines", "read_table", "table_rows", "write_report", "write_table"]
