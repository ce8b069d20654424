"""Latency of the safety filter, and a closed-loop comparison of its two rules.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/bench_filter.py [--table pointmass.srt] [--repeats 5] [--json out.json]
                                                        [--skip-eval]

Without ``--table`` a 61 x 61 x 45 point-mass table is solved first (a few seconds; the one the soundness tests
use). Each latency is the mean time per call over many calls, on fixed random inputs drawn beforehand, in
``--repeats`` runs:

* **single query** — ``ValueFilter.filter(t, x, z, action)`` for one state (numpy in and out, switch rule): the call a
  ``SafetyFilter.step`` makes. Target (issue 37): under 20 us. Once over the random states, once over those of them
  the filter certifies (before the last 0.1 s), where a deployed policy spends its steps. Of the latter, the
  compiled decision with its one-row buffers written, without the API's checks and ``info``
  (``switch_single_certified_decision_us``: ``CompiledDecision.one``), the compiled call of the last row again
  (``switch_single_compiled_call_us``) and numba's unboxing of its arguments alone (``switch_single_unboxing_us``:
  a compiled function that returns at once, handed them).
* **batch of 1,024** — the same call on ``(1024, n)`` states (numpy). Target: under 1 ms. Once over the random
  states (most of them outside the sets, where the filter searches the candidates), once over certified ones; and
  both again for the actions alone (``diagnostics=False``: ``info["value"]`` and a passing action's
  ``info["lookahead"]`` left out).
* the same for the smooth rule, for torch tensors (CPU) in and out, for a second filter of the same table
  (``compiled_*``), also for batches of 16 and 128 certified rows; in the calling thread
  alone (``one_thread_*``: ``ValueFilter.threads = 1``) beside the default threads, at 256, 512 and 1,024 rows,
  where a batch is cut into blocks for them; and, for scale, the ``Table`` API calls the filter replaces
  (``Table.value`` + ``Table.optimal_control``).
* **a row by what the decision finds** (``one_thread_row_*``, in one thread, per row): the rows of both batches of
  1,024 where the policy's action passes, where a certified action replaces it, and where nothing is certified,
  each kind decided as one batch; and for the last, the one-period tests alone of the policy's action and of every
  candidate (``one_thread_row_uncertified_tests_only_us``), the least such a row costs while the filter searches
  for the least bad action there.

Then one ``step`` of ``PointMassLanding-v0``, bare and in ``SafetyFilter``: what the filter adds to a training step;
and the filter's decisions inside that loop, one by one (the caches as a training loop leaves them).

Each figure is given as the best and the median wall-clock time over the runs and the median CPU time of the
process (on a machine shared with other jobs the wall clock includes their time slices; CPU time does not).

States are drawn over the hard-constraint box, budgets in ``[0, 0.6]`` and times in ``[0, 0.9]``, so that the mix
of passes and interventions is a realistic one.

Evaluation (``--skip-eval`` to leave it out): a uniformly random policy, filtered by each rule, from the grid nodes
with ``W_eps(0, x, Q) <= -margin`` for ``Q`` in ``{0.06, 0.3, 0.6}``, under the table's adversarial wind, a random
switching wind and the two constant extremes (``reach.sim.simulate.rollout``, dt = 0.01 s). Reported per rule: the
share of runs that land, that leave ``C1`` and that overspend (budget used above ``Q + dt``), the intervention rate
(steps where the applied action differs from the policy's) and the mean ``|applied - policy|`` [m/s^2]; and, for
reference, the same policy without a filter.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from softreach.filters import ValueFilter
from softreach.reach import SolveConfig, SolverSettings, get_model, load_table, solve_table
from softreach.reach.jit import entry_point
from softreach.reach.sim.simulate import constant, random_switching, rollout, table_disturbance

DT = 0.01


def _per_call(fn, calls: int, repeats: int) -> dict[str, float]:
    """Seconds per call: the best and the median over ``repeats`` runs of ``calls`` calls (after one warm-up
    call), in wall-clock time, and the median CPU time of this process (which other workers on a shared
    machine do not inflate)."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(calls):
            fn()
        wall.append((time.perf_counter() - t0) / calls)
        cpu.append((time.process_time() - c0) / calls)
    return {"wall_best": min(wall), "wall_median": statistics.median(wall), "cpu_median": statistics.median(cpu)}


