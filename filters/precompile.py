"""``softreach compile TABLE``: the filter's code compiled into the cache (:mod:`softreach.reach.jit`) ahead of its
first use, so that no episode stalls on it and processes started together do not each compile it (docs/filters.md,
'Speed'). One table per model and period is enough: tables of one value type share the compiled decision."""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np


def decision_code_counts() -> tuple[int, int]:
    """The compiled decision's numba cache hits and misses in this process so far (:func:`decision_code_source`)."""
    from .compiled import decide_rows

    return sum(decide_rows.stats.cache_hits.values()), sum(decide_rows.stats.cache_misses.values())


def decision_code_source(before: tuple[int, int]) -> str:
    """Where the compiled decision came from since :func:`decision_code_counts` gave ``before``: ``"compiled"``,
    loaded from the ``"cache"``, or already in this ``"process"``."""
    hits, misses = decision_code_counts()
    return "compiled" if misses > before[1] else "cache" if hits > before[0] else "process"


def precompile(table: Any, period: float | None = None, cells: bool = True) -> dict[str, Any]:
    """Make one decision, state certificate and start-plan search of the filter an environment wraps around ``table``.

    :param table: a :class:`~softreach.reach.tables.table.Table` (or its path)
    :param period: the control period [s] (default: the table's, else the model's for a continuous-time table)
    :param cells: the model's cells (built or unpacked where missing); ``False``: empty ones, which run the same code
    :return: ``model``, ``seconds``, ``source`` (``"compiled"`` by this call, loaded from the ``"cache"``, or already in
        this ``"process"``) and ``cache`` (the folder, :func:`softreach.reach.jit.compiled_cache_dir`)
    :raises ValueError: a table without ``W_eps`` or ``Q_min``, or no control period known (and the refusals of
        :class:`~softreach.filters.ValueFilter`, e.g. of a model it cannot serve)"""
    from softreach.reach import load_table
    from softreach.reach.proof.cell_certificate import CellCertificate
    from softreach.reach.proof.lookahead import Lookahead

    from . import ValueFilter
    from .compiled import decide_rows
    from .compiled_starts import start_plan_rows

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
    before = decision_code_counts()
    t0 = time.perf_counter()
    # the landing checks SafetyFilter asks for: the same compiled code as any other count, and cells it ships
    checks = getattr(model, "substeps", 1)
    empty = {}
    if not cells:
        la = Lookahead.from_table(table, model, dt, table.eps, target_checks=checks)
        empty = {"landing_cells": CellCertificate.empty(la)}
    vf = ValueFilter(table, dt, target_checks=checks, **empty)
    # a state in the middle of the table's grid; what the decision finds there does not matter
    grid = table.grid("V")
    x = 0.5 * (np.asarray(grid.lo[:model.state_dim]) + np.asarray(grid.hi[:model.state_dim]))
    vf.filter(0.0, x, 0.0, vf.fallback_action)
    vf.certify(0.0, x, 0.0)
    vf.compiled.start_plans(np.zeros(1), x[None], np.zeros(1), 1, np.ones(1, bool))
    seconds = time.perf_counter() - t0  # the filter's construction with its first decision
    source = decision_code_source(before)
    if not (decide_rows.signatures and start_plan_rows.signatures):
        raise RuntimeError(f"{model.name}: the filter made a decision without its compiled code")
    return {"model": model.name, "seconds": seconds, "source": source, "cache": decide_rows.stats.cache_path}


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
