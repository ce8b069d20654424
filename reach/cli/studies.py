"""The paper's convergence studies for the point mass: grid (Fig. 2) and eps (Fig. 3).

Not part of CI (each runs several solves); ``softreach study grid-convergence`` / ``eps-convergence`` prints the table
that the README reports. Every solve goes to its own table file in ``workdir`` and is reused (or resumed) by a
later run.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..numerics.compute import SolveConfig, solve_table
from ..models import get_model
from ..tables.query import load_table
from ..numerics.solver import SolverSettings

#: normalisation of the paper's Fig. 2: the domain's extents (40 m/s, 25 m)
NORMALISE = (40.0, 25.0)


def _solve(model, shape, budget_points, eps, accuracy, path: Path, classical_only=False):
    if not path.exists():
        cfg = SolveConfig(shape=shape, budget_points=budget_points, eps=eps, snapshots=2, classical_only=classical_only,
                          settings=SolverSettings.from_accuracy(accuracy, dtype="float32"))
        solve_table(model, cfg, path, progress=True)
    return load_table(path, verify_checksum=False)


def _zero_contour(axes: Sequence[np.ndarray], field: np.ndarray) -> list[np.ndarray]:
    """Polylines of the zero level of ``field`` on the grid (normalised units), by marching squares."""
    import contourpy

    gen = contourpy.contour_generator(axes[0] / NORMALISE[0], axes[1] / NORMALISE[1], field.T)
    return [line for line in gen.lines(0.0) if len(line) > 1]


def _sample_on(lines: list[np.ndarray], n: int, rng: np.random.Generator) -> np.ndarray:
    seg_a = np.concatenate([l[:-1] for l in lines])
    seg_b = np.concatenate([l[1:] for l in lines])
    length = np.linalg.norm(seg_b - seg_a, axis=1)
    pick = rng.choice(len(length), size=n, p=length / length.sum())
    u = rng.random(n)[:, None]
    return seg_a[pick] + u * (seg_b[pick] - seg_a[pick])


def _distance_to(points: np.ndarray, lines: list[np.ndarray]) -> np.ndarray:
    """Exact distance from each point to the nearest segment of ``lines`` (chunked brute force over segments)."""
    seg_a = np.concatenate([l[:-1] for l in lines])
    seg_b = np.concatenate([l[1:] for l in lines])
    d = seg_b - seg_a
    dd = np.maximum((d * d).sum(1), 1e-300)
    out = np.empty(len(points))
    for i in range(0, len(points), 2000):
        p = points[i:i + 2000, None, :]
        t = np.clip(((p - seg_a) * d).sum(-1) / dd, 0, 1)
        proj = seg_a + t[..., None] * d
        out[i:i + 2000] = np.sqrt(((p - proj) ** 2).sum(-1)).min(1)
    return out


def grid_convergence(sizes: Sequence[int], budget_points: int = 200, samples: int = 50_000, accuracy: str = "very_high",
                     workdir: str | Path = "runs/study", seed: int = 0) -> dict[str, Any]:
    """Fig. 2: distance from ``∂RA`` (classical, ``N x N``) to ``∂RA~_0`` (from ``W_eps`` on ``N x N x budget_points``)."""
    model = get_model("pointmass")
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    rows = []
    for n in sizes:
        t0 = time.perf_counter()
        table = _solve(model, (n, n), budget_points, 1e-3, accuracy, workdir / f"grid_{n}_{budget_points}_{accuracy}.srt")
        axes = table.state_axes("V")
        ra_lines = _zero_contour(axes, np.asarray(table.values("V")[0], dtype=np.float64))
        soft = table.slice("W_eps", 0.0, table.budget_resolution)
        soft_lines = _zero_contour(axes, soft)
        pts = _sample_on(ra_lines, samples, rng)
        dist = _distance_to(pts, soft_lines)
        ra, ra0 = table.set_mask(0.0), table.set_mask(0.0, 0.0)
        rows.append({
            "N": n, "h": float(np.sqrt(2.0) / (n - 1)), "mean": float(dist.mean()), "max": float(dist.max()),
            "measure_RA": float(ra.sum()) * table.cell_volume("V"), "measure_RA0": float(ra0.sum()) * table.cell_volume("V"),
            "symmetric_difference": float((ra ^ ra0).sum()) * table.cell_volume("V"),
            "solve_s": table.header.get("wall_time", {}), "study_s": time.perf_counter() - t0,
        })
    return {"study": "grid-convergence", "budget_points": budget_points, "samples": samples, "accuracy": accuracy,
            "units": "normalised: v / 40 m/s, y / 25 m", "rows": rows}


def eps_convergence(eps_list: Sequence[float], shape: tuple[int, int] = (101, 101), budget_points: int = 111,
                    budgets: Sequence[float] = (0.06, 0.3, 0.6), accuracy: str = "very_high",
                    workdir: str | Path = "runs/study") -> dict[str, Any]:
    """Fig. 3: ``d_{Q,k} = mu(RA^_Q^{eps_k} Δ RA^_Q^{eps_{k+1}})`` with the paper's proxy ``W_eps + 1e-3 <= 0``."""
    model = get_model("pointmass")
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    eps_list = sorted(eps_list, reverse=True)
    tables = [_solve(model, shape, budget_points, e, accuracy, workdir / f"eps_{e:g}_{shape[0]}_{budget_points}_{accuracy}.srt")
              for e in eps_list]
    rows = []
    for q in budgets:
        masks = [t.set_mask(0.0, q, margin=t.paper_proxy_margin()) for t in tables]
        vol = tables[0].cell_volume("W_eps")
        rows.append({"Q": q, "measure": [float(m.sum()) * vol for m in masks],
                     "d": [float((a ^ b).sum()) * vol for a, b in zip(masks, masks[1:])]})
    return {"study": "eps-convergence", "eps": list(eps_list), "grid": list(shape), "budget_points": budget_points,
            "accuracy": accuracy, "rows": rows}


def format_result(result: dict[str, Any]) -> str:
    if result["study"] == "grid-convergence":
        lines = [f"grid convergence ({result['accuracy']}, {result['budget_points']} budget nodes, {result['samples']} samples; {result['units']})",
                 "   N        h      mean       max   mu(RA)  mu(RA~_0)  mu(sym.diff)"]
        for r in result["rows"]:
            lines.append(f"{r['N']:4d} {r['h']:.5f} {r['mean']:.6f} {r['max']:.6f} {r['measure_RA']:8.2f} {r['measure_RA0']:9.2f} {r['symmetric_difference']:10.3f}")
        return "\n".join(lines)
    lines = [f"eps convergence (grid {result['grid']}, {result['budget_points']} budget nodes): eps = {result['eps']}"]
    for r in result["rows"]:
        lines.append(f"Q={r['Q']:<5g} measures {['%.2f' % m for m in r['measure']]}  d_Q,k {['%.3f' % d for d in r['d']]}")
    return "\n".join(lines)
