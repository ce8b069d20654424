"""Solve a model's classical ``V`` and soft ``W_eps`` into one table file, with progress and checkpoints."""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .. import backend as B
from .grid import Grid, budget_axis
from ..problem import Model, check_edges, classical_problem, soft_problem
from .budget_surface import budget_problem, solve_budget_surface
from .held import solve_held
from .solver import SolverSettings, solve
from ..tables.table import BackgroundWrites, TableWriter

DEFAULT_BUDGETS = (0.0, 0.06, 0.3, 0.6)


@dataclass
class SolveConfig:
    """What ``softreach solve`` computes.

    :param shape: state grid (one size per state)
    :param budget_points: nodes along the budget axis (``z = 0`` is one of them)
    :param eps: width of ``h_eps`` in units of the soft constraint
    :param budget_scale: ``kappa``; ``None`` takes the model's default
    :param settings: numerical settings
    :param snapshots: number of output times, evenly spaced over ``[0, T]`` (also the checkpoint interval)
    :param classical_only: solve only ``V``
    :param domain: grid box ``(lo, hi)`` over the state; ``None`` takes the model's
    """

    shape: tuple[int, ...]
    budget_points: int
    eps: float = 1e-3
    budget_scale: float | None = None
    settings: SolverSettings = field(default_factory=SolverSettings)
    snapshots: int = 21
    classical_only: bool = False
    domain: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: ``None``: the continuous-time game (the paper's). A period [s]: the sampled-data game, actions held for
    #: that long (:mod:`softreach.reach.numerics.held`); snapshots are then the sample times, ``snapshots`` is ignored
    control_period: float | None = None
    #: candidate held actions per control axis (sampled-data game only); ``None``: the model's ``held_levels``
    held_levels: int | None = None
    #: solve the budget surface ``Q_min`` on the state grid instead of ``W_eps`` on ``(x, z)``
    #: (:mod:`softreach.reach.numerics.budget_surface`); ``budget_points`` is then unused
    budget_surface: bool = False


def validate(model: Model, cfg: SolveConfig, out: str | os.PathLike | None) -> tuple[Grid, Grid | None]:
    """Check everything that can be checked before any work starts; return the state and augmented grids."""
    n = model.state_dim
    shape = tuple(cfg.shape)
    if len(shape) != n:
        raise ValueError(f"{model.name} has {n} states {model.state_names}; --grid needs {n} sizes, got {list(shape)}")
    for name, s in zip(model.state_names, shape):
        if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 5:
            raise ValueError(f"grid size for {name} must be an integer >= 5, got {s!r}")
    if not (isinstance(cfg.eps, (int, float)) and math.isfinite(cfg.eps) and cfg.eps > 0):
        raise ValueError(f"eps must be a finite number > 0, got {cfg.eps!r}")
    if cfg.budget_scale is not None and not (math.isfinite(cfg.budget_scale) and cfg.budget_scale > 0):
        raise ValueError(f"budget scale must be a finite number > 0, got {cfg.budget_scale!r}")
    if cfg.control_period is not None:
        sample_times(model.horizon, cfg.control_period)  # raises on a period that does not divide the horizon
    if isinstance(cfg.snapshots, bool) or not isinstance(cfg.snapshots, int) or cfg.snapshots < 2:
        raise ValueError(f"snapshots must be an integer >= 2, got {cfg.snapshots!r}")
    lo, hi = cfg.domain or model.domain
    for name, a, b in zip(model.state_names, lo, hi):
        if not (math.isfinite(a) and math.isfinite(b) and a < b):
            raise ValueError(f"domain along {name} must be finite with lo < hi, got [{a!r}, {b!r}]")
    if model.hard_box is not None:
        for name, a, b, ca, cb in zip(model.state_names, lo, hi, *model.hard_box):
            if a > ca or b < cb:
                raise ValueError(f"the grid domain along {name}, [{a}, {b}], does not contain the hard-constraint set's [{ca}, {cb}]")
    # a periodic axis (an angle) has no boundary: the grid wraps there, its domain is one period
    periodic = model.periodic_axes()
    state_grid = Grid(tuple(lo), tuple(hi), shape, periodic=periodic, names=tuple(model.state_names))
    if cfg.budget_surface and cfg.classical_only:
        raise ValueError("the budget surface is solved with V beside it: drop --classical")
    aug = None
    if not cfg.classical_only and not cfg.budget_surface:
        z_lo, z_hi, nz = budget_axis(model.horizon, cfg.budget_points)
        aug = Grid(tuple(lo) + (z_lo,), tuple(hi) + (z_hi,), shape + (nz,), periodic=periodic + (False,),
                   names=tuple(model.state_names) + ("z",))
    if out is not None:
        path = Path(out)
        parent = path.parent if str(path.parent) else Path(".")
        if path.is_dir():
            raise ValueError(f"output path {path} is a directory; give a file name such as {path / (model.name + '.srt')}")
        if not parent.is_dir():
            raise ValueError(f"output directory {parent} does not exist")
        if not os.access(parent, os.W_OK):
            raise PermissionError(f"output directory {parent} is not writable")
    return state_grid, aug


def hard_box_domain(model: Model, shape: Sequence[int], pad_cells: int = 3) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """A grid box that spends every node on the hard-constraint set ``C1`` and ``pad_cells`` cells around it.

    Outside ``C1`` no budget suffices (``Q_min = inf``, ``V, W_eps > 0``), so the default box's nodes there carry
    only the boundary condition; ``pad_cells`` keeps the constraint's zero crossing and a WENO5 stencil (three
    nodes each side) inside the grid. Periodic axes, and axes ``C1`` leaves unbounded, keep the model's box.

    :param shape: the state grid the box is for (the pad is in that grid's cells)
    :param pad_cells: cells beyond ``C1`` at each end
    """
    if model.hard_box is None:
        raise ValueError(f"{model.name} declares no hard_box: give the domain explicitly")
    if len(shape) != model.state_dim or any(int(n) <= 2 * pad_cells + 1 for n in shape):
        raise ValueError(f"a fitted domain needs {model.state_dim} grid sizes > {2 * pad_cells + 1}, got {list(shape)}")
    lo, hi = list(model.domain[0]), list(model.domain[1])
    for i, (per, n, a, b) in enumerate(zip(model.periodic_axes(), shape, *model.hard_box)):
        if per or not (math.isfinite(a) and math.isfinite(b)):
            continue
        dx = (b - a) / (int(n) - 1 - 2 * pad_cells)
        lo[i], hi[i] = a - pad_cells * dx, b + pad_cells * dx
    return tuple(lo), tuple(hi)


def sample_times(horizon: float, period: float) -> list[float]:
    """``[0, dt, 2 dt, ..., T]``: the sample times of a controller with period ``dt`` over the horizon ``T``."""
    if not (isinstance(period, (int, float)) and math.isfinite(period) and period > 0):
        raise ValueError(f"control period must be a finite number > 0, got {period!r}")
    n = round(horizon / period)
    if n < 1 or abs(n * period - horizon) > 1e-9 * max(1.0, horizon):
        raise ValueError(f"control period {period} must divide the horizon {horizon} into whole periods")
    return [float(k * period) for k in range(n)] + [float(horizon)]


def _progress(total: float, desc: str, enabled: bool):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="s", unit_scale=False, bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} model-s [{elapsed}<{remaining}]")


