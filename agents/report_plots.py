"""The evaluation report's plots (``softreach evaluate --plots DIR``): trajectories (Fig. 1 style), budget
curves (Fig. 5/9 style), the budget histogram, filter interventions and learning curves. matplotlib is imported
only when a plot is drawn."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .report_text import _title, task_words


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


def _wrapped_title(text: str, width_in: float, fontsize: float = 8) -> str:
    """``text`` broken into lines that fit a figure ``width_in`` inches wide at ``fontsize`` points (a character
    is about 0.55 em wide), instead of running off its edge."""
    import textwrap

    return "\n".join(textwrap.wrap(text, max(20, int(width_in * 72 / (0.55 * fontsize)))))


def _outcome_handles(result) -> list:
    """Legend entries of the outcome colours, in the words of the model's task, and of the start marker."""
    from matplotlib.lines import Line2D

    words = task_words(result)
    names = {"landed": words.reached, "hard_violation": "hard violation (left C1)", "timeout": "timeout"}
    handles = [Line2D([], [], color=c, label=names[k]) for k, c in OUTCOME_COLOURS.items()]
    handles.append(Line2D([], [], color="0.5", marker="o", mec="k", ls="", ms=4, label="start"))
    if result.config.get("filtered"):
        handles.append(Line2D([], [], color="k", marker=".", ls="", label="filter acted"))
    return handles


def _outcome(tr) -> str:
    return "landed" if tr.landed else ("hard_violation" if tr.hard_violation else "timeout")


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
    handles = _outcome_handles(result)
    if n == 2:
        fig, ax = plt.subplots(figsize=(7.5, 6))
        if table is not None:
            from softreach.reach.cli.plotting import budget_colour, contour_level, shade_set

            axes = table.state_axes("W_eps")
            shade_set(ax, model, axes, model.hard_constraint, 0.0, colors=[(1.0, 0.85, 0.85)])
            shade_set(ax, model, axes, model.soft_constraint, 0.0, colors=[(0.95, 0.9, 0.78)])
            X, Y, g = shade_set(ax, model, axes, model.target, 0.0, colors=[(0.6, 0.6, 0.6)])
            handles += [Line2D([], [], color=(1.0, 0.85, 0.85), lw=8, label="hard C1"),
                        Line2D([], [], color=(0.95, 0.9, 0.78), lw=8, label="soft C2"),
                        Line2D([], [], color=(0.6, 0.6, 0.6), lw=8, label=model.words.target)]
            q = result.config.get("budget")
            budgets = [q] if q is not None else list(model.paper_budgets)
            for i, b in enumerate(budgets):
                level = contour_level(table.set_level(0.0, float(b)))
                if level.min() <= 0:
                    ax.contour(X, Y, level, levels=[0.0], colors=[budget_colour(i)], linewidths=2)
                    handles.append(Line2D([], [], color=budget_colour(i), lw=2, label=f"RA~ Q={b:g} (t=0)"))
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
        ax.set_title(_wrapped_title(_title(result), 7.5), fontsize=8)
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
                if j == 0:
                    handles.append(Line2D([], [], color="r", lw=0.8, ls="--", label="bounds of hard C1"))
            ax.set_xlabel(f"{names[i]} [{model.state_units[i]}]")
            ax.set_ylabel(f"{names[alt]} [{model.state_units[alt]}]")
        axs[0, 0].legend(handles=handles, fontsize=7)
        fig.suptitle(_wrapped_title(_title(result), 5 * (n - 1)), fontsize=8)
    return _save(fig, out)


def plot_budget_curves(result, out: str | Path, max_episodes: int = 60) -> Path:
    """Fig. 5/9 style: the remaining budget ``z(t)`` along each episode, coloured by outcome."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.axhline(0.0, color="0.6", lw=0.8, zorder=0)
    for tr in result.traces[:max_episodes]:
        ax.plot(tr.t, tr.z, color=OUTCOME_COLOURS[_outcome(tr)], lw=1, alpha=0.7)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("remaining budget z [s]")
    ax.legend(handles=_outcome_handles(result)[:3], fontsize=7)
    ax.set_title(_wrapped_title("budget depletion: " + _title(result), 7), fontsize=8)
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
    fig.suptitle(_wrapped_title(_title(result), 10), fontsize=8)
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
    ax.set_title(_wrapped_title("filter interventions: " + _title(result), 7), fontsize=8)
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
    iv = run_dir / "eval" / "interventions.npz"
    if iv.is_file():
        d = np.load(iv)
        data["interventions"] = {"timesteps": d["timesteps"], "rate": d["intervention_rate"]}
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
    """Return and success (landing) rate over training: periodic evaluations (mean and spread) and a running mean of the
    training episodes; where the evaluations ran under the safety filter, the share of steps it acted. ``None``
    if the run left no curves."""
    data = learning_data(run_dir)
    if not data:
        return None
    plt = _plt()
    panels = 3 if "interventions" in data else 2
    fig, axs = plt.subplots(1, panels, figsize=(5.5 * panels, 4))
    if "interventions" in data:
        iv = data["interventions"]
        axs[2].plot(iv["timesteps"], iv["rate"], "o-", color="tab:purple", label="evaluation (deployed, filtered)")
        axs[2].set_xlabel("environment steps")
        axs[2].set_ylabel("share of steps the filter acted")
        axs[2].set_ylim(-0.02, 1.02)
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
        axs[0].fill_between(ev["timesteps"], m - s, m + s, color="tab:red", alpha=0.2,
                            label="evaluation: mean ± 1 std over its episodes")
        if ev["successes"] is not None and np.size(ev["successes"]):
            axs[1].plot(ev["timesteps"], ev["successes"].mean(axis=1), "o-", color="tab:red", label="evaluation")
    axs[0].set_xlabel("environment steps")
    axs[0].set_ylabel("episode return")
    axs[1].set_xlabel("environment steps")
    axs[1].set_ylabel("share of episodes that reached the target")
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


__all__ = ["OUTCOME_COLOURS", "learning_data", "plot_budget_curves", "plot_budget_histogram", "plot_interventions",
           "plot_learning_curves", "plot_trajectories", "write_plots"]
