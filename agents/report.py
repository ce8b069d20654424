"""The evaluation report: its JSON document (schema below, checked by :func:`validate_evaluation`) and plots.

JSON (``softreach evaluate --json PATH``), schema ``softreach.evaluation/1``::

    {
      "schema": "softreach.evaluation/1",
      "created": "2025-01-01T12:00:00",            # local time, ISO 8601
      "config": {...},                             # the evaluation's settings (EvalSpec fields and more)
      "aggregates": {...},                         # see AGGREGATE_FIELDS
      "episodes": [{...}, ...]                     # one row per episode, see EPISODE_FIELDS
    }

A rate is ``{"value", "low", "high", "count", "n"}`` (Wilson 95 % interval); a mean is
``{"mean", "low", "high", "std", "min", "max", "n"}`` (Student-t 95 % interval). ``null`` where there is no
data (e.g. the intervention rate without a filter, the sink rate when nothing landed).

Plots (``--plots DIR``): ``trajectories.png`` (Fig. 1 style: the sets and the closed-loop paths, filter
interventions marked), ``budget.png`` (Fig. 5/9 style: remaining budget ``z(t)``), ``budget_hist.png``
(budget used, against ``Q``), ``interventions.png`` (how often the filter acts along the episode) and, for a
trained policy, ``learning_curves.png`` (periodic evaluations and training episodes).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

EVAL_SCHEMA = "softreach.evaluation/1"

RATE = "rate"
MEAN = "mean"
#: aggregate name -> (kind, meaning); kind "rate" / "mean" as in the module docstring, "rate?"/"mean?" may be null
AGGREGATE_FIELDS: dict[str, tuple[str, str]] = {
    "episodes": ("int", "number of episodes"),
    "landing_rate": (RATE, "episodes that reached the target inside C2"),
    "hard_violation_rate": (RATE, "episodes that left the hard constraint C1"),
    "over_budget_rate": (RATE, "episodes that used more than Q + budget_tol of budget"),
    "budget_used": (MEAN, "budget used Q - z_final [s]; also p50, p90 and excess_max = max(used - Q)"),
    "time_outside_c2": (MEAN, "control periods that ended outside C2, times their length [s]"),
    "touchdown_sink_rate": (MEAN, "downward speed at touchdown [m/s], landed episodes only"),
    "control_effort": (MEAN, "mean squared normalised applied action over the horizon (1 = full deflection throughout)"),
    "return": (MEAN, "sum of the environment's rewards (unscaled)"),
    "intervention_rate": (MEAN + "?", "per episode: steps in which the filter changed the action / steps; null without a filter"),
    "intervened_episodes": (RATE + "?", "episodes in which the filter acted at least once; null without a filter"),
    "outcomes": ("dict", "counts of 'landed', 'hard_violation', 'timeout'"),
}
#: per-episode field -> (type, meaning)
EPISODE_FIELDS: dict[str, tuple[str, str]] = {
    "episode": ("int", "index"),
    "seed": ("int", "reset seed of the episode (gusts)"),
    "start_state": ("list", "physical start state"),
    "budget": ("float", "budget Q [s]"),
    "start_value": ("float?", "W_eps(0, x0, max(Q, r)) of the table; null without a table or outside it"),
    "start_inside": ("bool?", "x0 in RA~_Q (the table's set); null without a table"),
    "landed": ("bool", "reached the target inside C2"),
    "hard_violation": ("bool", "left C1"),
    "over_budget": ("bool", "budget_used > Q + budget_tol"),
    "budget_used": ("float", "Q - z at the end [s]"),
    "budget_left": ("float", "z at the end [s] (negative once exceeded)"),
    "time_outside_c2": ("float", "control periods ending outside C2 times their length [s]"),
    "touchdown_sink_rate": ("float?", "downward speed at touchdown [m/s]; null if not landed or the model has none"),
    "control_effort": ("float", "mean squared normalised applied action over the horizon"),
    "interventions": ("int?", "steps in which the filter changed the action; null without a filter"),
    "intervention_rate": ("float?", "interventions / steps; null without a filter"),
    "min_value": ("float?", "smallest W~ the filter saw; null without a filter"),
    "steps": ("int", "control periods"),
    "duration": ("float", "simulated time [s]"),
    "return": ("float", "sum of rewards"),
    "outcome": ("str", "'landed', 'hard_violation' or 'timeout'"),
    "final_state": ("list", "physical state at the end"),
}
CONFIG_FIELDS = ("model", "policy", "filter", "rule", "budget", "wind", "table", "episodes", "starts", "seed",
                 "filtered", "budget_tol")


def _json_default(o: Any):
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _finite(o: Any) -> Any:
    """Replace non-finite floats by ``None`` (JSON has no inf/NaN)."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, (float, np.floating)) and not math.isfinite(float(o)):
        return None
    return o


