"""Run a sweep's runs: in local processes (``ProcessPoolExecutor``) or as Ray tasks, resumable.

Each run lives in ``OUT/runs/<run_id>/``: ``train/`` (the ``softreach train`` outputs), ``eval-<eval_id>.json``
(each evaluation, schema ``softreach.evaluation/1``) and ``result.json`` (schema ``softreach.sweep-run/1``: the
run's status, error, training summary and every evaluation's aggregates), written atomically (a temporary file
renamed over it), so a killed run never leaves half a result. A rerun reads ``result.json``: a run whose training
and requested evaluations are all done is skipped; a run that trained but lacks an evaluation is only evaluated;
a failed or killed one runs again.

:func:`run_one` never raises for a failure of the run itself: the exception becomes ``status: "failed"`` with its
message. A worker process that dies (killed, out of memory, ``os._exit``) cannot report; the driver reports the
run it was running as ``status: "killed"`` (see :func:`execute_local` and :func:`execute_ray`).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import socket
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from .sweep import EvalSetting, SweepRun

RESULT_SCHEMA = "softreach.sweep-run/1"
RESULT_FILE = "result.json"
#: written by the worker when it starts a run; its presence after a worker died says the run was in flight
RUNNING_FILE = "running.json"

Task = tuple[SweepRun, list[EvalSetting], str]


def write_atomic(path: Path, data: dict[str, Any]) -> None:
    """Write JSON to ``path`` through a temporary file and a rename (atomic on POSIX)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(data, indent=1, allow_nan=False, default=str))
    os.replace(tmp, path)


def read_result(run_dir: str | Path) -> dict[str, Any] | None:
    """The run's ``result.json``, or ``None`` if absent or unreadable (a rerun then runs it again)."""
    try:
        data = json.loads((Path(run_dir) / RESULT_FILE).read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) and data.get("schema") == RESULT_SCHEMA else None


def is_done(result: dict[str, Any] | None, evals: list[EvalSetting]) -> bool:
    """Whether ``result`` holds a finished training and every evaluation in ``evals``."""
    if not result or result.get("train", {}).get("status") != "done":
        return False
    done = result.get("evaluations", {})
    return all(done.get(ev.eval_id, {}).get("status") == "done" for ev in evals)


def _error_text(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}".strip()


def new_result(run: SweepRun, status: str, error: str | None = None) -> dict[str, Any]:
    """A ``result.json`` document with no training and no evaluation (for a run that failed before them)."""
    return {"schema": RESULT_SCHEMA, "run_id": run.run_id, "run": asdict(run), "status": status, "error": error,
            "train": {"status": "not run"}, "evaluations": {}, "host": socket.gethostname(), "pid": os.getpid(),
            "finished": _dt.datetime.now().isoformat(timespec="seconds")}


def finished_training(run: SweepRun, run_dir: Path) -> dict[str, Any] | None:
    """The ``train`` entry of ``result.json`` for a training that finished in ``run_dir/train`` although the run
    left no result (its worker was killed while it evaluated), or ``None``.

    Finished means what :func:`~softreach.agents.safe_train.train_method` writes last: ``config.json`` with
    ``"status": "done"`` and this run's method, ``model.zip`` and ``training_safety.json``. The folder is the run
    id's, and the id hashes every training setting, so a finished training there is this run's.
    """
    from .safe_train import SAFETY_FILE

    d = Path(run_dir) / "train"
    try:
        cfg = json.loads((d / "config.json").read_text())
        safety = json.loads((d / SAFETY_FILE).read_text())
    except (OSError, ValueError):
        return None
    if cfg.get("status") != "done" or (cfg.get("method") or {}).get("name", "plain") != run.method or \
            not (d / "model.zip").is_file():
        return None
    best = d / "best_model.zip"
    return {"status": "done", "model_path": str(d / "model.zip"), "best_model_path": str(best) if best.is_file() else None,
            "wall_time_s": cfg.get("wall_time_s"), "timesteps": cfg.get("timesteps"), "run_dir": str(d),
            "safety": safety}