def _one_row_calls(vf) -> tuple:
    """The compiled call of ``vf``'s one-row decisions (:meth:`CompiledDecision.one`; its last row decided again),
    and a compiled function that returns at once, handed the same arguments: what numba's unboxing of them costs."""
    calls = list(vf.compiled._local.row.calls.values())
    assert len(calls) == 1, "one kind of one-row call expected"
    run, args = calls[0]
    names = ", ".join(f"a{i}" for i in range(len(args)))
    space: dict = {}
    exec(f"def nothing({names}):\n    return 0", space)
    # without numba's reference counting, as the decision is compiled
    nothing = numba.njit(_nrt=False)(space["nothing"])
    nothing(*args)
    unbox = entry_point(nothing, args)
    return (lambda: run(*args)), (lambda: unbox(*args))


def latency(table, repeats: int) -> dict[str, dict[str, float]]:
    """Microseconds per call of the filter and of the Table API it replaces."""
    rng = np.random.default_rng(0)
    n = 1024
    x = np.c_[rng.uniform(-15, 15, n), rng.uniform(0, 18, n)]
    z = rng.uniform(0, 0.6, n)
    t = rng.uniform(0, 0.9, n)
    a = rng.uniform(-60, 60, (n, 1))
    switch = ValueFilter(table, DT)
    smooth = ValueFilter(table, DT, rule="smooth")
    # a second filter of the same table, at every batch size
    compiled_only = ValueFilter(table, DT)
    # and in the calling thread alone (ValueFilter.threads = 1), beside the default threads
    one_thread = ValueFilter(table, DT)
    one_thread.threads = 1
    # a single query cycles through the drawn states so that caches do not flatter it
    singles = [(float(t[i]), x[i].copy(), float(z[i]), a[i].copy()) for i in range(256)]

    # the states the guarantee covers: certified ones, before the last 0.1 s
    cert, _, _ = switch.certify(np.round(t * 0.94, 2), x, z)
    inside = [(round(float(t[i]) * 0.94, 2), x[i].copy(), float(z[i]), a[i].copy()) for i in np.nonzero(cert)[0][:256]]
    # a batch of 1,024 of them (repeated as needed), as a vector of environments running certified episodes asks
    rows = np.resize(np.nonzero(cert)[0], n)
    cert_batch = (np.round(t[rows] * 0.94, 2), x[rows], z[rows], a[rows])

    def single_from(vf, queries, method="filter"):
        it = iter(())
        decide = getattr(vf, method)

        def call():
            nonlocal it
            try:
                args = next(it)
            except StopIteration:
                it = iter(queries)
                args = next(it)
            decide(*args)
        return call

    def single(vf):
        return single_from(vf, singles)

    out = {
        "switch_single_us": _per_call(single(switch), 300, repeats),
        "switch_single_certified_us": _per_call(single_from(switch, inside), 300, repeats),
        # of which the compiled decision with its one-row buffers written, without the API's checks and info
        "switch_single_certified_decision_us": _per_call(single_from(switch.compiled, [
            (*q, False, None, True) for q in inside], method="one"), 300, repeats),
        # the compiled call of the last row again, and numba's unboxing of its arguments alone
        **dict(zip(("switch_single_compiled_call_us", "switch_single_unboxing_us"),
                   (_per_call(f, 300, repeats) for f in _one_row_calls(switch)))),
        "switch_batch1024_us": _per_call(lambda: switch.filter(t, x, z, a), 5, repeats),
        "switch_batch1024_certified_us": _per_call(lambda: switch.filter(*cert_batch), 5, repeats),
        # the actions alone (diagnostics=False: no certificate at the state, no next one for a passing action)
        "switch_batch1024_actions_only_us": _per_call(lambda: switch.filter(t, x, z, a, diagnostics=False), 5,
                                                      repeats),
        "switch_batch1024_certified_actions_only_us": _per_call(
            lambda: switch.filter(*cert_batch, diagnostics=False), 5, repeats),
        "compiled_switch_batch1024_us": _per_call(lambda: compiled_only.filter(t, x, z, a), 5, repeats),
        "compiled_switch_batch1024_certified_us": _per_call(lambda: compiled_only.filter(*cert_batch), 5, repeats),
        **{f"compiled_switch_batch{k}_certified_us": _per_call(
            lambda k=k: compiled_only.filter(*(v[:k] for v in cert_batch)), max(5, 2048 // k), repeats)
           for k in (16, 128)},
        # threads: the default against one, where the batch is cut (ValueFilter.threads, PARALLEL_MIN_ROWS)
        **{f"{kind}_switch_batch{k}_certified_us": _per_call(lambda vf=vf, k=k: vf.filter(*(v[:k] for v in cert_batch)),
                                                             max(5, 2048 // k), repeats)
           for k in (256, 512) for kind, vf in (("default_threads", switch), ("one_thread", one_thread))},
        "one_thread_switch_batch1024_certified_us": _per_call(lambda: one_thread.filter(*cert_batch), 5, repeats),
        "one_thread_switch_batch1024_certified_actions_only_us": _per_call(
            lambda: one_thread.filter(*cert_batch, diagnostics=False), 5, repeats),
        "one_thread_switch_batch1024_us": _per_call(lambda: one_thread.filter(t, x, z, a), 5, repeats),
        "smooth_single_us": _per_call(single(smooth), 100, repeats),
        "smooth_batch1024_us": _per_call(lambda: smooth.filter(t, x, z, a), 2, repeats),
        "table_api_single_us": _per_call(lambda: (table.value(t[:1], x[:1], z[:1]),
                                                  table.optimal_control(t[:1], x[:1], z[:1])), 300, repeats),
        "table_api_batch1024_us": _per_call(lambda: (table.value(t, x, z), table.optimal_control(t, x, z)),
                                            20, repeats),
    }
    # what a row costs by what the decision finds there, in one thread: the rows of the random and the certified
    # batch where the policy's action passes, where it is replaced by a certified one, and where nothing is
    # certified (per row: the time of the batch of those rows over their number)
    kinds = {"passing": [], "replaced_certified": [], "uncertified": []}
    for bt, bx, bz, ba in ((t, x, z, a), cert_batch):
        _, info = one_thread.filter(bt, bx, bz, ba)
        for kind, rows_k in (("passing", ~info["active"]), ("replaced_certified", info["active"] & info["certified"]),
                             ("uncertified", ~info["certified"])):
            kinds[kind].append(tuple(v[rows_k] for v in (bt, bx, bz, ba)))
    for kind, parts in kinds.items():
        rows_k = tuple(np.concatenate(v) for v in zip(*parts))
        if len(rows_k[0]):
            per = _per_call(lambda r=rows_k: one_thread.filter(*r), 5, repeats)
            out[f"one_thread_row_{kind}_us"] = {k: v / len(rows_k[0]) for k, v in per.items()}
            if kind == "uncertified":
                # the least such a row can cost while the decision asks what it does there: the one-period
                # tests of the policy's action and of every candidate, and nothing else
                tests = _one_period_tests(one_thread.compiled, *rows_k)
                per = _per_call(tests, 5, repeats)
                out["one_thread_row_uncertified_tests_only_us"] = {k: v / len(rows_k[0]) for k, v in per.items()}
    try:
        import torch

        tt, xx, zz, aa = (torch.tensor(v, dtype=torch.float32) for v in (t, x, z, a / 60.0))
        out["switch_batch1024_torch_cpu_us"] = _per_call(lambda: switch.filter(tt, xx, zz, aa, normalized=True),
                                                         5, repeats)
    except ImportError:  # pragma: no cover
        pass
    return {k: {kind: v * 1e6 for kind, v in d.items()} for k, d in out.items()}


def _one_period_tests(decision, t, x, z, pol):
    """A call that runs, row by row in one thread, only the one-period tests (``filters.judge.judge``, no table
    read) that the compiled decision ``decision`` makes of the policy's action and of every candidate at each row:
    a lower bound of a row's cost where neither passes."""
    import numba as nb

    from softreach.filters.compiled import decision_space
    from softreach.filters.judge import judge

    @nb.njit(_nrt=False)
    def run(enclose, M, C, cands, t, x, z, pol, work, end_lo, end_hi, act):
        passed = 0
        for r in range(x.shape[0]):
            for s in range(cands.shape[0] + 1):
                for i in range(act.shape[0]):
                    act[i] = pol[r, i] if s == 0 else cands[s - 1, i]
                passed += judge(enclose, M, C, t[r], x[r], x[r], z[r], act, end_lo[s], end_hi[s], work)[0]
        return passed

    J, m = decision.cands.shape
    space = decision_space(x.shape[1], m, J)[0]
    args = (decision.enclose, decision.M, decision.C, decision.cands,
            *(np.ascontiguousarray(v, dtype=np.float64) for v in (t, x, z, pol)), space.work, space.end_lo,
            space.end_hi, space.act)
    return lambda: run(*args)


def env_steps(table, repeats: int, steps: int = 3000) -> dict[str, float]:
    """Microseconds per ``step`` of ``PointMassLanding-v0`` with uniformly random actions (resets included), bare
    and wrapped in :class:`SafetyFilter` with a filter on ``table``: what the filter adds to a training step. The
    best of ``repeats`` runs, taken round robin. Inside the filtered runs, the median of the filter's decisions
    (``ValueFilter.filter``, the call ``SafetyFilter.step`` makes), timed one by one where the policy's action passed
    and where it did not: between two decisions the environment's own step runs, so they start from the caches a
    training loop leaves them, unlike the single queries above."""
    import gymnasium as gym

    import softreach.envs  # noqa: F401  (registers the ids)
    from softreach.filters import PASS, SafetyFilter

    def make(filtered: bool):
        env = gym.make("softreach/PointMassLanding-v0")
        return SafetyFilter(env, table) if filtered else env

    envs = {"env_step_us": make(False), "safety_filter_step_us": make(True)}
    vf = envs["safety_filter_step_us"].value_filter
    decide = vf.filter
    times: dict[bool, list[float]] = {True: [], False: []}

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        out = decide(*args, **kwargs)
        elapsed = time.perf_counter() - t0
        times[bool(out[1]["reason"] == PASS)].append(elapsed)
        return out

    actions = np.random.default_rng(0).uniform(-1, 1, (steps, 1)).astype(np.float32)

    def run(env) -> float:
        """Microseconds per step of one run of the random policy's actions from ``reset(seed=0)``."""
        env.reset(seed=0)
        t0 = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        return (time.perf_counter() - t0) / steps * 1e6

    best = {k: float("inf") for k in envs}
    for _ in range(repeats):
        for key, env in envs.items():
            best[key] = min(best[key], run(env))
    # the decisions timed in runs of their own, so that the timer adds nothing to the steps above
    vf.filter = timed
    try:
        for _ in range(repeats):
            run(envs["safety_filter_step_us"])
    finally:
        del vf.filter
    for passed, key in ((True, "decision_in_loop_pass_us"), (False, "decision_in_loop_other_us")):
        best[key] = statistics.median(times[passed]) * 1e6 if times[passed] else float("nan")
    return best


def evaluate(table) -> dict:
    """Closed-loop comparison of the two rules (and no filter) with a random policy."""
    model = table.model
    g = table.grid("V")
    V, Y = np.meshgrid(g.axis(0), g.axis(1), indexing="ij")
    xs = np.c_[V.ravel(), Y.ravel()]
    filters = {"switch": ValueFilter(table, DT), "smooth": ValueFilter(table, DT, rule="smooth")}
    winds = {"adversarial": lambda: table_disturbance(table),
             "switching": lambda: random_switching(model, seed=3, hold=0.05),
             "up": lambda: constant([model.params.d_max]), "down": lambda: constant([-model.params.d_max])}
    rows = []
    for q in (0.06, 0.3, 0.6):
        ref = filters["switch"]
        starts = xs[ref.value(0.0, xs, q) <= -(ref.constant_margin or 0.0)]
        for wname, wind in winds.items():
            for rule in ("none", "switch", "smooth"):
                rng = np.random.default_rng(1)
                log = {"active": 0, "steps": 0, "moved": 0.0}

                def control(tq, x, zq, rule=rule, rng=rng, log=log):
                    pol = rng.uniform(-60, 60, (len(x), 1))
                    if rule == "none":
                        return pol
                    plan = log.get("plan")
                    plan = plan if plan is not None and len(plan) == len(x) else None
                    applied, info = filters[rule].filter(tq, x, zq, pol, plan=plan)
                    log["plan"] = info["plan"]
                    log["active"] += int(info["active"].sum())
                    log["steps"] += len(x)
                    log["moved"] += float(np.abs(applied - pol).sum())
                    return applied

                r = rollout(model, starts, q, control, wind(), dt=DT, eps=table.eps)
                rows.append({"Q": q, "wind": wname, "rule": rule, "starts": len(starts),
                             "landed": float(r.landed.mean()), "hard_violation": float(r.hard_violation.mean()),
                             "overspent": float((r.budget_used > q + DT).mean()),
                             "intervention_rate": log["active"] / log["steps"] if log["steps"] else 0.0,
                             "mean_abs_change": log["moved"] / log["steps"] if log["steps"] else 0.0})
    return {"rows": rows}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--table", help="a point-mass W_eps table (default: solve a 61 x 61 x 45 one)")
    parser.add_argument("--repeats", type=int, default=5, help="timing runs per figure; the median is kept")
    parser.add_argument("--skip-eval", action="store_true", help="latency only")
    parser.add_argument("--json", help="write the results to this JSON file")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as tmp:
        if args.table:
            path = Path(args.table)
        else:
            path = Path(tmp) / "pointmass_61.srt"
            cfg = SolveConfig(shape=(61, 61), budget_points=45, snapshots=11,
                              settings=SolverSettings.from_accuracy("medium", dtype="float32", compile=False))
            t0 = time.perf_counter()
            solve_table(get_model("pointmass"), cfg, path, progress=False)
            print(f"solved {path.name} in {time.perf_counter() - t0:.1f} s")
        table = load_table(path)
        t0 = time.perf_counter()
        vf = ValueFilter(table, DT)
        build = time.perf_counter() - t0
        # the first decision of a process loads the compiled kernels from numba's disk cache (compiles them where
        # there is none yet: once per installation)
        t0 = time.perf_counter()
        vf.filter(0.0, np.array([0.0, 5.0]), 0.3, np.array([0.0]))
        first = time.perf_counter() - t0
        results: dict = {
            "machine": {"python": platform.python_version(), "processor": platform.processor(),
                        "cpu_count": os.cpu_count(), "numpy": np.__version__,
                        "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS")},
            "table": {"grid": table.grid("W_eps").to_dict(), "snapshots": len(table.times())},
            "filter_construction_s": build,
            "first_decision_s": first,
            "table_control_period": table.control_period,
        }
        print(f"filter construction: {build * 1e3:.0f} ms; first decision: {first * 1e3:.0f} ms")
        lat = latency(table, args.repeats)
        results["latency_us"] = lat
        results["env_step_us"] = steps = env_steps(table, args.repeats)
        print(f"PointMassLanding-v0 step: {steps['env_step_us']:.1f} us bare, {steps['safety_filter_step_us']:.1f} us "
              f"in SafetyFilter (random actions, resets included; best of {args.repeats}); its decisions there "
              f"{steps['decision_in_loop_pass_us']:.1f} us where the policy's action passed, "
              f"{steps['decision_in_loop_other_us']:.1f} us where not (medians)")
        print(f"{'latency [us]':32s} {'wall best':>10s} {'wall median':>12s} {'cpu median':>11s}")
        for k, v in lat.items():
            print(f"{k:32s} {v['wall_best']:10.1f} {v['wall_median']:12.1f} {v['cpu_median']:11.1f}")
        print("targets (wall median / best): single query < 20 us: " + ", ".join(
                  f"{kind} {lat[key]['wall_median'] < 20} / {lat[key]['wall_best'] < 20}" for kind, key in (
                      ("random", "switch_single_us"), ("certified", "switch_single_certified_us")))
              + "; batch of 1,024 < 1 ms: " + ", ".join(
                  f"{kind} {lat[key]['wall_median'] < 1000} / {lat[key]['wall_best'] < 1000}" for kind, key in (
                      ("random", "switch_batch1024_us"), ("certified", "switch_batch1024_certified_us"),
                      ("random actions only", "switch_batch1024_actions_only_us"),
                      ("certified actions only", "switch_batch1024_certified_actions_only_us"))))
        if not args.skip_eval:
            ev = evaluate(table)
            results["evaluation"] = ev
            print(f"{'Q':>5s} {'wind':12s} {'rule':7s} {'starts':>6s} {'landed':>7s} {'hard':>6s} {'overspent':>9s} "
                  f"{'interv.':>8s} {'|da|':>7s}")
            for r in ev["rows"]:
                print(f"{r['Q']:5.2f} {r['wind']:12s} {r['rule']:7s} {r['starts']:6d} {r['landed']:7.3f} "
                      f"{r['hard_violation']:6.3f} {r['overspent']:9.3f} {r['intervention_rate']:8.3f} "
                      f"{r['mean_abs_change']:7.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(results, fh, indent=2)
    return results


if __name__ == "__main__":
    main()
