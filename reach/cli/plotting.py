"""Figures in the style of the paper: sets (Fig. 1), worst-case trajectories and budget depletion (Fig. 5)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

#: the paper's colours for Q = 0, 0.06, 0.3, 0.6 (then matplotlib's cycle)
PAPER_COLOURS = [(0.4, 0.8, 1.0), (0.0, 0.0, 0.5), (0.0, 0.5, 0.0), (0.4, 0.0, 0.6)]


def budget_colour(i: int, palette: Sequence = PAPER_COLOURS):
    """The colour of the ``i``-th budget's set in a figure: ``palette[i]`` (the paper's colours by default), then
    matplotlib's colour cycle, so a figure of more budgets than the paper's still tells them apart."""
    if i < len(palette):
        return palette[i]
    import matplotlib.pyplot as plt

    return plt.rcParams["axes.prop_cycle"].by_key()["color"][i % 10]


def shade_set(ax, model, axes: Sequence[np.ndarray], fn, t: float, **kw) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fill where ``fn(t, [X, Y]) <= 0`` (one of ``model``'s set functions: ``hard_constraint``, ``soft_constraint``,
    ``target``) on the grid of the two state axes ``axes``; ``kw`` goes to ``contourf`` (e.g. ``colors``).

    :return: ``(X, Y, values)``, the node coordinates and the set function on them, for contours drawn over it
    """
    X, Y = np.meshgrid(axes[0], axes[1], indexing="ij")
    vals = np.asarray(fn(t, [X, Y]), dtype=float)
    ax.contourf(X, Y, vals, levels=[vals.min() - 1, 0], **kw)
    return X, Y, vals


def contour_level(level: np.ndarray) -> np.ndarray:
    """A set's level function (:meth:`~softreach.reach.tables.query.Table.set_level`) ready for ``contour``: values that
    are not finite (no budget suffices, off the table) become a positive value above every finite one."""
    level = np.asarray(level, dtype=float)
    finite = np.isfinite(level)
    high = (float(np.max(np.abs(level[finite]))) if finite.any() else 0.0) + 1.0
    return np.where(finite, level, high)


def representative_starts(table, budgets: Sequence[float], t: float = 0.0) -> list[tuple[tuple[float, ...], float]]:
    """The paper's representative initial conditions (Fig. 1): :func:`softreach.reach.tables.starts.paper_starts`, the
    starts ``softreach evaluate --starts paper`` runs from, as tuples."""
    from ..tables.starts import paper_starts

    return [(tuple(float(v) for v in x), q) for x, q in paper_starts(table, budgets, t)]


