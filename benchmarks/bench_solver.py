"""Speed of the solver: softreach against hj_reachability on the same problem in one run, the memory bandwidth it
reaches, and how its cost grows with the grid.

    python benchmarks/bench_solver.py [--grid 101 101 --budget-points 111 --accuracy high] \
        [--peer-python /work/peer-venv/bin/python] [--threads 1 2] [--scaling] [--skip-peer]

The comparison: both solve the point mass's soft-constrained reach-avoid game ``W_eps`` on the budget-augmented
grid ``(v, y, z)`` from ``T = 1`` to ``t = 0`` with the same accuracy preset (derivative scheme and Runge-Kutta
order), ``eps``, ``kappa`` and reach-avoid projection after every stage. softreach is timed as the whole
``softreach solve`` process (interpreter start, imports, ``V`` and ``W_eps``, the table written), the peer for its
solve alone (its JIT compilation included). softreach runs first cold, with an empty kernel cache
(``SOFTREACH_CACHE`` in a fresh folder: the first solve on a machine), then warm from that cache, once per
``--threads`` value. The peer is used if ``hj_reachability`` imports in ``--peer-python`` (default
``$SOFTREACH_PEER_PYTHON``) or in this interpreter (``pip install -e ".[peer]"``); otherwise only softreach is timed.

Bandwidth: a stream copy of 256 MB arrays (numpy, one thread, the best of five) measures what the machine moves;
softreach's time stepping moves at least 32 bytes per node and Runge-Kutta stage in float32 (the rate loop reads
the padded value and writes the rate, 8 B; the stage loop reads the value, the padded value, the rate and both
obstacles and writes the padded value, 24 B), which over its stepping time is the bandwidth it reaches.

``--scaling``: wall clock (and the process's CPU time, which a loaded machine changes less) of the solve (in this
process, warm) against the grid size per axis for ``V`` (``N x N``) and ``W_eps`` (``N x N x N``), and the exponent
``p`` of the least-squares fit ``wall ~ N^p``. A CFL-limited explicit
scheme takes ``N`` steps of ``N^d`` nodes, so ``p`` is about ``d + 1`` once fixed costs no longer matter.

The machine's load (``os.getloadavg``) is printed beside each number: on a shared machine the wall clock of a run
depends on it.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: bytes a float32 node moves per Runge-Kutta stage at the least (module docstring)
BYTES_PER_NODE_STAGE = 32


def _load() -> str:
    return "{:.1f}".format(os.getloadavg()[0])


def stream_copy_gbs(mb: int = 256, repeats: int = 5) -> float:
    """GB/s of ``np.copyto`` between two ``mb`` MB float32 arrays, counting the bytes read and written, best of
    ``repeats``."""
    import numpy as np

    a = np.ones(mb * 2**20 // 4, np.float32)
    b = np.empty_like(a)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.copyto(b, a)
        best = min(best, time.perf_counter() - t0)
    return 2 * a.nbytes / best / 1e9


def device_copy_gbs(device: str, mb: int = 1024, repeats: int = 10) -> float:
    """GB/s of a device-to-device copy between two ``mb`` MB float32 tensors (bytes read and written), the mean of
    ``repeats`` after one warm-up: what the GPU's memory moves."""
    import torch

    a = torch.ones(mb * 2**20 // 4, device=device)
    b = torch.empty_like(a)
    b.copy_(a)
    torch.cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(repeats):
        b.copy_(a)
    torch.cuda.synchronize()
    return 2 * a.numel() * 4 * repeats / (time.perf_counter() - t0) / 1e9


def _soft_cli_worker(args) -> dict:
    """``softreach solve`` in this process, with the fused stepper's loops counted and timed."""
    from softreach.cli import main as cli_main
    from softreach.reach.numerics import fused

    stats = {"stages": 0, "nodes_stages": 0, "stepping_s": 0.0, "threads": None}
    FS = fused.FusedStepper

    def timed(original):
        def run(self, *a, **k):
            t0 = time.perf_counter()
            try:
                return original(self, *a, **k)
            finally:
                stats["stepping_s"] += time.perf_counter() - t0
        return run

    def counted(original):
        def run(self, *a, **k):
            stats["stages"] += 1
            stats["nodes_stages"] += self.u.size
            return original(self, *a, **k)
        return run

    FS.rate, FS.step, FS._rate = timed(FS.rate), timed(FS.step), counted(FS._rate)
    if args.device.startswith("cuda"):  # the GPU's kernels: a march is timed to its end on the device
        import torch

        from softreach.reach.numerics import gpu

        CS = gpu.CudaStepper

        def synced(original):
            def run(self, *a, **k):
                torch.cuda.synchronize()
                t0 = time.perf_counter()
                try:
                    return original(self, *a, **k)
                finally:
                    torch.cuda.synchronize()
                    stats["stepping_s"] += time.perf_counter() - t0
            return run

        def stages(original):
            def run(self, *a, **k):
                stats["stages"] += len(self._stages)
                stats["nodes_stages"] += len(self._stages) * self.u.numel()
                return original(self, *a, **k)
            return run

        CS.march, CS.step = synced(CS.march), stages(CS.step)
    out = Path(args.out)
    argv = ["solve", "pointmass", "--grid", *map(str, args.grid), "--budget-points", str(args.budget_points),
            "--accuracy", args.accuracy, "--device", args.device, "--out", str(out), "--json", str(out) + ".json",
            "--quiet", "--no-resume"]
    if args.threads_one is not None:
        argv += ["--threads", str(args.threads_one)]
    if args.game == "V":
        argv.append("--classical")
    rc = cli_main(argv)
    if rc:
        raise SystemExit(rc)
    summary = json.loads(Path(str(out) + ".json").read_text())
    stats["threads"] = summary.get("threads")
    if args.device.startswith("cuda"):  # what the solve's tensors held on the GPU at most (the CUDA context aside)
        import torch

        stats["gpu_peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
    return {"solver": "softreach", "summary": summary, **stats, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _peer_worker(args) -> dict:
    import jax
    import jax.numpy as jnp
    import hj_reachability as hj
    import numpy as np

    from types import SimpleNamespace

    # the peer's interpreter need not have softreach: the problem arrives as JSON from the orchestrator
    jax.config.update("jax_enable_x64", False)
    spec = json.loads(args.problem)
    p = SimpleNamespace(**spec["params"])
    model = SimpleNamespace(domain=(tuple(spec["lo"]), tuple(spec["hi"])), horizon=spec["horizon"])
    z_lo, z_hi, nz = spec["z"]
    kappa, eps = spec["kappa"], 1e-3

    class Augmented(hj.ControlAndDisturbanceAffineDynamics):
        def __init__(self):
            super().__init__(control_mode="min", disturbance_mode="max",
                             control_space=hj.sets.Box(jnp.array([-p.u_max]), jnp.array([p.u_max])),
                             disturbance_space=hj.sets.Box(jnp.array([-p.d_max]), jnp.array([p.d_max])))

        def open_loop_dynamics(self, state, time):
            v, y, _ = state
            c2 = jnp.maximum(jnp.maximum(p.soft_speed[0] - v, v - p.soft_speed[1]), jnp.maximum(p.altitude[0] - y, y - p.altitude[1]))
            return jnp.array([-p.gravity, v, -jnp.clip(c2 / eps, 0.0, 1.0)])

        def control_jacobian(self, state, time):
            return jnp.array([[1.0], [0.0], [0.0]])

        def disturbance_jacobian(self, state, time):
            return jnp.array([[1.0], [0.0], [0.0]])

    class Plain(hj.ControlAndDisturbanceAffineDynamics):  # the classical game on (v, y)
        def __init__(self):
            super().__init__(control_mode="min", disturbance_mode="max",
                             control_space=hj.sets.Box(jnp.array([-p.u_max]), jnp.array([p.u_max])),
                             disturbance_space=hj.sets.Box(jnp.array([-p.d_max]), jnp.array([p.d_max])))

        def open_loop_dynamics(self, state, time):
            return jnp.array([-p.gravity, state[0]])

        def control_jacobian(self, state, time):
            return jnp.array([[1.0], [0.0]])

        def disturbance_jacobian(self, state, time):
            return jnp.array([[1.0], [0.0]])

    classical = args.game == "V"
    lo, hi = model.domain[0] + (() if classical else (z_lo,)), model.domain[1] + (() if classical else (z_hi,))
    shape = tuple(args.grid) + (() if classical else (nz,))
    grid = hj.Grid.from_lattice_parameters_and_boundary_conditions(hj.sets.Box(np.array(lo), np.array(hi)), shape)
    v, y = grid.states[..., 0], grid.states[..., 1]
    box = lambda lo, hi: jnp.maximum(jnp.maximum(lo[0] - v, v - hi[0]), jnp.maximum(lo[1] - y, y - hi[1]))
    g = box((p.target_speed[0], p.target_altitude[0]), (p.target_speed[1], p.target_altitude[1]))
    c1 = box((p.hard_speed[0], p.altitude[0]), (p.hard_speed[1], p.altitude[1]))
    c2 = box((p.soft_speed[0], p.altitude[0]), (p.soft_speed[1], p.altitude[1]))
    if classical:
        l, c = g, jnp.maximum(c1, c2)
    else:
        z = grid.states[..., 2]
        l = jnp.maximum(jnp.maximum(c2, -kappa * z), g)
        c = jnp.maximum(c1, -kappa * z)
    settings = hj.SolverSettings.with_accuracy(args.accuracy, value_postprocessor=lambda t, w: jnp.maximum(c, jnp.minimum(l, w)))
    t0 = time.perf_counter()
    W = hj.step(settings, Plain() if classical else Augmented(), grid, 0.0, jnp.maximum(c, l), -model.horizon,
                progress_bar=False)
    W = np.asarray(jax.block_until_ready(W))
    wall = time.perf_counter() - t0
    if classical:
        cell = float(grid.spacings[0] * grid.spacings[1])
        return {"solver": "hj_reachability", "wall_s": wall, "device": str(jax.devices()[0]),
                "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                "classical_measure": float((W <= 0).sum() * cell), "finite": bool(np.isfinite(W).all())}

    class G:  # the few grid facts _result needs
        spacing = tuple(float(s) for s in grid.spacings)
        shape = tuple(args.grid) + (nz,)
        lo = model.domain[0] + (z_lo,)

    return _result("hj_reachability", wall, W, G, model) | {"device": str(jax.devices()[0])}


def _result(name, wall, W, grid, model) -> dict:
    import numpy as np

    dz = grid.spacing[2]
    iz0 = int(round(-grid.lo[2] / dz))
    cell = grid.spacing[0] * grid.spacing[1]
    half = 0.5 * (W[:, :, iz0] + W[:, :, iz0 + 1])  # W at z = dz/2, the RA~_0 rule of Table.set_mask
    return {"solver": name, "wall_s": wall, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "ra0_measure": float((half <= 0).sum() * cell), "raw_z0_measure": float((W[:, :, iz0] <= 0).sum() * cell),
            "finite": bool(np.isfinite(W).all())}




def _problem(args) -> str:
    from softreach.reach import budget_axis, get_model

    model = get_model("pointmass")
    return json.dumps({"params": model.parameters(), "lo": list(model.domain[0]), "hi": list(model.domain[1]),
                       "horizon": model.horizon, "z": list(budget_axis(model.horizon, args.budget_points)),
                       "kappa": model.budget_scale})


def _run(worker: str, args, python: str, env: dict | None = None, threads: int | None = None) -> dict:
    """``worker`` in a fresh process; its JSON line, with ``process_s`` the wall clock of the whole process."""
    cmd = [python, __file__, "--worker", worker, "--grid", *map(str, args.grid), "--budget-points",
           str(args.budget_points), "--accuracy", args.accuracy, "--device", args.device, "--game", args.game,
           "--problem", _problem(args), "--out", args.out]
    if threads is not None:
        cmd += ["--threads-one", str(threads)]
    load = _load()
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **(env or {})})
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{worker} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1]) | {"process_s": wall, "load": load}