def evaluation_document(result) -> dict[str, Any]:
    """The JSON document of an :class:`~softreach.agents.evaluate.EvaluationResult`."""
    doc = {"schema": EVAL_SCHEMA, "created": _dt.datetime.now().isoformat(timespec="seconds"),
           "config": result.config, "aggregates": result.aggregates, "episodes": result.episodes}
    return _finite(json.loads(json.dumps(doc, default=_json_default)))


def write_json(result, path: str | Path) -> Path:
    """Write :func:`evaluation_document` to ``path`` (checked against the schema first)."""
    doc = evaluation_document(result)
    validate_evaluation(doc)
    path = Path(path)
    if str(path.parent) and not path.parent.is_dir():
        raise ValueError(f"--json directory {path.parent} does not exist")
    path.write_text(json.dumps(doc, indent=1, allow_nan=False))
    return path


def _check_type(where: str, value: Any, kind: str) -> None:
    optional = kind.endswith("?")
    kind = kind.rstrip("?")
    if value is None:
        if optional:
            return
        raise ValueError(f"{where} must not be null")
    ok = {
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
        "bool": lambda v: isinstance(v, bool),
        "str": lambda v: isinstance(v, str),
        "list": lambda v: isinstance(v, list),
        "dict": lambda v: isinstance(v, dict),
    }
    if kind == RATE:
        if not isinstance(value, dict) or set(value) != {"value", "low", "high", "count", "n"}:
            raise ValueError(f"{where} must be a rate {{value, low, high, count, n}}, got {value!r}")
        if value["n"] and not (0 <= value["low"] <= value["value"] <= value["high"] <= 1):
            raise ValueError(f"{where}: need 0 <= low <= value <= high <= 1, got {value!r}")
        return
    if kind == MEAN:
        need = {"mean", "low", "high", "std", "min", "max", "n"}
        if not isinstance(value, dict) or not need <= set(value):
            raise ValueError(f"{where} must be a mean with {sorted(need)}, got {value!r}")
        if value["n"] and not (value["low"] <= value["mean"] + 1e-12 and value["mean"] <= value["high"] + 1e-12
                               and value["min"] <= value["max"]):
            raise ValueError(f"{where}: need low <= mean <= high and min <= max, got {value!r}")
        return
    if not ok[kind](value):
        raise ValueError(f"{where} must be of type {kind}, got {value!r}")


