"""Speed and memory of the W_eps solve: softreach against hj_reachability on the same problem, in one run.

    python benchmarks/bench_solver.py --grid 101 101 --budget-points 111 --accuracy medium \
        [--peer-python /path/to/python-with-hj_reachability]

Both solve the point mass's soft-constrained reach-avoid game on the budget-augmented grid ``(v, y, z)``, from
``T = 1`` to ``t = 0``, with the same accuracy preset (derivative scheme and Runge-Kutta order), the same ``eps``,
``kappa`` and the same reach-avoid projection after every step. Each solver runs in its own subprocess, so the
peak resident memory it reports is its own. softreach is timed twice: cold (including ``torch.compile``) and warm
(the compiled kernels come from the on-disk cache). The peer is used if ``hj_reachability`` imports in this
interpreter (``pip install -e ".[peer]"``) or in ``--peer-python``; otherwise only softreach is timed.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time


def _soft_worker(args) -> dict:
    import numpy as np
    import torch

    from softreach.reach import Grid, SolverSettings, budget_axis, get_model, soft_problem, solve

    torch.set_num_threads(args.threads)
    model = get_model("pointmass")
    z_lo, z_hi, nz = budget_axis(model.horizon, args.budget_points)
    grid = Grid(model.domain[0] + (z_lo,), model.domain[1] + (z_hi,), tuple(args.grid) + (nz,))
    settings = SolverSettings.from_accuracy(args.accuracy, dtype="float32", compile=None if args.compile == "auto" else args.compile == "yes",
                                            device=args.device)
    t0 = time.perf_counter()
    W = solve(soft_problem(model, 1e-3, model.budget_scale), grid, [0.0, model.horizon], settings)
    if args.device.startswith("cuda"):
        torch.cuda.synchronize()
    wall = time.perf_counter() - t0
    W = W.cpu().numpy() if hasattr(W, "cpu") else np.asarray(W)
    return _result("softreach", wall, W, grid, model)


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

    grid = hj.Grid.from_lattice_parameters_and_boundary_conditions(
        hj.sets.Box(np.array(model.domain[0] + (z_lo,)), np.array(model.domain[1] + (z_hi,))), tuple(args.grid) + (nz,))
    v, y, z = (grid.states[..., i] for i in range(3))
    box = lambda lo, hi: jnp.maximum(jnp.maximum(lo[0] - v, v - hi[0]), jnp.maximum(lo[1] - y, y - hi[1]))
    g = box((p.target_speed[0], p.target_altitude[0]), (p.target_speed[1], p.target_altitude[1]))
    c1 = box((p.hard_speed[0], p.altitude[0]), (p.hard_speed[1], p.altitude[1]))
    c2 = box((p.soft_speed[0], p.altitude[0]), (p.soft_speed[1], p.altitude[1]))
    l = jnp.maximum(jnp.maximum(c2, -kappa * z), g)
    c = jnp.maximum(c1, -kappa * z)
    settings = hj.SolverSettings.with_accuracy(args.accuracy, value_postprocessor=lambda t, w: jnp.maximum(c, jnp.minimum(l, w)))
    t0 = time.perf_counter()
    W = hj.step(settings, Augmented(), grid, 0.0, jnp.maximum(c, l), -model.horizon, progress_bar=False)
    W = np.asarray(jax.block_until_ready(W))
    wall = time.perf_counter() - t0

    class G:  # the few grid facts _result needs
        spacing = tuple(float(s) for s in grid.spacings)
        shape = tuple(args.grid) + (nz,)
        lo = model.domain[0] + (z_lo,)

    return _result("hj_reachability", wall, W, G, model)


def _result(name, wall, W, grid, model) -> dict:
    import numpy as np

    dz = grid.spacing[2]
    iz0 = int(round(-grid.lo[2] / dz))
    cell = grid.spacing[0] * grid.spacing[1]
    half = 0.5 * (W[:, :, iz0] + W[:, :, iz0 + 1])  # W at z = dz/2, the RA~_0 rule of Table.set_mask
    return {"solver": name, "wall_s": wall, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "ra0_measure": float((half <= 0).sum() * cell), "raw_z0_measure": float((W[:, :, iz0] <= 0).sum() * cell),
            "finite": bool(np.isfinite(W).all())}


def _classical_measure(args) -> float:
    from softreach.reach import Grid, SolverSettings, classical_problem, get_model, solve
    import numpy as np

    model = get_model("pointmass")
    grid = Grid(model.domain[0], model.domain[1], tuple(args.grid))
    V = np.asarray(solve(classical_problem(model), grid, [0.0, 1.0], SolverSettings.from_accuracy(args.accuracy, dtype="float64", compile=False)))
    return float((V <= 0).sum() * grid.spacing[0] * grid.spacing[1])


def _problem(args) -> str:
    from softreach.reach import budget_axis, get_model

    model = get_model("pointmass")
    return json.dumps({"params": model.parameters(), "lo": list(model.domain[0]), "hi": list(model.domain[1]),
                       "horizon": model.horizon, "z": list(budget_axis(model.horizon, args.budget_points)),
                       "kappa": model.budget_scale})


def _run(worker: str, args, python: str) -> dict:
    cmd = [python, __file__, "--worker", worker, "--grid", *map(str, args.grid), "--budget-points", str(args.budget_points),
           "--accuracy", args.accuracy, "--threads", str(args.threads), "--compile", args.compile, "--device", args.device,
           "--problem", _problem(args)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{worker} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=int, nargs=2, default=[101, 101])
    ap.add_argument("--budget-points", type=int, default=111)
    ap.add_argument("--accuracy", default="medium", choices=["low", "medium", "high", "very_high"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--compile", default="auto", choices=["auto", "yes", "no"])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--peer-python", default=None, help="an interpreter where hj_reachability imports")
    ap.add_argument("--skip-peer", action="store_true")
    ap.add_argument("--worker", choices=["softreach", "peer"], help=argparse.SUPPRESS)
    ap.add_argument("--problem", default="{}", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker == "softreach":
        print(json.dumps(_soft_worker(args)))
        return
    if args.worker == "peer":
        print(json.dumps(_peer_worker(args)))
        return
    rows = [_run("softreach", args, sys.executable) | {"run": "cold"}, _run("softreach", args, sys.executable) | {"run": "warm"}]
    peer_python = args.peer_python
    if peer_python is None and not args.skip_peer:
        try:
            import hj_reachability  # noqa: F401

            peer_python = sys.executable
        except ImportError:
            pass
    if peer_python and not args.skip_peer:
        rows.append(_run("peer", args, peer_python) | {"run": "-"})
    ra = _classical_measure(args)
    print(f"point mass W_eps, grid {args.grid[0]}x{args.grid[1]}x{args.budget_points}, accuracy {args.accuracy}, "
          f"{args.threads} threads, device {args.device}; classical RA measure {ra:.2f}")
    print(f"{'solver':16s} {'run':5s} {'wall [s]':>9s} {'peak RSS [MB]':>14s} {'RA~_0 (dz/2)':>13s} {'raw z=0':>8s}")
    for r in rows:
        print(f"{r['solver']:16s} {r['run']:5s} {r['wall_s']:9.1f} {r['peak_rss_mb']:14.0f} {r['ra0_measure']:13.2f} {r['raw_z0_measure']:8.2f}")
    peer = [r for r in rows if r["solver"] == "hj_reachability"]
    if peer:
        print(f"speed-up vs hj_reachability: cold {peer[0]['wall_s'] / rows[0]['wall_s']:.2f}x, warm {peer[0]['wall_s'] / rows[1]['wall_s']:.2f}x")


if __name__ == "__main__":
    main()