def _train(run: SweepRun, run_dir: Path, previous: dict[str, Any] | None) -> dict[str, Any]:
    """Train, unless ``previous`` says the training is done and its model is still there, or the run's folder
    holds a finished training (:func:`finished_training`)."""
    old = (previous or {}).get("train", {})
    if old.get("status") == "done" and Path(old.get("model_path", "")).is_file():
        return old
    found = finished_training(run, run_dir)
    if found is not None:
        return found
    from .safe_train import train_method

    res, safety = train_method(run.train_spec(run_dir / "train"), run.method, run.safe_overrides)
    return {"status": "done", "model_path": str(res.model_path),
            "best_model_path": str(res.best_model_path) if res.best_model_path else None,
            "wall_time_s": res.wall_time_s, "timesteps": res.timesteps, "run_dir": str(res.out_dir),
            "safety": safety}


def _evaluate(run: SweepRun, ev: EvalSetting, trained: dict[str, Any], run_dir: Path, cache: dict) -> dict[str, Any]:
    """One evaluation of the trained policy; its full document goes to ``eval-<eval_id>.json``."""
    from .evaluate import EvalSpec, evaluate
    from .report import write_json
    from .safe_train import load_method_policy

    best = trained.get("best_model_path")
    path = best if (ev.checkpoint == "best" and best) else trained["model_path"]
    if path not in cache:
        cache[path] = load_method_policy(path)  # a Saute policy appends its safety state itself
    rule = run.rule if run.rule != "none" else "switch"
    t0 = time.perf_counter()
    res = evaluate(EvalSpec(model=run.model, policy=path, filter=ev.table if ev.filter == "on" else None, rule=rule,
                            budget=ev.budget, wind=ev.wind, table=ev.table, episodes=ev.episodes, starts=ev.starts,
                            seed=ev.seed, keep_traces=0), policy_obj=cache[path])
    wall = time.perf_counter() - t0
    doc_path = write_json(res, run_dir / f"eval-{ev.eval_id}.json")
    return {"status": "done", "error": None, "setting": asdict(ev), "rule": rule if ev.filter == "on" else None,
            "checkpoint": Path(path).name, "policy": path, "wall_time_s": wall, "document": str(doc_path),
            "aggregates": json.loads(doc_path.read_text())["aggregates"]}


def run_one(run: SweepRun, evals: list[EvalSetting], run_dir: str) -> dict[str, Any]:
    """Train ``run`` (unless done) and evaluate it under ``evals`` (those not done), in this process.

    Writes ``result.json`` atomically and returns it. A failure of the training marks the run and all its
    evaluations failed; a failure of one evaluation marks that evaluation (and the run) failed. Never raises for
    an exception of the run (``SystemExit`` included); ``KeyboardInterrupt`` propagates.

    :param run: the training run
    :param evals: its evaluations
    :param run_dir: the run's folder (created; an earlier ``result.json`` there is resumed from)
    """
    if "OMP_NUM_THREADS" not in os.environ:  # small MLPs gain nothing from more threads; runs share the cores
        import torch

        torch.set_num_threads(1)
    d = Path(run_dir)
    d.mkdir(parents=True, exist_ok=True)
    write_atomic(d / RUNNING_FILE, {"pid": os.getpid(), "host": socket.gethostname(),
                                    "started": _dt.datetime.now().isoformat(timespec="seconds")})
    previous = read_result(d)
    result = new_result(run, "running")
    try:
        result["train"] = _train(run, d, previous)
    except (Exception, SystemExit) as exc:  # noqa: BLE001  (reported in the table, not raised)
        result.update(status="failed", error="train: " + _error_text(exc),
                      traceback=traceback.format_exc(limit=8))
        return _finish(d, result)
    old = (previous or {}).get("evaluations", {})
    same_policy = previous is not None and previous.get("train") == result["train"]
    if same_policy:  # evaluations of this policy that are not asked for now stay in the record
        result["evaluations"].update({k: v for k, v in old.items() if v.get("status") == "done"})
    cache: dict[str, Any] = {}
    for ev in evals:
        if same_policy and old.get(ev.eval_id, {}).get("status") == "done":
            continue
        # the record so far, status "running": a worker killed now loses only the evaluation in flight
        write_atomic(d / RESULT_FILE, result)
        try:
            result["evaluations"][ev.eval_id] = _evaluate(run, ev, result["train"], d, cache)
        except (Exception, SystemExit) as exc:  # noqa: BLE001
            result["evaluations"][ev.eval_id] = {"status": "failed", "error": "evaluate: " + _error_text(exc),
                                                 "setting": asdict(ev)}
    failed = [result["evaluations"][ev.eval_id]["error"] for ev in evals
              if result["evaluations"][ev.eval_id]["status"] != "done"]
    result.update(status="failed" if failed else "done", error=failed[0] if failed else None,
                  finished=_dt.datetime.now().isoformat(timespec="seconds"))
    return _finish(d, result)


