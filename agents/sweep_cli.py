"""The ``softreach sweep`` subcommand and :func:`run_sweep`, which plans, runs (locally or on Ray), resumes and
reports a sweep (configuration: :mod:`.sweep`; execution: :mod:`.sweep_exec`; table and report:
:mod:`.sweep_report`).

Output folder (``--out``, default ``runs/sweep``): ``sweep.json`` (the resolved sweep; ``softreach sweep
OUT/sweep.json --out OUT`` resumes it), ``runs/<run_id>/`` (one folder per run), ``results.csv`` (the tidy
table, rewritten after every finished run), ``report.md`` and ``plots/``.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

from .config import ALGOS, METHODS, MODELS


def add_sweep_command(sub: argparse._SubParsersAction) -> None:
    """Register ``sweep`` on the ``softreach`` parser's subparsers."""
    from .commands import RULE_CHOICES, START_CHOICES, WIND_CHOICES

    p = sub.add_parser("sweep", help="train and evaluate a grid of configurations (local processes or Ray)",
                       description="Train every combination of the grid's values and evaluate each policy; write one "
                                   "tidy table (results.csv: one row per run and evaluation), report.md and plots. "
                                   "Rerunning into the same --out skips the runs already done. Grid lists come from "
                                   "a sweep FILE (.json or .toml, keys as the options without dashes, e.g. "
                                   "eval_budgets) and/or the options (which win). See docs/agents.md.")
    p.add_argument("file", nargs="?", metavar="FILE", help="a .json or .toml sweep file (optional)")
    p.add_argument("--models", nargs="+", choices=MODELS, help="grid: models (default pointmass)")
    p.add_argument("--algos", nargs="+", choices=ALGOS, help="grid: algorithms (default ppo)")
    p.add_argument("--methods", nargs="+", choices=METHODS,
                   help="grid: training method, 'plain' (the algorithm as it is; the default), 'lag' "
                        "(PPO-Lagrangian) or 'saute' (PPO-Saute); the baselines train without the filter (rule none)")
    p.add_argument("--rules", nargs="+", choices=("none",) + RULE_CHOICES,
                   help="grid: filter rule during training, 'none' for no filter (default switch)")
    p.add_argument("--budgets", nargs="+", metavar="Q|LO:HI|default",
                   help="grid: training budget Q, range LO:HI, or 'default' (the environment's range; the default)")
    p.add_argument("--winds", nargs="+", choices=WIND_CHOICES, help="grid: training wind (default random)")
    p.add_argument("--seeds", nargs="+", type=int, help="grid: training seeds (default 0 1 2)")
    p.add_argument("--table", action="append", metavar="[MODEL=]PATH",
                   help="W_eps table of a model (filter, adversarial wind, starts inside RA~_Q); repeat per model")
    p.add_argument("--timesteps", type=int, help="environment steps per run (default: each model's)")
    p.add_argument("--n-envs", type=int, help="environments stepped together per run")
    p.add_argument("--set", action="append", default=[], metavar="SECTION.FIELD=VALUE",
                   help="override for every run, SECTION run, ppo, sac or safe (the baselines): run.eval_freq=0, "
                        "ppo.n_steps=64, safe.lambda_lr=0.05 "
                        "(VALUE read as JSON, else as text)")
    p.add_argument("--eval-winds", nargs="+", choices=WIND_CHOICES,
                   help="evaluation winds (default adversarial with a table, else random)")
    p.add_argument("--eval-budgets", nargs="+", type=float,
                   help="evaluation budgets Q (default the model's paper ones)")
    p.add_argument("--eval-filters", nargs="+", choices=("on", "off"),
                   help="evaluate with and/or without the filter (default both with a table)")
    p.add_argument("--episodes", type=int, help="episodes per evaluation (default 30)")
    p.add_argument("--starts", choices=START_CHOICES, help="evaluation starts (default inside with a table, else env)")
    p.add_argument("--eval-seed", type=int, help="evaluation seed (default 0; the same for every run)")
    p.add_argument("--eval-own-budget", action="store_true", default=None,
                   help="evaluate a run trained at one budget Q (--budgets Q) only at that Q, which must be among "
                        "--eval-budgets; runs with the budget drawn per episode ('default', LO:HI) at every one")
    p.add_argument("--checkpoint", choices=("best", "final"),
                   help="evaluate best_model.zip (best periodic evaluation; the default) or the final model.zip")
    p.add_argument("--workers", type=int, default=1, help="runs at once: local processes, or Ray CPUs with "
                                                          "--ray local (default 1)")
    p.add_argument("--ray", metavar="auto|local|ADDRESS", default=None,
                   help="run each run as a Ray task: 'auto' (the running cluster), 'local' (start Ray here) or a "
                        "cluster address; needs pip install 'softreach[sweep]'")
    p.add_argument("--out", metavar="DIR", default="runs/sweep", help="output folder (default runs/sweep)")
    p.add_argument("--dry-run", action="store_true", help="list the runs and whether each is done; run nothing")
    p.set_defaults(func=run_sweep_command)


