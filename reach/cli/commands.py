"""The ``solve``, ``plot`` and ``study`` subcommands of the ``softreach`` command line."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ..registry import model_argument, model_metavar


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("solve", help="solve V and W_eps for a model and write a table",
                       description="Solve the classical value V and the soft-constrained W_eps on the budget-augmented grid.")
    p.add_argument("model", type=model_argument, metavar=model_metavar(),
                   help="a registered model or the module:Class path of your own Model subclass")
    p.add_argument("--grid", type=int, nargs="+", metavar="N", help="state grid sizes (default: the model's; "
                   "with --held its held_shape where it has one)")
    p.add_argument("--domain", nargs="+", metavar="LO|HI|hard", default=None,
                   help="grid box: the lower ends of every state axis, then the upper ends (2n numbers), or 'hard' "
                        "for the hard-constraint box C1 and 3 cells around it (default: the model's box)")
    p.add_argument("--budget-points", type=int, metavar="NZ", help="nodes along the budget axis z (default: "
                   "the model's; with --held its held_budget_points where it has one)")
    p.add_argument("--eps", type=float, default=1e-3, help="width of h_eps (default 1e-3)")
    p.add_argument("--budget-scale", type=float, help="kappa in l = max(c2, -kappa z, g) (default: the model's)")
    p.add_argument("--accuracy", choices=["low", "medium", "high", "very_high"], default="very_high",
                   help="scheme: low first order/RK1, medium ENO2/RK2, high WENO3/RK3, very_high WENO5/RK3 (default)")
    p.add_argument("--device", default="cpu", help="cpu or cuda[:k] (torch backend; default cpu)")
    p.add_argument("--backend", choices=["torch", "numpy"], default="torch",
                   help="array library of the solver: torch (default; --device, --threads and torch.compile apply) "
                        "or numpy (single-threaded reference, no compilation)")
    p.add_argument("--dtype", choices=["float32", "float64"], default="float32",
                   help="floating-point type of the computation (default float32: half the memory, faster; float64 "
                        "for convergence studies); the table stores float32 either way")
    p.add_argument("--compile", choices=["auto", "yes", "no"], default="auto",
                   help="fuse steps with torch.compile: auto compiles grids of 90,000 nodes or more (default), yes "
                        "always, no never; the first compile on a machine takes a minute or more, later ones load "
                        "it from the on-disk cache")
    p.add_argument("--dissipation", choices=["auto", "godunov", "local", "global"], default="local",
                   help="numerical Hamiltonian: local/global Lax-Friedrichs, Godunov's (separable Hamiltonians), "
                        "or auto: Godunov where separable (default local)")
    p.add_argument("--snapshots", type=int, default=None, help="output times over [0, T] (also the checkpoint interval)")
    p.add_argument("--out", default=None, help="table path (default: <model>.srt)")
    p.add_argument("--json", dest="json_path", default=None, help="write a machine-readable summary here")
    p.add_argument("--classical", action="store_true", help="solve only the classical V")
    p.add_argument("--held", action="store_true",
                   help="solve the sampled-data game at the model's control period (actions held for a period, wind "
                        "free at every instant): the table the safety filter certifies with")
    p.add_argument("--control-period", type=float, default=None, metavar="SECONDS",
                   help="the sampled-data game at this period instead of the model's (implies --held)")
    p.add_argument("--budget-surface", action="store_true",
                   help="solve the budget surface Q_min(t, x) on the state grid instead of W_eps on (x, z): "
                        "RA~_Q = {Q_min <= Q} for every Q at the cost of one state-grid solve")
    p.add_argument("--held-levels", type=int, default=None, metavar="K",
                   help="candidate held actions per control axis, corners and centre included (default: the "
                        "model's held_levels)")
    p.add_argument("--no-resume", action="store_true", help="ignore an unfinished .partial file and start over")
    p.add_argument("--budgets", type=float, nargs="+", default=None, help="budgets for the summary (default 0 0.06 0.3 0.6 for the point mass)")
    p.add_argument("--threads", type=int, default=None,
                   help="torch CPU threads (default: one per idle core, at least one; OMP_NUM_THREADS, if set, wins)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run_solve)

    p = sub.add_parser("plot", help="draw the sets of a table (Fig. 1 style)")
    p.add_argument("table", help="a table file written by softreach solve (.srt)")
    p.add_argument("--budgets", type=float, nargs="+", default=None,
                   help="budgets Q [s] whose sets RA~_Q are drawn (default: the model's)")
    p.add_argument("--t", type=float, default=0.0, metavar="SECONDS",
                   help="time t of the sets, in seconds from the start of the horizon [0, T] (default 0: the sets "
                        "of starts with the whole horizon ahead)")
    p.add_argument("--from", dest="starts", action="append", default=[], metavar="X1,X2,...[:Q]",
                   help="simulate the W-derived policy under worst-case disturbance from this state with budget Q (repeatable; write --from=-12,4:0.3 when the state starts with a minus sign)")
    p.add_argument("--paper-starts", action="store_true",
                   help="add the paper's representative starts: the highest point just inside RA~_Q for Q = 0, 0.3, 0.6 (Fig. 1, 5)")
    p.add_argument("--slice", dest="slices", type=float, action="append", default=[], metavar="VALUE",
                   help="models with more than 2 states: also outline the sets at this value of the third state (radians for angles; repeatable)")
    p.add_argument("--out", default="fig.png", help="image path (default fig.png)")
    p.set_defaults(func=run_plot)

    p = sub.add_parser("study", help="convergence studies of the paper (Fig. 2, Fig. 3)")
    p.add_argument("which", choices=["grid-convergence", "eps-convergence"],
                   help="grid-convergence: distance from the classical set's boundary to that of RA~_0 as the "
                        "point-mass grid is refined (Fig. 2); eps-convergence: the measure of the difference "
                        "between RA~_Q at successive eps (Fig. 3)")
    p.add_argument("--sizes", type=int, nargs="+", default=[50, 100, 150, 200, 300],
                   help="grid-convergence: state grid sizes N of the N x N grids (default 50 100 150 200 300)")
    p.add_argument("--budget-points", type=int, default=200, help="nodes along the budget axis z (default 200)")
    p.add_argument("--eps-list", type=float, nargs="+", default=[10.0, 3.0, 1.0, 0.1, 1e-2, 1e-3],
                   help="eps-convergence: the eps values compared in turn (default 10 3 1 0.1 0.01 0.001)")
    p.add_argument("--grid", type=int, nargs=2, default=[101, 101], help="eps-convergence: state grid (default 101 101)")
    p.add_argument("--samples", type=int, default=50_000,
                   help="grid-convergence: points sampled on the boundary of RA (default 50000)")
    p.add_argument("--accuracy", choices=["low", "medium", "high", "very_high"], default="very_high",
                   help="scheme: low first order/RK1, medium ENO2/RK2, high WENO3/RK3, very_high WENO5/RK3 (default)")
    p.add_argument("--workdir", default="runs/study", help="where the solved tables are kept (default runs/study)")
    p.add_argument("--json", dest="json_path", default=None, help="write the results here")
    p.set_defaults(func=run_study)


def idle_cores() -> int | None:
    """Torch threads for a CPU solve: one per core that the load average leaves idle, at least one; ``None``
    (torch's own choice) when ``OMP_NUM_THREADS`` is set.

    Threads that synchronise at every step wait for the slowest, so one busy core stalls them all: on a loaded
    machine one thread is the faster, on an idle one every core is (docs/solver.md, "Threads", measures both).
    """
    import os

    if "OMP_NUM_THREADS" in os.environ:
        return None
    cores = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except OSError:  # no load average on this platform
        return cores
    return max(1, min(cores, int(cores - load + 0.5)))


def _settings(args: argparse.Namespace):
    from ..numerics.solver import SolverSettings

    compile_ = {"auto": None, "yes": True, "no": False}[args.compile]
    return SolverSettings.from_accuracy(args.accuracy, backend=args.backend, device=args.device, dtype=args.dtype,
                                        compile=compile_, dissipation=getattr(args, "dissipation", "local"))


def run_solve(args: argparse.Namespace) -> int:
    from ..numerics.compute import SolveConfig, solve_table
    from ..models import get_model

    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads must be >= 1, got {args.threads}")
    model = get_model(args.model)
    ahead = None
    if not args.classical:
        # the safety filter's compiled code does not depend on the table: compile it on another core meanwhile
        from softreach.filters.background import start

        ahead = start()
    threads = args.threads if args.threads is not None else idle_cores()
    if ahead is not None and args.threads is None and threads is not None:
        threads = max(1, threads - 1)  # the core the compilation takes
    if threads is not None and args.backend == "torch" and args.device == "cpu":
        import torch

        torch.set_num_threads(threads)
    # a model may declare a coarser default grid for its held table (held_shape, held_budget_points)
    held = args.held or args.control_period is not None
    shape = tuple(args.grid) if args.grid else (held and getattr(model, "held_shape", None)) or model.default_shape
    cfg = SolveConfig(
        shape=shape,
        domain=_domain(args.domain, model, shape),
        budget_points=(args.budget_points or (held and getattr(model, "held_budget_points", None))
                       or model.default_budget_points),
        eps=args.eps,
        budget_scale=args.budget_scale,
        settings=_settings(args),
        snapshots=model.default_snapshots if args.snapshots is None else args.snapshots,
        classical_only=args.classical,
        control_period=args.control_period if args.control_period is not None else (
            model.control_period if args.held else None),
        held_levels=args.held_levels,
        budget_surface=args.budget_surface,
    )
    suffix = ("-held" if cfg.control_period is not None else "") + ("-qmin" if cfg.budget_surface else "")
    # a class path names the table after the class ("my_pkg.mod:Car" -> Car.srt)
    out = Path(args.out or f"{args.model.rpartition(':')[2]}{suffix}.srt")
    if args.json_path:
        _check_writable(Path(args.json_path), "--json")
    budgets = args.budgets if args.budgets is not None else model.default_budgets
    try:
        summary = solve_table(model, cfg, out, resume=not args.no_resume, progress=not args.quiet, budgets=budgets)
    except KeyboardInterrupt:
        print(f"\nsoftreach: interrupted. Finished snapshots are kept in {out}.partial; run the same command again to "
              f"resume from them (--no-resume starts over).", file=sys.stderr)
        return 130
    summary["table"] = str(out)
    if args.device == "cpu" and args.backend == "torch":
        import torch

        summary["threads"] = torch.get_num_threads()
    print(_format_summary(summary))
    if args.json_path:
        Path(args.json_path).write_text(json.dumps(summary, indent=2))
    return 0


def _domain(words: list[str] | None, model, shape: tuple[int, ...]):
    """``--domain``: ``None`` (the model's box), ``hard`` (:func:`~softreach.reach.numerics.compute.hard_box_domain`), or
    ``2 n`` numbers."""
    from ..numerics.compute import hard_box_domain

    if words is None:
        return None
    if words == ["hard"]:
        return hard_box_domain(model, shape)
    n = model.state_dim
    try:
        values = [float(w) for w in words]
    except ValueError:
        raise ValueError(f"--domain takes 'hard' or {2 * n} numbers (lower ends, then upper ends), got {words}") from None
    if len(values) != 2 * n:
        raise ValueError(f"--domain needs {2 * n} numbers for {model.name} ({n} lower ends, then {n} upper ends), "
                         f"got {len(values)}: {words}")
    return tuple(values[:n]), tuple(values[n:])


def _check_writable(path: Path, option: str) -> None:
    """Fail before a long run, not after it, when its output file cannot be written."""
    import os

    if path.is_dir():
        raise ValueError(f"{option} {path} is a directory")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"{option} directory {parent} does not exist")
    if not os.access(path if path.exists() else parent, os.W_OK):
        raise PermissionError(f"{option} {path} is not writable")


def _format_summary(s: dict[str, Any]) -> str:
    lines = [f"table: {s.get('table')}", f"classical RA measure at t=0: {s['classical_measure']:.4f}"]
    if "budgets" in s:
        for q, m in zip(s["budgets"], s["soft_measure"]):
            lines.append(f"RA~_Q measure, Q={q:g}: {m:.4f}")
        d = s["q0_vs_classical"]
        lines.append(f"Q=0 vs classical: symmetric difference {d['symmetric_difference']:.4f} ({100 * d['relative']:.2f}% of RA)")
    if s.get("control_period") is not None:
        lines.append(f"sampled-data game: actions held for {s['control_period']:g} s, wind free at every instant")
    lines.append("wall time: " + ", ".join(f"{k} {v:.1f}s" for k, v in s.get("wall_time_s", {}).items())
                 + (" (resumed: the interrupted run's solver time included)" if s.get("resumed") else ""))
    return "\n".join(lines)


def _parse_start(text: str, n: int) -> tuple[tuple[float, ...], float]:
    state, _, q = text.partition(":")
    try:
        x = tuple(float(v) for v in state.split(","))
        budget = float(q) if q else 0.0
    except ValueError:
        raise ValueError(f"--from expects X1,...,X{n}[:Q], got {text!r}") from None
    if len(x) != n:
        raise ValueError(f"--from expects {n} state values, got {text!r}")
    return x, budget


def _check_start(start: tuple[tuple[float, ...], float], text: str, table) -> tuple[tuple[float, ...], float]:
    """Refuse, naming the values, a ``--from`` start outside the table's grid (where it has no value: the model's
    domain unless the table was solved on a smaller box) or a budget outside ``[0, T]``."""
    import math

    x, q = start
    model = table.model
    grid = table.grid("V")
    units = getattr(model, "state_units", ("",) * model.state_dim)
    bad = [f"{name}={v:g} not in [{lo:g}, {hi:g}] {unit}".rstrip()
           for name, unit, v, lo, hi, per in zip(model.state_names, units, x, grid.lo, grid.hi, grid.periodic)
           if not (math.isfinite(v) and (per or lo <= v <= hi))]
    if bad:
        raise ValueError(f"--from={text}: the start lies outside the table's grid (the {model.name} domain it was "
                         f"solved on): " + "; ".join(bad))
    if not (math.isfinite(q) and 0.0 <= q <= model.horizon):
        raise ValueError(f"--from={text}: budget Q={q:g} must lie in [0, T] = [0, {model.horizon:g}] s")
    model.validate_state(list(x))
    return start


def run_plot(args: argparse.Namespace) -> int:
    from ..tables.query import load_table

    table = load_table(args.table)
    model = table.model
    budgets = args.budgets if args.budgets is not None else list(model.default_budgets)
    if not 0.0 <= args.t <= model.horizon:
        raise ValueError(f"--t {args.t:g} must lie in [0, T] = [0, {model.horizon:g}] s")
    starts = [_check_start(_parse_start(s, model.state_dim), s, table) for s in args.starts]
    if args.paper_starts and table.has_budget:
        from .plotting import representative_starts

        picks = [q for q in (budgets[0], budgets[len(budgets) // 2], budgets[-1])] if len(budgets) > 2 else budgets
        starts += representative_starts(table, sorted(set(picks)))
    if model.state_dim == 2:
        from .plotting import plot_sets_2d

        out = plot_sets_2d(table, budgets if table.has_budget else [], args.out, t=args.t,
                           starts=[s for s, _ in starts], start_budgets=[q for _, q in starts])
    else:
        from .plotting_nd import plot_sets_nd

        out = plot_sets_nd(table, budgets, args.out, t=args.t, starts=[s for s, _ in starts], start_budgets=[q for _, q in starts],
                           slices=args.slices, panel_axes=tuple(model.plot_axes))
    print(f"wrote {out}")
    return 0


def run_study(args: argparse.Namespace) -> int:
    from . import studies

    if args.json_path:
        _check_writable(Path(args.json_path), "--json")
    if args.which == "grid-convergence":
        result = studies.grid_convergence(args.sizes, args.budget_points, samples=args.samples, accuracy=args.accuracy, workdir=args.workdir)
    else:
        result = studies.eps_convergence(args.eps_list, tuple(args.grid), args.budget_points, accuracy=args.accuracy, workdir=args.workdir)
    print(studies.format_result(result))
    if args.json_path:
        Path(args.json_path).write_text(json.dumps(result, indent=2))
    return 0
