"""Figures for models with three states (the glider, paper Fig. 6-9): projected sets, trajectories, budgets.

A reader compares these with the paper's Fig. 6-8 (the verified safe regions for ``Q in {0, 5, 10}`` with the
target, hard and soft constraint sets) and Fig. 9 (the residual budget along one trajectory from each set).

The sets live in three dimensions ``(x0, x1, x2)``; a panel shows the first two (altitude ``h`` on the vertical
axis, airspeed ``V`` on the horizontal one for the glider) and either

* the **projection** over the third (``gamma``): a node ``(h, V)`` is in the projected set when some grid value
  of ``gamma`` puts it in the set (:func:`project_level`), or
* **slices** at chosen values of the third coordinate, drawn as outlines over the projection
  (``slices=(...)`` in the state's units, radians for the glider).

Every region is the zero sublevel set of a function on the table's nodes: the sets' level functions
(:meth:`softreach.reach.tables.query.Table.set_level`) and the model's implicit functions, projected by their minimum
over the third state. Outlines are those functions' zero contours, interpolated between nodes as the table is.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Sequence

import numpy as np

from .plotting import budget_colour

#: the paper's colours for Q = 0, 5, 10 (Fig. 6-9), then matplotlib's cycle
PAPER_COLOURS = [(0.4, 0.8, 1.0), (0.0, 0.5, 0.0), (0.4, 0.0, 0.6)]
HARD_COLOUR = (1.0, 0.8, 0.8)
SOFT_COLOUR = (1.0, 0.87, 0.68)
TARGET_COLOUR = (0.55, 0.55, 0.55)
SLICE_STYLES = [":", "-.", (0, (5, 1)), (0, (1, 1)), (0, (3, 1, 1, 1))]


def highest_node(table, mask: np.ndarray, axis: int = 0) -> float | None:
    """The largest grid coordinate along ``axis`` (altitude for the glider) of a node in ``mask``; ``None`` if empty.

    For the glider, the highest altitude from which a landing is verified.
    """
    mask = np.asarray(mask, bool)
    if not mask.any():
        return None
    others = tuple(i for i in range(mask.ndim) if i != axis)
    idx = np.nonzero(mask.any(axis=others))[0].max()
    return float(table.state_axes("V" if "V" in table.fields else "W_eps")[axis][idx])


def pick_starts(table, budgets: Sequence[float], t: float = 0.0, depth: float | None = None,
                panel_axes: tuple[int, int] | None = None) -> list[tuple[tuple[float, ...], float]]:
    """One representative start per budget, as in the paper's Fig. 6-8: :func:`softreach.reach.tables.starts.paper_starts`
    (a node of ``RA~_Q`` outside the projection of the next smaller set onto the panel, among the deepest of
    ``W_eps``, the highest such), the starts ``softreach evaluate --starts paper`` runs from, as tuples.

    :return: ``[(x, Q), ...]``, one entry per budget whose set is not empty
    """
    from ..tables.starts import START_DEPTH, paper_starts

    picks = paper_starts(table, budgets, t, START_DEPTH if depth is None else depth, panel_axes)
    return [(tuple(float(v) for v in x), q) for x, q in picks]


def project_level(level: np.ndarray, axis: int = 2) -> np.ndarray:
    """The projection of a level function along ``axis``: its minimum there, whose zero sublevel set is the
    projection of the set: a node is in it when some node along ``axis`` is in the set."""
    return np.min(np.asarray(level, float), axis=axis)


def _fill(ax, X, Y, level, colour, alpha=1.0, zorder=1):
    """Fill the zero sublevel set of a level function over the nodes."""
    from .plotting import contour_level

    v = contour_level(level)
    if v.min() > 0:
        return
    ax.contourf(X, Y, v, levels=[min(v.min(), 0.0) - 1.0, 0.0], colors=[colour], alpha=alpha, zorder=zorder)


def _outline(ax, X, Y, level, **kw):
    """Draw the zero contour of a level function over the nodes."""
    from .plotting import contour_level

    v = contour_level(level)
    if v.min() > 0 or v.max() <= 0:
        return
    ax.contour(X, Y, v, levels=[0.0], **kw)


def plot_sets_nd(table, budgets: Sequence[float], out: str | Path, t: float = 0.0,
                 starts: Sequence[tuple[float, ...]] = (), start_budgets: Sequence[float] = (), *,
                 dt: float = 0.01, slices: Sequence[float] = (), auto_starts: bool = True,
                 panel_axes: tuple[int, int] = (1, 0), dpi: int = 120) -> Path:
    """Paper Fig. 6-8 (one panel per budget) and Fig. 9 (budget depletion) for a three-state model.

    Each set panel shows, over the first two states (``panel_axes = (horizontal, vertical)``; airspeed and
    altitude for the glider): the hard constraint set ``C1`` (light red), the soft constraint set ``C2`` (light
    orange) and the target (grey), all projected over the third state; the verified safe region ``RA~_Q``
    projected over the third state (filled in the budget's colour), the classical ``RA`` projected (dashed
    black, where the table has ``V``), and, for each value in ``slices``, the outline of ``RA~_Q`` at that value
    of the third state.

    Trajectories: from ``starts`` with budgets ``start_budgets`` (default 0), or, when no start is given and
    ``auto_starts`` is set, one per budget from :func:`pick_starts`. Each runs the table's W-derived control
    against the table's worst-case disturbance (:func:`softreach.reach.sim.simulate.rollout`, control period
    ``dt``), is drawn in the panel of the smallest budget at least its own, and its remaining budget ``z(t)``
    goes into the last panel (Fig. 9), labelled with the budget used and whether it landed without a hard
    violation.

    :param table: a solved table of a three-state model with ``W_eps`` (and optionally ``V``)
    :param budgets: the ``Q`` of the panels
    :param out: PNG path
    :param t: time of the sets (and start time of the trajectories)
    :return: the path written
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from ..sim.simulate import rollout, table_control, table_disturbance

    model = table.model
    n = model.state_dim
    if n != 3:
        raise ValueError(f"plot_sets_nd draws three-state models; {model.name} has {n} states")
    if not table.has_budget:
        raise ValueError(f"table {table.path} holds only the classical V; plot_sets_nd needs W_eps (solve without --classical)")
    budgets = [float(q) for q in budgets]
    if not budgets:
        raise ValueError("give at least one budget")
    ix, iy = panel_axes
    (iz,) = [i for i in range(3) if i not in (ix, iy)]
    grid = table.grid("W_eps")
    axes = [grid.axis(i) for i in range(n)]
    X, Y = np.meshgrid(axes[ix], axes[iy], indexing="ij")

    def proj(level):  # (n0, n1, n2) -> (len(axes[ix]), len(axes[iy]))
        p = project_level(level, axis=iz)
        kept = [i for i in range(3) if i != iz]
        return p if kept == [ix, iy] else p.T

    full = np.meshgrid(*axes, indexing="ij")
    c1 = np.asarray(model.hard_constraint(t, full), float)
    hard = proj(c1)
    soft = proj(np.maximum(np.asarray(model.soft_constraint(t, full), float), c1))
    target = proj(np.maximum(np.asarray(model.target(t, full), float), c1))
    classical = proj(table.set_level(t)) if "V" in table.fields else None

    runs: list[tuple[np.ndarray, float]] = []
    if len(starts):
        qs = list(start_budgets) or [0.0] * len(starts)
        if len(qs) != len(starts):
            raise ValueError(f"{len(starts)} starts but {len(qs)} start budgets")
        runs = [(np.asarray(s, float), float(q)) for s, q in zip(starts, qs)]
    elif auto_starts:
        runs = [(np.asarray(s, float), q) for s, q in pick_starts(table, budgets, t, panel_axes=panel_axes)]
    ro = None
    if runs:
        x0 = np.stack([r[0] for r in runs])
        q0 = np.array([r[1] for r in runs])
        ro = rollout(model, x0, q0, table_control(table), table_disturbance(table), t0=t, dt=dt, eps=table.eps)

    n_panels = len(budgets) + (1 if ro is not None else 0)
    fig, axs = plt.subplots(1, n_panels, figsize=(4.3 * n_panels, 4.6), squeeze=False)
    names, units = model.state_names, model.state_units
    label_x, label_y = f"{names[ix]} [{units[ix]}]", f"{names[iy]} [{units[iy]}]"
    for k, q in enumerate(budgets):
        ax = axs[0, k]
        _fill(ax, X, Y, hard, HARD_COLOUR, zorder=0)
        _fill(ax, X, Y, soft, SOFT_COLOUR, zorder=0)
        level = table.set_level(t, q)
        _fill(ax, X, Y, proj(level), budget_colour(k, PAPER_COLOURS), alpha=0.55, zorder=2)
        _outline(ax, X, Y, proj(level), colors=[budget_colour(k, PAPER_COLOURS)], linewidths=1.5, zorder=3)
        _fill(ax, X, Y, target, TARGET_COLOUR, zorder=4)
        if classical is not None:
            _outline(ax, X, Y, classical, colors="k", linestyles="--", linewidths=1.0, zorder=5)
        for j, s in enumerate(slices):
            kz = int(np.argmin(np.abs(axes[iz] - s)))
            sl = np.take(level, kz, axis=iz)
            sl = sl if [i for i in range(3) if i != iz] == [ix, iy] else sl.T
            _outline(ax, X, Y, sl, colors="k", linestyles=[SLICE_STYLES[j % len(SLICE_STYLES)]], linewidths=1.0, zorder=5)
        top = highest_node(table, level <= 0, axis=iy)
        ax.set_title(f"Q = {q:g} s: highest {names[iy]} in the set {top:g} {units[iy]}" if top is not None
                     else f"Q = {q:g} s: empty on this grid", fontsize=10)
        ax.set_xlabel(label_x)
        if k == 0:
            ax.set_ylabel(label_y)
        ax.set_xlim(axes[ix][0], axes[ix][-1])
        ax.set_ylim(axes[iy][0], axes[iy][-1])
    handles = [Patch(color=HARD_COLOUR, label="hard constraint C1"), Patch(color=SOFT_COLOUR, label="soft constraint C2"),
               Patch(color=TARGET_COLOUR, label=model.words.target),
               Patch(color=(0.6, 0.6, 0.6), alpha=0.55, label=f"verified safe region (over {names[iz]})")]
    if classical is not None:
        handles.append(Line2D([], [], color="k", ls="--", lw=1.0, label="classical RA (hard C1 and C2)"))
    for j, s in enumerate(slices):
        shown = math.degrees(s) if units[iz] == "rad" else s
        unit = "deg" if units[iz] == "rad" else units[iz]
        handles.append(Line2D([], [], color="k", ls=SLICE_STYLES[j % len(SLICE_STYLES)], lw=1.0,
                              label=f"slice {names[iz]} = {shown:.3g} {unit}"))
    axs[0, 0].legend(handles=handles, fontsize=7, loc="upper left", framealpha=0.85)

    if ro is not None:
        bax = axs[0, -1]
        for j, (x0j, qj) in enumerate(runs):
            k = next((i for i, q in enumerate(budgets) if q >= qj - 1e-12), 0)
            c = budget_colour(k, PAPER_COLOURS)
            steps = int(ro.steps[j]) + 1
            path = ro.x[:steps, j]
            ax = axs[0, k]
            ax.plot(path[:, ix], path[:, iy], color="k", lw=2.6, zorder=6)
            ax.plot(path[:, ix], path[:, iy], color=c, lw=1.6, zorder=7)
            ax.plot(x0j[ix], x0j[iy], "o", color=c, mec="k", ms=7, zorder=8)
            status = (model.words.reached if ro.landed[j] else f"NOT {model.words.reached}") + (
                ", HARD VIOLATION" if ro.hard_violation[j] else "")
            zz = ro.z[:steps, j]
            bax.plot(ro.t[:steps], zz, color=c, lw=2,
                     label=f"Q={qj:g}: used {ro.budget_used[j]:.2f} s, {status} at t={ro.t[steps - 1]:.2f} s")
            bax.plot(ro.t[0], zz[0], "o", color=c, mec="k")
        bax.axhline(0, color="k", lw=0.8)
        bax.set_xlabel("t [s]")
        bax.set_ylabel("remaining budget z [s]")
        bax.set_title("budget depletion, worst-case disturbance", fontsize=10)
        bax.legend(fontsize=7, loc="upper right")
        bax.set_ylim(-0.5, max(1.0, max(q for _, q in runs)) * 1.25)
    g = table.grid("W_eps")
    fig.suptitle(f"{model.name}: soft-constrained reach-avoid sets at t = {t:g} s, projected over {names[iz]} "
                 f"(grid {' x '.join(map(str, g.shape))}, eps = {table.eps:g})", fontsize=11)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
