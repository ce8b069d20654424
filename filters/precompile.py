"""The filter's compiled decision, compiled ahead of its first use: ``softreach compile TABLE``.

The first decision a machine makes compiles :mod:`softreach.filters.compiled`, and the first reset the start's
certificate (:mod:`softreach.filters.compiled_certify`; ``benchmarks/first_compile.py filter`` measures both),
into the package's compiled-code cache (:mod:`softreach.reach.jit`: ``$NUMBA_CACHE_DIR``, else ``numba/`` in
``$SOFTREACH_CACHE`` or ``~/.cache/softreach``), which every later process loads in a fraction of a second.
Made on purpose, that compilation does not stall an episode, and environment processes started together (a
vector of environments, an SB3 ``SubprocVecEnv``) do not each compile at once. One table of each model and
period is enough: every table of the same value type (``float32`` or ``float64``) shares the compiled decision,
and each model adds its own enclosure.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np


def precompile(table: Any, period: float | None = None, cells: bool = True) -> dict[str, Any]:
    """Make one decision, one certificate of a state and one start-plan search of the filter the environment
    wraps around ``table``.

    :param table: a :class:`~softreach.reach.tables.table.Table` (or its path)
    :param period: the control period [s] (default: the table's)
    :param cells: give the filter the model's cells (built or unpacked where missing); ``False``: cells that
        certify nothing (:meth:`~softreach.reach.proof.cell_certificate.CellCertificate.empty`), with which it runs
        the same compiled code, which is all that compiling ahead needs
    :return: ``model``, ``compiled`` (always true: every filter decides compiled; a model without what it needs
        is refused by :class:`~softreach.filters.ValueFilter`, with ``missing`` then never reached), ``seconds``,
        ``source`` (``"compiled"`` now, loaded from the ``"cache"``, or already in this ``"process"``) and
        ``cache`` (the folder of the compiled code, :func:`softreach.reach.jit.compiled_cache_dir`)
    """
    from softreach.reach import load_table
    from softreach.reach.proof.cell_certificate import CellCertificate
    from softreach.reach.proof.lookahead import Lookahead

    from . import ValueFilter
    from .compiled import decide_rows
    from .compiled_certify import certify_rows
    from .compiled_starts import start_plan_rows
    from .plans import START_SEGMENTS

    if not hasattr(table, "model"):
        table = load_table(table)
    model = table.model
    if not (table.has_budget or table.has_budget_surface):
        raise ValueError(f"softreach compile needs a W_eps or Q_min table (softreach solve {model.name} --held); "
                         f"{table.path} holds only the classical V")
    if period is None and table.control_period is None:
        if model.control_period is None:
            raise ValueError(f"softreach compile needs --period SECONDS: {table.path} was solved in continuous time "
                             f"and {model.name} declares no control_period")
        period = model.control_period  # the cells certify; the table only ranks, at the env's period
    dt = float(period if period is not None else table.control_period)
    hits, misses = (sum(c.values()) for c in (decide_rows.stats.cache_hits, decide_rows.stats.cache_misses))
    t0 = time.perf_counter()
    # the landing checks SafetyFilter asks for: the same compiled code as any other count, and cells it ships
    checks = getattr(model, "substeps", 1)
    empty = {}
    if not cells:
        la = Lookahead.from_table(table, model, dt, table.eps, target_checks=checks)
        empty = {"safe_cells": None, "landing_cells": CellCertificate.empty(la)}
    vf = ValueFilter(table, dt, target_checks=checks, **empty)
    out: dict[str, Any] = {"model": model.name, "compiled": True, "seconds": 0.0, "source": None, "cache": None,
                           "missing": None}
    # a state in the middle of the table's grid; what the decision finds there does not matter
    grid = table.grid("V")
    x = 0.5 * (np.asarray(grid.lo[:model.state_dim]) + np.asarray(grid.hi[:model.state_dim]))
    vf.filter(0.0, x, 0.0, vf.fallback_action)
    vf.certify(0.0, x, 0.0)
    vf.compiled.start_plans(np.zeros(1), x[None], np.zeros(1), 1, np.ones(1, bool), START_SEGMENTS)
    out["seconds"] = time.perf_counter() - t0  # the filter's construction with its first decision
    # compiled now, loaded from the cache, or already in this process
    out["source"] = ("compiled" if sum(decide_rows.stats.cache_misses.values()) > misses else
                     "cache" if sum(decide_rows.stats.cache_hits.values()) > hits else "process")
    out["cache"] = decide_rows.stats.cache_path
    if not (decide_rows.signatures and certify_rows.signatures and start_plan_rows.signatures):
        raise RuntimeError(f"{model.name}: the filter made a decision without its compiled code")
    return out


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register ``compile`` on the ``softreach`` parser's subparsers."""
    p = sub.add_parser("compile", help="compile the safety filter's decision ahead of its first use",
                       description="Compile the safety filter's decision and a start's certificate into the "
                                   "compiled-code cache ($NUMBA_CACHE_DIR, else numba/ in $SOFTREACH_CACHE or "
                                   "~/.cache/softreach; about a minute once per machine), so that no later process "
                                   "compiles them at its first decision or reset: before an episode, a vector of "
                                   "environments or an SB3 SubprocVecEnv starts. One table of each model is enough.")
    p.add_argument("tables", nargs="+", metavar="TABLE", help="table files (one per model and period is enough)")
    p.add_argument("--period", type=float, default=None, help="control period [s] (default: each table's)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    for path in args.tables:
        r = precompile(path, args.period)
        if r["source"] == "compiled":
            print(f"{path}: {r['model']}'s filter compiled in {r['seconds']:.1f} s, cached in {r['cache']}")
        else:
            print(f"{path}: {r['model']}'s filter was already compiled (cached in {r['cache']}); its first "
                  f"decision took {r['seconds']:.1f} s")
    return 0