def solve_table(model: Model, cfg: SolveConfig, out: str | os.PathLike, *, resume: bool = True, progress: bool = True,
                budgets: Sequence[float] = DEFAULT_BUDGETS) -> dict[str, Any]:
    """Solve ``V`` (and ``W_eps``) for ``model`` and write the table to ``out``.

    Snapshots stream to ``out + '.partial'``; if that file exists from an interrupted run with the same settings the
    solve resumes from its last finished snapshot. Returns the summary that is also stored in the table header.
    """
    state_grid, aug = validate(model, cfg, out)
    kappa = cfg.budget_scale if cfg.budget_scale is not None else model.budget_scale
    held = cfg.control_period is not None
    if held:
        # a table of the sampled-data game is made for a filter: a model without what the filter needs (its cells
        # included), or whose enclosure a simulation refutes, is refused now, not after the solve
        from ..proof.enclosure_check import check_model_for_filter
        check_model_for_filter(model, cfg.control_period, "softreach solve --held", cells=True)
        times = sample_times(model.horizon, cfg.control_period)
        controls = [list(a) for a in model.held_candidates(cfg.held_levels)]
    else:
        times = [float(t) for t in np.linspace(0.0, model.horizon, cfg.snapshots)]
    game = {"control_period": float(cfg.control_period), "held_controls": controls} if held else {"control_period": None}
    fields: dict[str, dict[str, Any]] = {}
    problems = {}
    fields["V"] = {"grid": state_grid.to_dict(), "times": times, "problem": classical_problem(model).metadata(),
                   "settings": cfg.settings.to_dict(), **game}
    problems["V"] = (classical_problem(model), state_grid)
    if cfg.budget_surface:
        bp = budget_problem(model, cfg.eps)
        fields["Q_min"] = {"grid": state_grid.to_dict(), "times": times, "problem": bp.metadata(),
                           "settings": cfg.settings.to_dict(), **game}
        problems["Q_min"] = (bp, state_grid)
    if aug is not None:
        sp = soft_problem(model, cfg.eps, kappa)
        fields["W_eps"] = {"grid": aug.to_dict(), "times": times, "problem": sp.metadata(),
                           "settings": cfg.settings.to_dict(), **game}
        problems["W_eps"] = (sp, aug)
    header = {"model": model.metadata(), "fields": fields}
    writer = TableWriter(out, header, resume=resume)
    writes = BackgroundWrites()
    resumed = _announce_resume(writer, problems)
    walls: dict[str, float] = {}
    # the first torch.compile on a machine takes a minute or more at 0 %: say so when it starts
    notices = contextlib.ExitStack()
    if progress and cfg.settings.backend == "torch":
        notices.enter_context(compile_notice())
    try:
        for name, (problem, grid) in problems.items():
            k = writer.resume_point(name)
            if k == 0:
                walls[name] = float(writer.header["fields"][name].get("wall_s", 0.0))
                continue
            start = None if k is None else (k, writer.read_snapshot(name, k))
            # a resumed solve shows the whole horizon, with the finished part already done
            bar = _progress(times[-1] - times[0], f"{name} {'x'.join(map(str, grid.shape))}", progress)
            if bar is not None and k is not None:
                bar.update(times[-1] - times[k])
            spec = writer.header["fields"][name]
            before = float(spec.get("wall_s", 0.0))
            t0 = time.perf_counter()

            def store(kk, values, _n=name, _grid=grid):
                writer.write_snapshot(_n, kk, values)
                # the certificates only: Q_min >= 0 (its ghosts, extrapolated away from zero, only rise)
                if _n in ("V", "W_eps"):
                    check_edges(_n, values, _grid.periodic, _grid.names or model.state_names, model.state_dim)

            def sink(kk, tt, u, _spec=spec, _before=before, _t0=t0):
                values = _host_copy(u)
                writes.wait()  # the header changes only while no write is in flight
                _spec["wall_s"] = _before + time.perf_counter() - _t0
                writes.submit(store, kk, values)
            if held:
                solve_held(problem, grid, times, cfg.settings, np.asarray(controls), start=start, progress=bar,
                           sink=sink)
            else:
                # Q_min takes cap wherever its feasible set, solved first, says that no budget suffices
                if name == "Q_min":
                    # the table's own V (solved first) decides where Q_min may be 0 (Prop. 3)
                    solve_budget_surface(problem, grid, times, cfg.settings, start=start, progress=bar, sink=sink,
                                         classical=lambda kk: writer.read_snapshot("V", kk))
                else:
                    solve(problem, grid, times, cfg.settings, start=start, progress=bar, sink=sink)
            writes.wait()
            walls[name] = before + time.perf_counter() - t0
            if bar is not None:
                bar.close()
        writer.set(wall_time=walls)
        path = writer.finalize()
    finally:
        notices.close()
        try:
            writes.close()
        finally:
            writer.close()
    from ..tables.query import load_table

    table = load_table(path, verify_checksum=False)
    summary = summarize(table, budgets)
    summary["wall_time_s"] = walls
    summary["settings"] = cfg.settings.to_dict()
    summary["eps"] = cfg.eps if aug is not None or cfg.budget_surface else None
    summary["budget_scale"] = kappa if aug is not None else None
    summary["control_period"] = cfg.control_period
    summary["resumed"] = resumed
    return summary