def _value(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def spec_from_args(args: argparse.Namespace):
    """The :class:`~softreach.agents.sweep.SweepSpec` of a command line: the file's, with the options given."""
    from .sweep import OVERRIDE_SECTIONS, SweepSpec, load_sweep_file, parse_budget

    spec = load_sweep_file(args.file) if args.file else SweepSpec()
    given: dict[str, Any] = {}
    for name in ("models", "algos", "methods", "rules", "winds", "seeds", "eval_winds", "eval_budgets", "eval_filters"):
        if getattr(args, name) is not None:
            given[name] = tuple(getattr(args, name))
    if args.budgets is not None:
        given["budgets"] = tuple(parse_budget(b) for b in args.budgets)
    for name in ("timesteps", "n_envs", "episodes", "starts", "eval_seed", "checkpoint", "eval_own_budget"):
        if getattr(args, name) is not None:
            given[name] = getattr(args, name)
    spec = replace(spec, **given)
    tables = dict(spec.tables)
    for item in args.table or []:
        model, sep, path = item.rpartition("=")
        if not sep:
            if len(spec.models) != 1:
                raise ValueError(f"--table {item}: name the model (MODEL=PATH) when the sweep has several models")
            model = spec.models[0]
        if model not in MODELS:
            raise ValueError(f"--table {item}: unknown model {model!r}; choose from {list(MODELS)}")
        tables[model] = path
    # absolute paths: Ray workers need not share our working directory, and run ids hash the path
    spec = replace(spec, tables={m: str(Path(p).resolve()) for m, p in tables.items()})
    overrides = {k: dict(v) for k, v in spec.overrides.items()}
    for item in args.set:
        key, sep, text = item.partition("=")
        section, dot, fld = key.partition(".")
        if not (sep and dot and fld):
            raise ValueError(f"--set {item!r} must be SECTION.FIELD=VALUE (e.g. ppo.n_steps=64)")
        if section not in OVERRIDE_SECTIONS:
            raise ValueError(f"--set {item!r}: section {section!r} must be one of {list(OVERRIDE_SECTIONS)}")
        overrides.setdefault(section, {})[fld] = _value(text)
    return replace(spec, overrides=overrides)


def run_sweep(spec, out: str | Path, workers: int = 1, ray: str | None = None,
              log: Callable[[str], None] = print, dry_run: bool = False) -> dict[str, Any]:
    """Check ``spec``, run the runs that are not done, write the table and the report.

    :param out: output folder (resumed if it holds runs of the same ids)
    :param workers: local processes (or Ray CPUs with ``ray="local"``)
    :param ray: ``None`` (local processes), ``"auto"``, ``"local"`` or a Ray cluster address
    :param log: where progress lines go
    :param dry_run: only list the runs
    :returns: ``{"runs", "skipped", "ran", "rows", "table", "report", "status"}``
    """
    from .sweep_exec import RESULT_FILE, execute_local, execute_ray, is_done, new_result, read_result, write_atomic
    from .sweep_report import table_rows, write_report, write_table

    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"--workers must be a positive integer, got {workers!r}")
    spec.check()
    out = Path(out).resolve()
    runs = spec.runs()
    ids = [r.run_id for r in runs]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise ValueError(f"the grid repeats runs {dup} (a value given twice?)")
    evals = {r.run_id: spec.run_evaluations(r) for r in runs}
    dirs = {r.run_id: out / "runs" / r.run_id for r in runs}
    results = {r.run_id: read_result(dirs[r.run_id]) for r in runs}
    todo = {r.run_id: (r, evals[r.run_id], str(dirs[r.run_id])) for r in runs
            if not is_done(results[r.run_id], evals[r.run_id])}
    resume = f"softreach sweep {shlex.quote(str(out / 'sweep.json'))} --out {shlex.quote(str(out))}" + \
             (f" --ray {ray}" if ray else "") + (f" --workers {workers}" if workers != 1 else "")
    n_evals = sum(len(evals[r.run_id]) for r in runs)
    log(f"sweep: {len(runs)} runs, {n_evals} evaluations; {len(runs) - len(todo)} already done, {len(todo)} to run "
        f"({'Ray ' + ray if ray else f'{workers} local process(es)'}) -> {out}")
    if dry_run:
        for r in runs:
            log(f"  {'todo' if r.run_id in todo else 'done'}  {r.run_id}")
        return {"runs": len(runs), "skipped": len(runs) - len(todo), "ran": 0, "rows": [], "table": None,
                "report": None, "status": {}, "resume": resume}
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep.json").write_text(json.dumps(spec.to_dict(), indent=1))
    table = out / "results.csv"

    def items() -> list:
        return [(r, evals[r.run_id], results[r.run_id]) for r in runs]

    t0 = time.perf_counter()
    finished = 0

    def on_result(rid: str, res: dict[str, Any]) -> None:
        nonlocal finished
        if res["status"] == "killed":  # keep what an earlier invocation finished (training, evaluations)
            prev = read_result(dirs[rid])
            if prev is not None:
                res = {**prev, "status": "killed", "error": res["error"]}
        dirs[rid].mkdir(parents=True, exist_ok=True)
        write_atomic(dirs[rid] / RESULT_FILE, res)  # again on the driver: a Ray worker may write elsewhere
        results[rid] = res
        finished += 1
        err = f": {res['error']}" if res.get("error") else ""
        log(f"[{finished}/{len(todo)}] {rid} {res['status']}{err} ({time.perf_counter() - t0:.0f} s)")
        write_table(table_rows(items()), table)

    try:
        if todo and ray:
            execute_ray(todo, ray, workers, on_result)
        elif todo:
            execute_local(todo, workers, on_result)
    except KeyboardInterrupt:
        write_table(table_rows(items()), table)
        raise SweepInterrupted(resume, finished, len(todo)) from None
    for rid in todo:  # a backend that returned without a result for a run: say so
        if results[rid] is None or results[rid].get("status") == "running":
            on_result(rid, new_result(todo[rid][0], "failed", "no result came back from the worker"))
    rows = table_rows(items())
    write_table(rows, table)
    counts = {"runs": len(runs), "skipped": len(runs) - len(todo), "ran": len(todo)}
    report = write_report(rows, [(r, results[r.run_id]) for r in runs], out, resume, counts,
                          time.perf_counter() - t0)
    status = {s: sum(1 for r in rows if r["status"] == s) for s in ("done", "failed", "killed", "missing")}
    return {**counts, "rows": rows, "table": table, "report": report, "status": status, "resume": resume}


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C during a sweep; carries the command that resumes it."""

    def __init__(self, resume: str, finished: int, todo: int):
        super().__init__(resume)
        self.resume, self.finished, self.todo = resume, finished, todo


def run_sweep_command(args: argparse.Namespace) -> int:
    """``softreach sweep``: 0 when every run finished, 1 when one failed or was killed, 130 on Ctrl-C."""
    spec = spec_from_args(args)
    try:
        res = run_sweep(spec, args.out, workers=args.workers, ray=args.ray, dry_run=args.dry_run)
    except SweepInterrupted as exc:
        print(f"\nsoftreach sweep: interrupted after {exc.finished} of {exc.todo} runs; finished runs are kept. "
              f"Resume (skips them) with:\n  {exc.resume}", file=sys.stderr)
        return 130
    if args.dry_run:
        return 0
    st = res["status"]
    print(f"table: {res['table']}  ({st['done']} rows done" +
          "".join(f", {st[k]} {k}" for k in ("failed", "killed", "missing") if st[k]) + ")")
    print(f"report: {res['report']}")
    if st["failed"] or st["killed"] or st["missing"]:
        print(f"some runs did not finish (errors in the report); retry them with: {res['resume']}", file=sys.stderr)
        return 1
    return 0


__all__ = ["SweepInterrupted", "add_sweep_command", "run_sweep", "run_sweep_command", "spec_from_args"]