def _peer_python(args) -> str | None:
    if args.skip_peer:
        return None
    if args.peer_python:
        return args.peer_python
    try:
        import hj_reachability  # noqa: F401

        return sys.executable
    except ImportError:
        return None


def compare(args) -> None:
    """softreach cold and warm (per thread count) and the peer, one problem, one run."""
    peer_python = _peer_python(args)
    rows = []
    with tempfile.TemporaryDirectory(prefix="softreach-bench-") as tmp:
        args.out = str(Path(tmp) / "bench.srt")
        # the kernel caches (ours, inductor's inside it, Triton's), empty unless --cache-dir names a used folder:
        # the cold run is then the first solve on a machine
        cache = Path(args.cache_dir or tmp)
        env = {"SOFTREACH_CACHE": str(cache / "cache"), "TRITON_CACHE_DIR": str(cache / "triton")}
        if not args.no_cold:
            rows.append(_run("softreach", args, sys.executable, env, args.threads[0]) | {"run": "cold"})
        for th in args.threads:
            rows.append(_run("softreach", args, sys.executable, env, th) | {"run": "warm"})
        if peer_python:
            rows.append(_run("peer", args, peer_python) | {"run": "-"})
    # measured after the solvers: a child process reports the parent's peak memory as its own floor
    if args.device.startswith("cuda"):
        gbs = device_copy_gbs(args.device)
        print(f"device copy (torch, {args.device}): {gbs:.1f} GB/s (load {_load()})")
    else:
        gbs = stream_copy_gbs()
        print(f"stream copy (numpy, 1 thread): {gbs:.1f} GB/s (load {_load()})")
    what = "V" if args.game == "V" else "W_eps"
    print(f"point mass {what}, grid {'x'.join(map(str, args.grid))}{'' if args.game == 'V' else 'x' + str(args.budget_points)}, "
          f"accuracy {args.accuracy}, device {args.device}")
    print(f"{'solver':16s} {'run':5s} {'threads':>7s} {'process [s]':>11s} {'solve [s]':>9s} {'stepping [s]':>12s} "
          f"{'GB/s':>6s} {'of copy':>7s} {'RSS [MB]':>8s} {'RA~_0':>7s} {'RA (V)':>7s} {'load':>5s}")
    for r in rows:
        if r["solver"] == "softreach":
            s = r["summary"]
            solve_s = sum(s["wall_time_s"].values())
            bw = BYTES_PER_NODE_STAGE * r["nodes_stages"] / max(r["stepping_s"], 1e-9) / 1e9
            ra0 = s["soft_measure"][0] if "soft_measure" in s else float("nan")
            bws = f"{bw:6.1f} {bw / gbs:7.0%}" if r["stages"] else f"{'-':>6s} {'-':>7s}"  # the array code ran
            print(f"{'softreach':16s} {r['run']:5s} {r['threads']!s:>7s} {r['process_s']:11.1f} {solve_s:9.1f} "
                  f"{r['stepping_s']:12.1f} {bws} {r['peak_rss_mb']:8.0f} {ra0:7.2f} "
                  f"{s['classical_measure']:7.2f} {r['load']:>5s}"
                  + (f"  GPU peak {r['gpu_peak_mb']:.0f} MiB" if "gpu_peak_mb" in r else ""))
        else:
            print(f"{'hj_reachability':16s} {'-':5s} {'-':>7s} {r['process_s']:11.1f} {r['wall_s']:9.1f} {'-':>12s} "
                  f"{'-':>6s} {'-':>7s} {r['peak_rss_mb']:8.0f} {r.get('ra0_measure', float('nan')):7.2f} "
                  f"{r.get('classical_measure', float('nan')):7.2f} {r['load']:>5s}  ({r['device']})")
    peer = [r for r in rows if r["solver"] == "hj_reachability"]
    if peer:
        for r in rows[:-1]:
            print(f"speed-up, softreach {r['run']} ({r['threads']} threads) whole process vs the peer's solve: "
                  f"{peer[0]['wall_s'] / r['process_s']:.2f}x")
        s = [r for r in rows if r["solver"] == "softreach"][-1]["summary"]
        cell = (40.0 / (args.grid[0] - 1)) * (25.0 / (args.grid[1] - 1))
        mine, theirs = (s["soft_measure"][0], peer[0]["ra0_measure"]) if args.game == "W" else (
            s["classical_measure"], peer[0]["classical_measure"])
        print(f"set measure softreach {mine:.2f} vs peer {theirs:.2f}: {abs(mine - theirs) / cell:.1f} cells apart")