def validate_evaluation(doc: dict[str, Any]) -> None:
    """Check a document against schema ``softreach.evaluation/1``; ``ValueError`` naming the first problem."""
    if not isinstance(doc, dict):
        raise ValueError(f"an evaluation document is a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != EVAL_SCHEMA:
        raise ValueError(f"schema must be {EVAL_SCHEMA!r}, got {doc.get('schema')!r}")
    for key in ("created", "config", "aggregates", "episodes"):
        if key not in doc:
            raise ValueError(f"missing top-level field {key!r}")
    for key in CONFIG_FIELDS:
        if key not in doc["config"]:
            raise ValueError(f"config lacks {key!r}")
    agg = doc["aggregates"]
    for key, (kind, _) in AGGREGATE_FIELDS.items():
        if key not in agg:
            raise ValueError(f"aggregates lack {key!r}")
        _check_type(f"aggregates.{key}", agg[key], kind)
    if not isinstance(doc["episodes"], list) or len(doc["episodes"]) != agg["episodes"]:
        raise ValueError(f"episodes must be a list of {agg['episodes']} rows")
    for i, row in enumerate(doc["episodes"]):
        for key, (kind, _) in EPISODE_FIELDS.items():
            if key not in row:
                raise ValueError(f"episodes[{i}] lacks {key!r}")
            _check_type(f"episodes[{i}].{key}", row[key], kind)
    landed = sum(r["landed"] for r in doc["episodes"])
    if agg["landing_rate"]["count"] != landed:
        raise ValueError(f"aggregates.landing_rate.count {agg['landing_rate']['count']} != {landed} landed episodes")


# --------------------------------------------------------------------------------------------- plots

OUTCOME_COLOURS = {"landed": "tab:green", "hard_violation": "tab:red", "timeout": "tab:orange"}


def _save(fig, out: str | Path) -> Path:
    """Lay out, write and close a figure; every plot of the report ends here."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _outcome(tr) -> str:
    return "landed" if tr.landed else ("hard_violation" if tr.hard_violation else "timeout")


def _title(result) -> str:
    c = result.config
    if c.get("budget") is not None:
        q = f"Q={c['budget']:g}"
    else:
        q = "Q of each paper point" if c.get("starts") == "paper" else "Q drawn per episode"
    return (f"{c['model']}: {c['policy_name']}{' + filter (' + c['rule'] + ')' if c['filtered'] else ' (no filter)'}, "
            f"{c['wind']} wind, {c['starts']} starts, {q}")


def plot_trajectories(result, out: str | Path, table=None, max_episodes: int = 40) -> Path:
    """Fig. 1 style: ``C1``, ``C2``, the target, ``RA~_Q`` (2-D models, with a table) and the closed-loop paths
    coloured by outcome; steps where the filter acted are marked with dots."""
    plt = _plt()
    from matplotlib.lines import Line2D

    traces = result.traces[:max_episodes]
    names = result.config.get("state_names") or ["x0", "x1"]
    model = table.model if table is not None else None
    if model is None:
        from softreach.reach.models import get_model

        model = get_model(result.config["model"])
    n = model.state_dim
    handles = [Line2D([], [], color=c, label=k.replace("_", " ")) for k, c in OUTCOME_COLOURS.items()]
    handles.append(Line2D([], [], color="k", marker=".", ls="", label="filter acted"))
    if n == 2:
        fig, ax = plt.subplots(figsize=(7.5, 6))
        if table is not None:
            from softreach.reach.plotting import _colour, _set_region

            axes = table.state_axes("W_eps")
            _set_region(ax, model, axes, model.hard_constraint, 0.0, colors=[(1.0, 0.85, 0.85)])
            _set_region(ax, model, axes, model.soft_constraint, 0.0, colors=[(0.95, 0.9, 0.78)])
            X, Y, g = _set_region(ax, model, axes, model.target, 0.0, colors=[(0.6, 0.6, 0.6)])
            q = result.config.get("budget")
            budgets = [q] if q is not None else list(model.paper_budgets)
            for i, b in enumerate(budgets):
                m = table.set_mask(0.0, float(b)).astype(float)
                if m.max() > 0:
                    ax.contour(X, Y, m, levels=[0.5], colors=[_colour(i)], linewidths=2)
                    handles.append(Line2D([], [], color=_colour(i), lw=2, label=f"RA~ Q={b:g} (t=0)"))
        for tr in traces:
            c = OUTCOME_COLOURS[_outcome(tr)]
            ax.plot(tr.x[:, 0], tr.x[:, 1], color=c, lw=1, alpha=0.8)
            ax.plot(tr.x[0, 0], tr.x[0, 1], "o", color=c, mec="k", ms=4)
            act = np.nonzero(tr.filter_active)[0]
            if len(act):
                ax.plot(tr.x[act, 0], tr.x[act, 1], ".", color="k", ms=2)
        units = model.state_units
        ax.set_xlabel(f"{names[0]} [{units[0]}]")
        ax.set_ylabel(f"{names[1]} [{units[1]}]")
        ax.legend(handles=handles, fontsize=7, loc="upper right")
        ax.set_title(_title(result), fontsize=8)
    else:
        fig, axs = plt.subplots(1, n - 1, figsize=(5 * (n - 1), 5), squeeze=False)
        alt = 0
        others = [i for i in range(n) if i != alt]
        box = model.hard_box
        for j, i in enumerate(others):
            ax = axs[0, j]
            for tr in traces:
                c = OUTCOME_COLOURS[_outcome(tr)]
                ax.plot(tr.x[:, i], tr.x[:, alt], color=c, lw=1, alpha=0.8)
                ax.plot(tr.x[0, i], tr.x[0, alt], "o", color=c, mec="k", ms=4)
                act = np.nonzero(tr.filter_active)[0]
                if len(act):
                    ax.plot(tr.x[act, i], tr.x[act, alt], ".", color="k", ms=2)
            if box is not None:
                for v in (box[0][i], box[1][i]):
                    ax.axvline(v, color="r", lw=0.8, ls="--")
            ax.set_xlabel(f"{names[i]} [{model.state_units[i]}]")
            ax.set_ylabel(f"{names[alt]} [{model.state_units[alt]}]")
        axs[0, 0].legend(handles=handles, fontsize=7)
        fig.suptitle(_title(result), fontsize=8)
    return _save(fig, out)


def plot_budget_curves(result, out: str | Path, max_episodes: int = 60) -> Path:
    """Fig. 5/9 style: the remaining budget ``z(t)`` along each episode, coloured by outcome."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for tr in result.traces[:max_episodes]:
        ax.plot(tr.t, tr.z, color=OUTCOME_COLOURS[_outcome(tr)], lw=1, alpha=0.7)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("remaining budget z [s]")
    ax.set_title("budget depletion: " + _title(result), fontsize=8)
    return _save(fig, out)


def plot_budget_histogram(result, out: str | Path) -> Path:
    """The distribution of the budget used (and of ``used - Q``), with ``Q`` marked."""
    plt = _plt()
    used = np.array([r["budget_used"] for r in result.episodes], dtype=float)
    qs = np.array([r["budget"] for r in result.episodes], dtype=float)
    fig, axs = plt.subplots(1, 2, figsize=(10, 4))
    axs[0].hist(used, bins=30, color="tab:blue", alpha=0.8)
    q = result.config.get("budget")
    if q is not None:
        axs[0].axvline(q, color="k", ls="--", label=f"Q={q:g}")
        axs[0].legend(fontsize=8)
    axs[0].set_xlabel("budget used [s]")
    axs[0].set_ylabel("episodes")
    axs[1].hist(used - qs, bins=30, color="tab:purple", alpha=0.8)
    axs[1].axvline(0.0, color="k", ls="--", label="used = Q")
    axs[1].axvline(result.config.get("budget_tol", 0.0), color="r", ls=":", label="Q + tolerance")
    axs[1].set_xlabel("budget used - Q [s]")
    axs[1].legend(fontsize=8)
    fig.suptitle(_title(result), fontsize=8)
    return _save(fig, out)


def plot_interventions(result, out: str | Path) -> Path:
    """How often the filter acts: the fraction of running episodes in which it acted, over time."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    traces = result.traces
    if traces:
        steps = max(len(tr.filter_active) for tr in traces)
        active = np.zeros(steps)
        running = np.zeros(steps)
        for tr in traces:
            k = len(tr.filter_active)
            active[:k] += tr.filter_active
            running[:k] += 1
        dt = result.config.get("dt", 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            ax.plot(np.arange(steps) * dt, active / running, color="k")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("fraction of episodes filtered")
    ax.set_title("filter interventions: " + _title(result), fontsize=8)
    return _save(fig, out)


def learning_data(run_dir: str | Path) -> dict[str, Any]:
    """Learning-curve data of a training run: periodic evaluations and training episodes (empty if absent)."""
    run_dir = Path(run_dir)
    data: dict[str, Any] = {}
    ev = run_dir / "eval" / "evaluations.npz"
    if ev.is_file():
        d = np.load(ev)
        data["eval"] = {"timesteps": d["timesteps"], "returns": d["results"],
                        "successes": d["successes"] if "successes" in d.files else None}
    rows = []
    for f in sorted((run_dir / "monitor").glob("train-*.monitor.csv")):
        import csv

        with f.open() as fh:
            fh.readline()  # the Monitor's JSON header line
            for r in csv.DictReader(fh):
                rows.append((float(r["t"]), float(r["r"]), float(r["l"]), r.get("landed") == "True"))
    if rows:
        rows.sort()
        arr = np.array([(r[1], r[2], r[3]) for r in rows], dtype=float)
        data["train"] = {"returns": arr[:, 0], "lengths": arr[:, 1], "landed": arr[:, 2],
                         "timesteps": np.cumsum(arr[:, 1])}
    return data


def plot_learning_curves(run_dir: str | Path, out: str | Path) -> Path | None:
    """Return and landing rate over training: periodic evaluations (mean and spread) and a running mean of the
    training episodes. ``None`` if the run left no curves."""
    data = learning_data(run_dir)
    if not data:
        return None
    plt = _plt()
    fig, axs = plt.subplots(1, 2, figsize=(11, 4))
    if "train" in data:
        tr = data["train"]
        k = max(1, min(200, len(tr["returns"]) // 20))
        kern = np.ones(k) / k
        x = tr["timesteps"][k - 1:]
        axs[0].plot(x, np.convolve(tr["returns"], kern, mode="valid"), color="tab:blue", lw=1,
                    label=f"training episodes (mean of {k})")
        axs[1].plot(x, np.convolve(tr["landed"], kern, mode="valid"), color="tab:blue", lw=1,
                    label="training episodes")
    if "eval" in data:
        ev = data["eval"]
        m, s = ev["returns"].mean(axis=1), ev["returns"].std(axis=1)
        axs[0].plot(ev["timesteps"], m, "o-", color="tab:red", label="evaluation (deterministic)")
        axs[0].fill_between(ev["timesteps"], m - s, m + s, color="tab:red", alpha=0.2)
        if ev["successes"] is not None and np.size(ev["successes"]):
            axs[1].plot(ev["timesteps"], ev["successes"].mean(axis=1), "o-", color="tab:red", label="evaluation")
    axs[0].set_xlabel("environment steps")
    axs[0].set_ylabel("episode return")
    axs[1].set_xlabel("environment steps")
    axs[1].set_ylabel("landing rate")
    axs[1].set_ylim(-0.02, 1.02)
    for ax in axs:
        ax.legend(fontsize=8)
    fig.suptitle(f"learning curves: {Path(run_dir)}", fontsize=8)
    return _save(fig, out)


def write_plots(result, out_dir: str | Path, table=None, run_dir: str | Path | None = None,
                prefix: str = "") -> list[Path]:
    """All the plots of one evaluation into ``out_dir`` (created); returns the files written."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = [plot_trajectories(result, out_dir / f"{prefix}trajectories.png", table=table),
             plot_budget_curves(result, out_dir / f"{prefix}budget.png"),
             plot_budget_histogram(result, out_dir / f"{prefix}budget_hist.png")]
    if result.config.get("filtered"):
        files.append(plot_interventions(result, out_dir / f"{prefix}interventions.png"))
    if run_dir is not None:
        lc = plot_learning_curves(run_dir, out_dir / f"{prefix}learning_curves.png")
        if lc is not None:
            files.append(lc)
    return files