def _host_copy(u: Any) -> np.ndarray:
    """A snapshot as float32 on the host that the solver will not overwrite while it is written: a device's copy, or
    a copy of a CPU array (which may be the stepper's own buffer)."""
    values = B.to_numpy(u)
    if getattr(u, "is_cuda", False):
        return np.ascontiguousarray(values, dtype="<f4")
    return np.array(values, dtype="<f4", copy=True, order="C")


def _announce_resume(writer: TableWriter, problems: dict[str, Any]) -> bool:
    """Say on stderr (progress bar or not) that the solve continues an interrupted one, and how far that got;
    return whether it does."""
    done = {name: writer.header["fields"][name]["done"] for name in problems}
    if not any(any(d) for d in done.values()):
        return False
    parts = ", ".join(f"{name} {sum(d)}/{len(d)}" for name, d in done.items())
    print(f"softreach: resuming the interrupted solve in {writer.partial} (snapshots already solved: {parts}); "
          f"--no-resume starts over", file=sys.stderr)
    return True


#: CPU seconds the solver's first ``torch.compile`` takes with an empty compile cache (the engine of a GPU, and of a
#: CPU for a model whose step cannot be compiled pointwise), as ``benchmarks/first_compile.py torch`` measures them
#: (docs/solver.md quotes the measurement): the notice's estimate of the wall time on an idle core
COLD_COMPILE_S = 70