def _finish(run_dir: Path, result: dict[str, Any]) -> dict[str, Any]:
    """Write ``result.json``, then drop the running marker (the run is no longer in flight)."""
    write_atomic(run_dir / RESULT_FILE, result)
    (run_dir / RUNNING_FILE).unlink(missing_ok=True)
    return result


# --------------------------------------------------------------------------------------------- local processes

def _ignore_sigint() -> None:
    """Worker initializer: Ctrl-C in a terminal reaches the whole process group; the driver alone answers it
    (by ending the workers), so that workers do not print a traceback each."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _terminate(pool: Any) -> None:
    """Cancel the queued runs and end the running ones now (their result files are never half written; their
    runs are retried by the next invocation)."""
    if hasattr(pool, "terminate_workers"):  # Python >= 3.14
        pool.terminate_workers()
        return
    # taken before shutdown, which forgets them (Python 3.11 sets ``_processes`` to None) and would otherwise
    # leave the running worker training until its run ends, and the exit waiting for it
    procs = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for proc in procs:
        proc.terminate()


def execute_local(tasks: dict[str, Task], workers: int, on_result: Callable[[str, dict[str, Any]], None],
                  runner: Callable[..., dict[str, Any]] = run_one) -> None:
    """Run ``tasks`` in ``workers`` local processes.

    Processes are started with ``spawn`` (a forked child of a process that has used torch's thread pool can
    hang). When a worker dies the pool breaks and every unfinished future fails with ``BrokenProcessPool``;
    runs that had started (their ``running.json`` exists) are reported killed, the others go to a fresh pool.

    :param tasks: ``run_id -> (run, evals, run_dir)``
    :param workers: processes at once
    :param on_result: called in this process with each run's id and result as it finishes
    :param runner: the function a worker calls with ``(run, evals, run_dir)``
    """
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    pending = dict(tasks)
    for _, _, run_dir in pending.values():
        (Path(run_dir) / RUNNING_FILE).unlink(missing_ok=True)  # stale marker of an earlier invocation
    while pending:
        pool = ProcessPoolExecutor(max_workers=max(1, min(workers, len(pending))), mp_context=mp.get_context("spawn"),
                                   initializer=_ignore_sigint)
        broken: list[str] = []
        try:
            futures = {pool.submit(runner, *task): rid for rid, task in pending.items()}
            waiting = set(futures)
            while waiting:
                # wake up now and then: a Ctrl-C delivered to one of the pool's threads is only acted on when the
                # main thread runs, which an unbounded wait would put off until a run finished
                done, waiting = wait(waiting, timeout=0.5, return_when=FIRST_COMPLETED)
                for fut in done:
                    rid = futures[fut]
                    try:
                        res = fut.result()
                    except BrokenProcessPool:
                        broken.append(rid)
                        continue
                    except Exception as exc:  # noqa: BLE001  e.g. a task that could not be pickled
                        res = new_result(pending[rid][0], "failed", _error_text(exc))
                    del pending[rid]
                    on_result(rid, res)
        except KeyboardInterrupt:
            _terminate(pool)
            raise
        pool.shutdown(wait=True)
        started = [rid for rid in broken if (Path(pending[rid][2]) / RUNNING_FILE).is_file()]
        lost = started or broken  # a pool that broke before any run started would break again
        for rid in lost:
            why = ("its worker process died (killed, out of memory or exited) while it ran; other runs in "
                   "flight in the same pool are stopped with it") if rid in started else \
                  "the process pool broke before this run started"
            on_result(rid, new_result(pending.pop(rid)[0], "killed", why))


# --------------------------------------------------------------------------------------------- Ray

def connect_ray(address: str, workers: int):
    """Import Ray and connect; an already initialised Ray is reused.

    :param address: ``"local"`` starts a Ray instance here; ``"auto"`` or an address joins a running cluster
    :param workers: CPUs of a ``"local"`` instance
    :returns: ``(ray module, whether this call started Ray)``
    :raises RuntimeError: Ray is not installed, or no cluster answers at ``address`` (the message says what to do)
    """
    try:
        import ray
    except ImportError:
        raise RuntimeError("--ray needs Ray: pip install 'softreach[sweep]' (or pip install 'ray>=2.9')") from None
    if ray.is_initialized():
        return ray, False
    try:
        if address == "local":
            # Ray starts its workers at niceness 15, below every other process: on a shared machine a sweep's runs
            # would get a small share of the CPU. They are the sweep's work: they run at the driver's priority
            ray.init(num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False,
                     _system_config={"worker_niceness": 0})
        else:
            ray.init(address=address, log_to_driver=False)
    except ConnectionError as exc:
        raise RuntimeError(f"no Ray cluster at --ray {address}: {exc} (start one with `ray start --head`, or use "
                           "--ray local for a Ray instance on this machine)") from None
    return ray, True


def execute_ray(tasks: dict[str, Task], address: str, workers: int,
                on_result: Callable[[str, dict[str, Any]], None],
                runner: Callable[..., dict[str, Any]] = run_one) -> None:
    """Run ``tasks`` as Ray tasks (one CPU each, no automatic retry: a rerun of the sweep retries).

    A task whose worker dies raises ``WorkerCrashedError`` (or another ``RayError``) here; the run is reported
    killed with that message. The output folder must be visible to every node at the same path (a shared file
    system); the driver also writes each returned ``result.json``, so the table is complete on the driver.

    :param tasks: ``run_id -> (run, evals, run_dir)``
    :param address: see :func:`connect_ray`
    :param workers: CPUs of a ``"local"`` Ray instance
    :param on_result: called here with each run's id and result as it finishes
    :param runner: the function a task calls with ``(run, evals, run_dir)``
    """
    ray, started_here = connect_ray(address, workers)
    from ray.exceptions import RayError, RayTaskError

    remote = ray.remote(num_cpus=1, max_retries=0)(runner)
    try:
        refs = {remote.remote(*task): rid for rid, task in tasks.items()}
        try:
            while refs:
                ready, _ = ray.wait(list(refs), num_returns=1)
                for ref in ready:
                    rid = refs.pop(ref)
                    try:
                        res = ray.get(ref)
                    except RayTaskError as exc:  # an exception that escaped run_one (should not happen)
                        res = new_result(tasks[rid][0], "failed", _error_text(exc.as_instanceof_cause()))
                    except RayError as exc:
                        res = new_result(tasks[rid][0], "killed", _error_text(exc).splitlines()[0])
                    on_result(rid, res)
        except KeyboardInterrupt:
            for ref in refs:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()


__all__ = ["RESULT_FILE", "RESULT_SCHEMA", "RUNNING_FILE", "connect_ray", "execute_local", "execute_ray",
           "is_done", "new_result", "read_result", "run_one", "write_atomic"]
