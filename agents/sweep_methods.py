"""The budget comparison's table in a sweep's report: per evaluation setting (wind, ``Q``), one row per recipe
(training method, filter rule during training, training budget) and deployment (with or without the filter),
its seeds pooled.

Intervals, 95 %: rates (landing, hard violations, overspends) pool the seeds' episodes (Wilson); the return,
control effort and time to land give the interval over the pooled episodes (Student t of the pooled mean, from
each seed's mean, standard deviation and count) and the interval over the seeds' means (Student t of the seed
means, :func:`~softreach.agents.statistics.mean_ci`), which is the one that says how much a retrained policy may
differ.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .statistics import mean_ci, wilson

#: the baselines' names in the table
BASELINES = {"lag": "PPO-Lagrangian", "saute": "PPO-Saute"}


def recipe(row: dict[str, Any]) -> str:
    """How a run trained, in words: the method, the filter during training and the training budget."""
    method = row.get("method") or "plain"
    if method in BASELINES:
        name = BASELINES[method]
    elif row["rule"] == "none":
        name = f"{row['algo'].upper()} learned without the filter"
    else:
        name = f"{row['algo'].upper()} trained under the filter ({row['rule']})"
    budget = str(row["budget"])
    return f"{name}, {'Q drawn per episode' if budget == 'default' else f'trained at Q = {budget}'}"


def pooled_mean(rows: Sequence[dict[str, Any]], name: str, lower: float = -math.inf,
                upper: float = math.inf) -> dict[str, Any] | None:
    """The mean of every episode of ``rows`` with its Student-t 95 % interval, from each row's ``<name>_mean``,
    ``_std`` and ``_n`` (the pooled variance: within-row sums of squares plus the rows' spread about the pooled
    mean), cut to ``[lower, upper]`` where the quantity is bounded (as :func:`mean_ci`); ``None`` without
    episodes."""
    parts = [(int(r[f"{name}_n"]), float(r[f"{name}_mean"]), float(r[f"{name}_std"] or 0.0)) for r in rows
             if r.get(f"{name}_n") not in (None, "", 0) and r.get(f"{name}_mean") not in (None, "")]
    n = sum(k for k, _, _ in parts)
    if n == 0:
        return None
    m = sum(k * v for k, v, _ in parts) / n
    if n == 1:
        return {"mean": m, "low": m, "high": m, "n": 1}
    from scipy.stats import t as student

    ss = sum((k - 1) * s * s + k * (v - m) ** 2 for k, v, s in parts)
    half = float(student.ppf(0.975, n - 1)) * math.sqrt(ss / (n - 1) / n)
    return {"mean": m, "low": max(m - half, lower), "high": min(m + half, upper), "n": n}


def _num(x: Any) -> float | None:
    return None if x in (None, "") else float(x)


def _rate(rows: Sequence[dict[str, Any]], name: str) -> tuple[int, int]:
    return (sum(int(r[f"{name}_count"]) for r in rows), sum(int(r[f"{name}_n"]) for r in rows))


def _both(rows: Sequence[dict[str, Any]], name: str, digits: int, lower: float = -math.inf,
          upper: float = math.inf) -> str:
    """``mean [episodes' interval] [seeds' interval]``, both cut to ``[lower, upper]``."""
    ep = pooled_mean(rows, name, lower, upper)
    if ep is None:
        return "—"
    seeds = mean_ci([_num(r[f"{name}_mean"]) for r in rows], lower=lower, upper=upper)
    f = f"{{:.{digits}f}}"
    return (f"{f.format(ep['mean'])} [{f.format(ep['low'])}, {f.format(ep['high'])}] "
            f"[{f.format(seeds['low'])}, {f.format(seeds['high'])}]")


def _settings(rows: list[dict[str, Any]]) -> dict[tuple, dict[tuple, list[dict[str, Any]]]]:
    """Finished rows by evaluation (wind, ``Q``), then by (recipe, filter at deployment)."""
    settings: dict[tuple, dict[tuple, list[dict[str, Any]]]] = {}
    for r in rows:
        if r["status"] != "done":
            continue
        q = _num(r["eval_budget"])
        key = (r["eval_wind"], "drawn" if q is None else f"{q:g}")
        settings.setdefault(key, {}).setdefault((recipe(r), r["eval_filter"]), []).append(r)
    return settings


def _landed(rs: Sequence[dict[str, Any]]) -> str:
    landed, n = _rate(rs, "landing_rate")
    w = wilson(landed, n)
    return f"{100 * w['value']:.0f}% [{100 * w['low']:.0f}, {100 * w['high']:.0f}]"


def _count(rs: Sequence[dict[str, Any]], name: str) -> str:
    count, n = _rate(rs, name)
    return f"{count}/{n}"


def _training(rs: Sequence[dict[str, Any]]) -> str:
    """Training hard violations and overspends per 100k steps, mean of the seeds; for runs trained under a filter
    also the counts of the episodes from the starts it certified, summed over the seeds (its guarantee's share)."""
    trained = [(_num(r["train_hard_per_100k"]), _num(r["train_over_per_100k"])) for r in rs
               if _num(r.get("train_hard_per_100k")) is not None]
    if not trained:
        return "—"
    text = f"{np.mean([h for h, _ in trained]):.0f}, {np.mean([o for _, o in trained]):.0f}"
    cert = [[_num(r.get(f"train_certified_{k}")) for k in ("episodes", "hard_violations", "over_budget")] for r in rs]
    if cert and all(None not in c for c in cert):
        n, hard, over = (int(sum(c[i] for c in cert)) for i in range(3))
        text += f"; from certified starts {hard}, {over} in {n} episodes"
    return text


def paired_lines(rows: list[dict[str, Any]]) -> list[str]:
    """A shorter table: one row per evaluation setting and recipe, each cell ``alone / + filter`` (the recipe
    deployed without and with the filter); effort and time to land deployed with the filter."""
    head = ["| wind, `Q` | recipe | seeds | landed: alone / + filter | hard | over `Q` | return [episodes] "
            "[seeds]: alone / + filter | control effort, + filter | time to land [s], + filter | interventions | "
            "training: hard, over `Q` per 100k steps |", "|---" * 11 + "|"]
    settings = _settings(rows)
    if not settings:
        return []
    lines = []
    for (wind, q), groups in settings.items():
        first = True
        for name in dict.fromkeys(k[0] for k in groups):
            off, on = groups.get((name, "off"), []), groups.get((name, "on"), [])
            both = [g for g in (off, on) if g]

            def pair(f):
                return " / ".join(f(g) if g else "—" for g in (off, on))

            inter = [_num(r["intervention_rate_mean"]) for r in on if _num(r.get("intervention_rate_mean")) is not None]
            lines.append(
                f"| {f'{wind}, {q}' if first else ''} | {name} | {len({r['seed'] for g in both for r in g})} | "
                f"{pair(_landed)} | {pair(lambda g: _count(g, 'hard_violation_rate'))} | "
                f"{pair(lambda g: _count(g, 'over_budget_rate'))} | "
                f"{pair(lambda g: _both(g, 'return', 1))} | "
                f"{_both(on, 'control_effort', 3, 0.0, 1.0) if on else '—'} | "
                f"{_both(on, 'time_to_land', 3, 0.0) if on else '—'} | "
                f"{f'{100 * np.mean(inter):.1f} %' if inter else '—'} | {_training(both[0])} |")
            first = False
    return head + lines


def method_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The markdown table (see the module docstring): per evaluation setting, one row per recipe and deployment
    (alone, + filter); finished rows only."""
    settings = _settings(rows)
    if not settings:
        return []
    head = ["| wind, `Q` | recipe | deployed | seeds | landed | hard | over `Q` | return [episodes] [seeds] | "
            "control effort [episodes] [seeds] | time to land [s] [episodes] [seeds] | interventions | training: "
            "hard, over `Q` per 100k steps |", "|---" * 12 + "|"]
    lines = []
    for (wind, q), groups in settings.items():
        first = True
        for (name, filt), rs in groups.items():
            inter = [_num(r["intervention_rate_mean"]) for r in rs if _num(r.get("intervention_rate_mean")) is not None]
            lines.append(
                f"| {f'{wind}, {q}' if first else ''} | {name} | {'+ filter' if filt == 'on' else 'alone'} | "
                f"{len({r['seed'] for r in rs})} | {_landed(rs)} | {_count(rs, 'hard_violation_rate')} | "
                f"{_count(rs, 'over_budget_rate')} | {_both(rs, 'return', 1)} | "
                f"{_both(rs, 'control_effort', 3, 0.0, 1.0)} | {_both(rs, 'time_to_land', 3, 0.0)} | "
                f"{f'{100 * np.mean(inter):.1f} %' if inter else '—'} | {_training(rs)} |")
            first = False
    return head + lines


def plot_deployed(rows: list[dict[str, Any]], out: str | Path) -> Path | None:
    """The comparison at a glance: one panel per evaluation ``Q`` (the winds pooled), deployed alone (open
    markers) and with the filter (filled); one point per run, its hard violations plus overspends in the episodes
    at that ``Q`` (x) against their mean return (y); a colour per recipe, a circle for one policy for every budget
    and a triangle for a policy trained at that ``Q``. ``None`` without finished rows."""
    from .report_plots import _plt, _save

    done = [r for r in rows if r["status"] == "done" and _num(r["eval_budget"]) is not None]
    if not done:
        return None
    qs = sorted({_num(r["eval_budget"]) for r in done})
    names = list(dict.fromkeys(recipe(r).split(", ")[0] for r in done))
    plt = _plt()
    fig, axs = plt.subplots(1, len(qs) + 1, figsize=(4.2 * len(qs) + 4.0, 4.4), squeeze=False,
                            gridspec_kw={"width_ratios": [1.0] * len(qs) + [0.95]})
    legend_ax = axs[0, -1]
    axs = axs[:, :-1]
    seen: set[tuple] = set()
    for ax, q in zip(axs[0], qs):
        runs: dict[tuple, list[dict[str, Any]]] = {}
        for r in done:
            if _num(r["eval_budget"]) == q:
                runs.setdefault((r["run_id"], r["eval_filter"]), []).append(r)
        for (_, filt), rs in runs.items():
            name = recipe(rs[0]).split(", ")[0]
            own = str(rs[0]["budget"]) != "default"
            x = sum(int(r["hard_violation_rate_count"]) + int(r["over_budget_rate_count"]) for r in rs)
            y = pooled_mean(rs, "return")
            if y is None:
                continue
            colour = f"C{names.index(name) % 10}"
            key = (name, own, filt)
            label = f"{name}, {'trained at this Q' if own else 'Q drawn'}, {'+ filter' if filt == 'on' else 'alone'}"
            ax.scatter(x, y["mean"], marker="^" if own else "o", s=42, edgecolors=colour,
                       facecolors=colour if filt == "on" else "none", label=None if key in seen else label)
            seen.add(key)
        ax.set_title(f"Q = {q:g} s (adversarial and random wind pooled)", fontsize=8)
        ax.set_xlabel("deployed: hard violations + overspends (episodes at this Q)", fontsize=8)
    axs[0, 0].set_ylabel("deployed mean return", fontsize=8)
    lows, highs = zip(*(ax.get_ylim() for ax in axs[0]))
    for ax in axs[0]:
        ax.set_ylim(min(lows), max(highs))
        ax.tick_params(labelsize=7)
    handles, labels = [], []
    for ax in axs[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.append(h)
            labels.append(lab)
    legend_ax.axis("off")
    legend_ax.legend(handles, labels, fontsize=6.5, loc="center left", frameon=False)
    fig.suptitle("deployed from certified starts: violations against return, one point per seed and recipe "
                 "(filled: under the filter)", fontsize=9)
    return _save(fig, out)


__all__ = ["BASELINES", "method_lines", "paired_lines", "plot_deployed", "pooled_mean", "recipe"]