def compile_notice():
    """A context in which the first ``torch.compile`` that starts announces itself on stderr, once per process,
    with :data:`COLD_COMPILE_S` when torch's compile cache is empty (a machine's first solve), or as a load
    from the cache otherwise. Nothing is said where torch offers no compile hook."""
    try:
        from torch._dynamo.callback import callback_handler
        from torch._inductor.runtime.cache_dir_utils import cache_dir
    except ImportError:  # another torch: no announcement, the solve is unchanged
        return contextlib.nullcontext()
    return _CompileNotice(callback_handler, cache_dir)


class _CompileNotice:
    said = False  # once per process, whatever the number of solves and compiled graphs

    def __init__(self, handler: Any, cache_dir: Any):
        self.handler, self.cache_dir = handler, cache_dir

    def __enter__(self) -> "_CompileNotice":
        self.handler.register_start_callback(self._start)
        return self

    def __exit__(self, *exc: Any) -> None:
        self.handler.remove_start_callback(self._start)

    def _start(self, args: Any) -> None:
        if _CompileNotice.said:
            return
        _CompileNotice.said = True
        where = Path(self.cache_dir())
        graphs = where / "fxgraph"
        if graphs.is_dir() and any(graphs.iterdir()):
            line = f"softreach: torch.compile: building the solver's kernels from the compile cache in {where}"
        else:
            line = (f"softreach: compiling the solver with torch.compile, once per machine: about "
                    f"{COLD_COMPILE_S:.0f} s at 0 % on an idle core, longer on a busy machine; then cached in {where}")
        from tqdm.auto import tqdm

        tqdm.write(line, file=sys.stderr)


def summarize(table, budgets: Sequence[float] = DEFAULT_BUDGETS, t: float = 0.0) -> dict[str, Any]:
    """Set measures at time ``t``: ``RA``, ``RA~_Q`` per budget and the ``Q = 0`` vs classical difference."""
    out: dict[str, Any] = {"t": t, "model": table.model_metadata["name"], "grid": table.grid("V").to_dict()}
    ra = table.set_mask(t)
    vol = table.cell_volume("V")
    out["classical_measure"] = float(ra.sum()) * vol
    if table.has_budget or table.has_budget_surface:
        if table.has_budget:
            out["budget_grid"] = table.grid("W_eps").to_dict()
            out["budget_resolution"] = table.budget_resolution
        out["budgets"] = [float(q) for q in budgets]
        out["soft_measure"] = [table.set_measure(t, q) for q in budgets]
        ra0 = table.set_mask(t, 0.0)
        out["q0_vs_classical"] = {
            "symmetric_difference": float((ra0 ^ ra).sum()) * vol,
            "in_soft_not_classical": float((ra0 & ~ra).sum()) * vol,
            "in_classical_not_soft": float((ra & ~ra0).sum()) * vol,
            "relative": float((ra0 ^ ra).sum()) / max(1, int(ra.sum())),
        }
        if table.has_budget:
            # the raw slice {W_eps(t, x, 0) <= 0} for reference (ill-posed: see Table.set_mask)
            out["q0_vs_classical"]["raw_slice_measure"] = float((table.slice("W_eps", t, 0.0) <= 0).sum()) * vol
    return out