def plot_sets_2d(table, budgets: Sequence[float], out: str | Path, t: float = 0.0,
                 starts: Sequence[tuple[float, ...]] = (), start_budgets: Sequence[float] = (),
                 dt: float = 1e-3) -> Path:
    """Fig. 1 style: target, ``C1``, ``C2``, the classical set dashed, ``RA~_Q`` per budget, and optionally the
    W-derived worst-case trajectories from ``starts`` (with budgets ``start_budgets``) and their budget curves."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    from ..sim.simulate import rollout, table_control, table_disturbance

    model = table.model
    if model.state_dim != 2:
        raise ValueError(f"plot_sets_2d draws 2-D models; {model.name} has {model.state_dim} states")
    axes = table.state_axes("V")
    with_traj = len(starts) > 0
    fig, axs = plt.subplots(1, 2 if with_traj else 1, figsize=(11 if with_traj else 6.5, 5.5),
                            gridspec_kw={"width_ratios": [1.6, 1]} if with_traj else None, squeeze=False)
    ax = axs[0, 0]
    shade_set(ax, model, axes, model.hard_constraint, t, colors=[(1.0, 0.8, 0.8)])
    shade_set(ax, model, axes, model.soft_constraint, t, colors=[(0.93, 0.85, 0.7)])
    X, Y, g = shade_set(ax, model, axes, model.target, t, colors=[(0.6, 0.6, 0.6)])
    ax.contour(X, Y, g, levels=[0], colors="k", linewidths=1)
    handles = [Line2D([], [], color=(1.0, 0.8, 0.8), lw=8, label="hard C1 (allowed; outside is a crash)"),
               Line2D([], [], color=(0.93, 0.85, 0.7), lw=8, label="soft C2 (outside costs budget)"),
               Line2D([], [], color=(0.6, 0.6, 0.6), lw=8, label=model.words.target)]
    budgets = [float(q) for q in budgets]
    x0 = np.asarray(starts, dtype=float).reshape(len(starts), -1) if with_traj else np.zeros((0, 2))
    qs = np.asarray(list(start_budgets) or [0.0] * len(x0), dtype=float)
    for i, q in enumerate(budgets):
        ax.contour(X, Y, contour_level(table.set_level(t, q)), levels=[0.0], colors=[budget_colour(i)], linewidths=2,
                   zorder=2)
        no_path = with_traj and not np.any(qs == q)
        handles.append(Line2D([], [], color=budget_colour(i), lw=2,
                              label=f"RA~ Q={q:g}" + (" (no start given: no path)" if no_path else "")))
    if "V" in table.fields:
        # on top: RA and RA~_0 nearly coincide (Prop. 3), and the dashes must stay visible over the Q = 0 line
        ax.contour(X, Y, contour_level(table.set_level(t)), levels=[0.0], colors="k", linestyles=[(0, (4, 3))],
                   linewidths=1.2, zorder=3)
        handles.append(Line2D([], [], color="k", ls=(0, (4, 3)), lw=1.2, label="classical RA"))
    names, units = model.state_names, model.state_units
    ax.set_xlabel(f"{names[0]} [{units[0]}]")
    ax.set_ylabel(f"{names[1]} [{units[1]}]")
    ax.set_title(f"{model.name}: reach-avoid sets at t={t:g}")
    if with_traj:
        ro = rollout(model, x0, qs, table_control(table), table_disturbance(table), t0=t, dt=dt, eps=table.eps or 1e-3)
        bax = axs[0, 1]
        # the zero line below the curves: a run that spends nothing stays on it and must still be seen
        bax.axhline(0, color="0.6", lw=0.8, zorder=0)
        words = model.words
        for j in range(len(x0)):
            c = budget_colour(budgets.index(qs[j]) if qs[j] in budgets else j)
            n = ro.steps[j] + 1
            # a black underlay keeps a path visible where it runs along the outline drawn in its own colour
            ax.plot(ro.x[:n, j, 0], ro.x[:n, j, 1], color="k", lw=3.2, zorder=4)
            ax.plot(ro.x[:n, j, 0], ro.x[:n, j, 1], ls=(0, (2, 1)), color=c, lw=2.0, zorder=5)
            ax.plot(*x0[j], "o", color=c, mec="k", ms=7, zorder=6)
            outcome = words.reached if ro.landed[j] else f"NOT {words.reached}"
            bax.plot(ro.t[:n], ro.z[:n, j], color="k", lw=3.2, zorder=1)
            bax.plot(ro.t[:n], ro.z[:n, j], color=c, lw=2.0, zorder=2,
                     label=f"Q={qs[j]:g}: used {ro.budget_used[j]:.3f} s, {outcome}"
                     + (", HARD VIOLATION" if ro.hard_violation[j] else ""))
        handles.append(Line2D([], [], color="0.3", ls=(0, (2, 1)), lw=2.0, marker="o", mec="k",
                              label="start (dot) and W-derived path, worst-case wind"))
        top = max(float(np.max(qs)) if len(qs) else 0.0, 0.05)
        bax.set_ylim(-0.06 * top, 1.1 * top)
        bax.set_xlabel("t [s]")
        bax.set_ylabel("remaining budget z [s]")
        bax.set_title("budget depletion (worst-case disturbance)")
        bax.legend(fontsize=8)
    ax.legend(handles=handles, fontsize=8, loc="upper right")
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