# --------------------------------------------------------------------------------------------- text

def _pct(rate: dict[str, Any] | None) -> str:
    if rate is None or rate.get("value") is None:
        return "—"
    return f"{100 * rate['value']:.0f}% [{100 * rate['low']:.0f}, {100 * rate['high']:.0f}]"


def _num(m: dict[str, Any] | None, key: str = "mean", fmt: str = "{:.3f}") -> str:
    if m is None or m.get(key) is None:
        return "—"
    return fmt.format(m[key])


def summary_lines(result) -> list[str]:
    """A few human-readable lines of an evaluation's aggregates."""
    a = result.aggregates
    lines = [_title(result), f"  episodes: {a['episodes']}  outcomes: {a['outcomes']}",
             f"  landing rate: {_pct(a['landing_rate'])}   hard violations: {_pct(a['hard_violation_rate'])}",
             f"  budget used: mean {_num(a['budget_used'])}  max {_num(a['budget_used'], 'max')}  "
             f"over Q (+{result.config['budget_tol']:g} s): {_pct(a['over_budget_rate'])}",
             f"  return: {_num(a['return'], fmt='{:.1f}')}  control effort: {_num(a['control_effort'])}  "
             f"touchdown sink rate: {_num(a['touchdown_sink_rate'])} m/s"]
    if a["intervention_rate"] is not None:
        lines.append(f"  interventions: {_num(a['intervention_rate'])} of steps (mean per episode), in "
                     f"{_pct(a['intervened_episodes'])} of episodes")
    if "by_start" in a:
        bs = a["by_start"]
        lines.append(f"  starts inside RA~_Q: {bs['inside']['episodes']} (landed {_pct(bs['inside']['landing_rate'])}, "
                     f"hard {_pct(bs['inside']['hard_violation_rate'])}); outside: {bs['outside']['episodes']} "
                     f"(landed {_pct(bs['outside']['landing_rate'])}, hard {_pct(bs['outside']['hard_violation_rate'])})")
    return lines