def scaling(args) -> None:
    """Wall clock of the warm solve against the grid size per axis, and the fitted exponent."""
    import numpy as np
    import torch

    from softreach.reach import Grid, SolverSettings, budget_axis, classical_problem, get_model, soft_problem, solve

    if args.threads_one is not None:
        torch.set_num_threads(args.threads_one)
    model = get_model("pointmass")
    st = SolverSettings.from_accuracy(args.accuracy, dtype="float32", compile=True)
    for name, sizes in (("V", args.v_sizes), ("W_eps", args.w_sizes)):
        walls, cpus = [], []
        print(f"{name}: wall clock of the solve against N (accuracy {args.accuracy}, {torch.get_num_threads()} threads)")
        for n in sizes:
            if name == "V":
                grid, problem = Grid(model.domain[0], model.domain[1], (n, n)), classical_problem(model)
            else:
                z_lo, z_hi, nz = budget_axis(model.horizon, n)
                grid = Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), (n, n, nz))
                problem = soft_problem(model, 1e-3, model.budget_scale)
            solve(problem, grid, [model.horizon - 0.01, model.horizon], st)  # compiled loops loaded, caches warm
            load = _load()
            t0, c0 = time.perf_counter(), time.process_time()
            solve(problem, grid, [0.0, model.horizon], st)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            print(f"  N = {n:4d}: {grid.size:>11,d} nodes  wall {walls[-1]:8.2f} s  CPU {cpus[-1]:8.2f} s  "
                  f"(load {load})")
        for what, ys in (("wall", walls), ("CPU", cpus)):
            p = np.polyfit(np.log(sizes), np.log(ys), 1)[0]
            q = np.polyfit(np.log(sizes[-2:]), np.log(ys[-2:]), 1)[0] if len(sizes) > 2 else p
            print(f"  fit {what} ~ N^p: p = {p:.2f} over all sizes, {q:.2f} over the two largest "
                  f"(a CFL-limited scheme: about {2 if name == 'V' else 3} + 1)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=int, nargs=2, default=[101, 101])
    ap.add_argument("--budget-points", type=int, default=111)
    ap.add_argument("--accuracy", default="high", choices=["low", "medium", "high", "very_high"])
    ap.add_argument("--game", default="W", choices=["W", "V"], help="W_eps on (v, y, z), or the classical V on (v, y)")
    ap.add_argument("--threads", type=int, nargs="+", default=[2, 1], help="softreach's warm runs, one per count")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--peer-python", default=os.environ.get("SOFTREACH_PEER_PYTHON"),
                    help="an interpreter where hj_reachability imports (default $SOFTREACH_PEER_PYTHON)")
    ap.add_argument("--skip-peer", action="store_true")
    ap.add_argument("--no-cold", action="store_true", help="no cold run of softreach")
    ap.add_argument("--cache-dir", default=None,
                    help="the kernel caches' folder, kept between runs of this script (default: a fresh one)")
    ap.add_argument("--scaling", action="store_true", help="wall clock against the grid size instead")
    ap.add_argument("--v-sizes", type=int, nargs="+", default=[51, 101, 201, 301])
    ap.add_argument("--w-sizes", type=int, nargs="+", default=[31, 51, 81, 101])
    ap.add_argument("--worker", choices=["softreach", "peer"], help=argparse.SUPPRESS)
    ap.add_argument("--problem", default="{}", help=argparse.SUPPRESS)
    ap.add_argument("--out", default="bench.srt", help=argparse.SUPPRESS)
    ap.add_argument("--threads-one", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker == "softreach":
        print(json.dumps(_soft_cli_worker(args)))
    elif args.worker == "peer":
        print(json.dumps(_peer_worker(args)))
    elif args.scaling:
        args.threads_one = args.threads[0]
        scaling(args)
    else:
        compare(args)


if __name__ == "__main__":
    main()