COMPARISON_HEADER = ("| policy | wind | Q | landing rate | hard violations | budget used: mean | max | over Q | "
                     "interventions |\n|---|---|---|---|---|---|---|---|---|")


def comparison_row(label: str, result) -> str:
    a = result.aggregates
    c = result.config
    q = "drawn" if c.get("budget") is None else f"{c['budget']:g}"
    inter = "—" if a["intervention_rate"] is None else f"{100 * a['intervention_rate']['mean']:.1f}%"
    hard = a["hard_violation_rate"]
    return (f"| {label} | {c['wind']} | {q} | {_pct(a['landing_rate'])} | {hard['count']}/{hard['n']} | "
            f"{_num(a['budget_used'])} | {_num(a['budget_used'], 'max')} | {a['over_budget_rate']['count']}/{a['episodes']} | "
            f"{inter} |")


def comparison_table(rows: Sequence[tuple[str, Any]]) -> str:
    """A markdown table of ``(label, EvaluationResult)`` pairs."""
    return "\n".join([COMPARISON_HEADER] + [comparison_row(label, r) for label, r in rows])


__all__ = ["AGGREGATE_FIELDS", "CONFIG_FIELDS", "EPISODE_FIELDS", "EVAL_SCHEMA", "comparison_table", "evaluation_document",
           "learning_data", "plot_budget_curves", "plot_budget_histogram", "plot_interventions",
           "plot_learning_curves", "plot_trajectories", "summary_lines", "validate_evaluation", "write_json",
           "write_plots"]
