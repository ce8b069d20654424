"""A verified safe set of the held-action game: stay in ``C1`` with the budget ``z >= 0`` until ``T`` (or land).

The landing certificate of :class:`~softreach.reach.lookahead.Lookahead` is the table's interpolant, which
between grid nodes can promise slightly more than a held action delivers. Safety (never leave ``C1``, never
spend more than the budget) does not need to rest on it. This module proves it on *cells*, by construction.

Cells are boxes: the hard-constraint box ``C1`` (:attr:`~softreach.reach.problem.Model.hard_box`) cut into
``shape`` state cells, times budget cells ``[j dz, (j + 1) dz]``. A cell ``(c, j)`` is **safe at sample time**
``t_k = k dt`` when some candidate held action ``a`` satisfies, from *every* state of the cell and for every wind
signal (:meth:`~softreach.reach.dynamics.Dynamics.held_enclosure_box`):

1. the motion of the period stays in ``C1`` (the convex ``c1`` at the corners of the tube box);
2. the budget spent, bounded by ``S`` as in the one-period test (pieces charged at their largest ``h_eps``),
   leaves ``j dz - S >= 0``;
3. every cell the end box touches, at every budget the period can leave, is safe at ``t_{k+1}``; or every run
   surely lands at one of the period's check instants (then the episode ends).

At ``t_N = T`` every cell inside ``C1`` is safe (the episode ends there). More budget never hurts: if ``(c, j)``
is safe so is ``(c, j + 1)`` (the same action works, by induction from ``T``). So a cell column is stored as one
number, ``m_k[c]``, the lowest safe budget index, and item 3 asks only ``floor((j dz - S) / dz) >= m_{k+1}[c']``
for every touched state cell ``c'``: ``j >= S / dz + max m_{k+1}``.

**What it proves.** A state ``(x, z)`` at ``t_k`` whose cell is safe has an action (:meth:`SafeCells.action`,
stored per cell) that keeps ``C1`` for the period, keeps the budget, and ends in a safe cell, whatever the wind
did; so by induction a controller that only ever applies actions whose end box is covered by safe cells
(:meth:`SafeCells.covered`) never leaves ``C1`` and never overspends, from any safe start, for every wind signal.
The proof uses only the model's enclosures (sound) and the boxes' corners (convex constraint functions); the
table is not read. It says nothing about landing, which the table's certificate is for.

The model must be autonomous only in that its enclosures do not depend on ``t`` (checked: they are evaluated once
per candidate unless the model says otherwise, :attr:`~softreach.reach.problem.Model.time_invariant`).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np

#: file format of :meth:`SafeCells.save`
FORMAT = "softreach-safe-cells-1"


class SafeCells:
    """The lowest safe budget index ``m[k, c]`` and a safe candidate ``best[k, c]`` per sample time and cell.

    :param lo, hi: the cell grid's box (the model's ``hard_box``)
    :param m: ``(N + 1, *shape)`` int16, ``never`` where no budget suffices
    :param best: ``(N + 1, *shape)`` int8 candidate index (``-1``: none)
    :param candidates: ``(J, m)`` physical held actions
    :param dt, dz, horizon: control period, budget cell, horizon [s]
    :param key: what the cells were built for (model parameters, period, ``h_eps`` width, candidates)
    """

    def __init__(self, lo: Any, hi: Any, m: np.ndarray, best: np.ndarray, candidates: Any, dt: float, dz: float,
                 horizon: float, key: dict[str, Any]):
        self.lo, self.hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.m, self.best = np.asarray(m), np.asarray(best)
        self.shape = self.m.shape[1:]
        self.width = (self.hi - self.lo) / np.asarray(self.shape, dtype=np.float64)
        self.candidates = np.asarray(candidates, dtype=np.float64)
        self.dt, self.dz, self.horizon = float(dt), float(dz), float(horizon)
        self.steps = self.m.shape[0] - 1
        self.top = int(round(self.horizon / self.dz))  # no run spends more than the horizon: budgets above are equal
        self.never = self.top + 1
        self.key = dict(key)

    # ---------------------------------------------------------------- building
    @classmethod
    def build(cls, lookahead: Any, shape: Any, dz: float | None = None) -> "SafeCells":
        """Solve the cell game backwards from ``T`` for the look-ahead's model, period, ``h_eps`` and candidates.

        :param lookahead: a :class:`~softreach.reach.lookahead.Lookahead` (its enclosures and budget bound)
        :param shape: cells per state axis over the model's ``hard_box``
        :param dz: budget cell [s]; default a quarter of the period
        """
        la, model = lookahead, lookahead.model
        if model.hard_box is None:
            raise ValueError(f"{model.name} declares no hard_box; the safe cells tile it")
        shape = tuple(int(s) for s in shape)
        if len(shape) != model.state_dim or min(shape) < 1:
            raise ValueError(f"shape must give {model.state_dim} positive cell counts, got {shape!r}")
        dt, T = la.dt, la.horizon
        dz = dt / 4 if dz is None else float(dz)
        if not (math.isfinite(dz) and dz > 0):
            raise ValueError(f"dz must be a positive number of seconds, got {dz!r}")
        N = int(round(T / dt))
        if not math.isclose(N * dt, T, rel_tol=1e-9):
            raise ValueError(f"the horizon {T} s is not a whole number of periods {dt} s")
        lo, hi = (np.asarray(b, dtype=np.float64) for b in model.hard_box)
        idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), axis=-1).reshape(-1, len(shape))
        width = (hi - lo) / np.asarray(shape)
        cell_lo, cell_hi = lo + idx * width, lo + (idx + 1) * width
        cells = cls(lo, hi, np.zeros((1,) + shape, np.int16), np.zeros((1,) + shape, np.int8), la.candidates, dt, dz,
                    T, {})
        never, J, C = cells.never, len(la.candidates), len(idx)
        m = np.empty((N + 1, C), np.int16)
        best = np.full((N + 1, C), -1, np.int8)
        inside = la._corner_max(model.hard_constraint, np.full(C, T), cell_lo, cell_hi) <= 0
        m[N] = np.where(inside, 0, never)
        geometry = None
        for k in range(N - 1, -1, -1):
            t = np.full(C, k * dt)
            if geometry is None or not model.time_invariant:
                geometry = [cells._cell_step(la, t, cell_lo, cell_hi, a) for a in la.candidates]
            need = np.full((J, C), never, np.int64)
            for j, (ok, spend, first, last, lands) in enumerate(geometry):
                touched = cells._range_max(m[k + 1], first, last)
                jmin = cells._budget_index(spend, touched)
                if lands is not None:
                    jmin = np.where(lands, np.minimum(jmin, cells._budget_index(spend, 0)), jmin)
                need[j] = np.where(ok, jmin, never)
            j_best = np.argmin(need, axis=0)
            m[k] = np.minimum(need[j_best, np.arange(C)], never)
            best[k] = np.where(m[k] < never, j_best, -1)
        key = {"model": model.name, "parameters": model.parameters(), "dt": dt, "eps": la.eps, "horizon": T,
               "candidates": la.candidates.tolist(), "pieces": la.pieces, "target_checks": la.target_checks,
               "shape": list(shape), "dz": dz}
        return cls(lo, hi, m.reshape((N + 1,) + shape), best.reshape((N + 1,) + shape), la.candidates, dt, dz, T,
                   key)

    def _cell_step(self, la: Any, t: np.ndarray, lo: np.ndarray, hi: np.ndarray, a: np.ndarray):
        """One candidate held from every cell: whether the period keeps ``C1``, the budget bound, the range of
        cells the end box touches, and whether every run surely lands."""
        model, C = la.model, len(lo)
        acts = np.broadcast_to(a, (C, len(a)))
        tube_lo, tube_hi, end_lo, end_hi = model.held_enclosure_box(float(t[0]), lo, hi, acts, la.dt)
        bounded = np.isfinite(tube_lo).all(axis=1) & np.isfinite(tube_hi).all(axis=1)
        ok = bounded & (la._corner_max(model.hard_constraint, t, tube_lo, tube_hi) <= 0)
        pieces = model.held_tube_pieces_box(float(t[0]), lo, hi, acts, la.dt, la.pieces)
        spend = la._budget_spent(t, pieces[0], pieces[1], la.dt)
        first, last, on_grid = self._cell_range(end_lo, end_hi)
        lands = None
        if la.target_checks:
            rows = ok & la._meets_target(tube_lo, tube_hi)
            # landing needs only the budget spent until the landing instant, at most the whole period's bound
            lands = la._lands(t, lo, np.full(C, np.inf), acts, hi, rows)
        return ok & (on_grid | (lands if lands is not None else False)), spend, first, last, lands

    # ---------------------------------------------------------------- cell arithmetic
    def _cell_range(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First and last cell index per axis a box ``[lo, hi]`` touches (closed cells), and whether it lies on
        the grid. Off-grid boxes get a valid range and ``False``."""
        with np.errstate(invalid="ignore"):
            f = np.floor((lo - self.lo) / self.width)
            g = np.floor((hi - self.lo) / self.width)
        n = np.asarray(self.shape)
        # a box reaching exactly the grid's upper end touches the last cell only
        g = np.where(hi == self.hi, n - 1, g)
        on = (np.isfinite(f) & np.isfinite(g) & (f >= 0) & (g <= n - 1)).all(axis=1)
        f = np.clip(np.nan_to_num(f), 0, n - 1).astype(np.int64)
        g = np.clip(np.nan_to_num(g), 0, n - 1).astype(np.int64)
        return f, np.maximum(f, g), on

    def _range_max(self, field: np.ndarray, first: np.ndarray, last: np.ndarray) -> np.ndarray:
        """The largest ``field`` value over the cells ``first..last`` (per axis, inclusive) of each row."""
        field = field.reshape(self.shape)
        span = (last - first).max(axis=0) + 1 if len(first) else np.ones(len(self.shape), np.int64)
        out = np.full(len(first), np.iinfo(np.int64).min)
        for off in itertools.product(*[range(int(s)) for s in span]):
            ix = tuple(np.minimum(first[:, d] + off[d], last[:, d]) for d in range(len(self.shape)))
            out = np.maximum(out, field[ix])
        return out

    def _budget_index(self, spend: np.ndarray, needed: Any) -> np.ndarray:
        """The lowest budget index ``j`` with ``j dz - spend >= needed dz``: the start budgets whose lowest end
        budget still lies in a safe cell of index ``needed``."""
        needed = np.asarray(needed, dtype=np.int64)
        j = np.ceil(spend / self.dz + needed - 1e-12).astype(np.int64)
        # float guard: the condition itself, not its rearrangement, decides
        j = np.where(j * self.dz - spend >= needed * self.dz, j, j + 1)
        return np.minimum(np.maximum(j, 0), self.never)

    def step_index(self, t: np.ndarray) -> np.ndarray:
        """The sample index whose game covers time ``t``: ``floor(t / dt)``, which asks for survival until at
        least ``T`` (the game is the same from any start time but the horizon; a later index asks less)."""
        return np.clip(np.floor(np.asarray(t, dtype=np.float64) / self.dt + 1e-9), 0, self.steps).astype(np.int64)

    def _budget_floor(self, z: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore"):
            j = np.floor(np.minimum(z, self.top * self.dz) / self.dz + 1e-12)
        j = np.where(j * self.dz > z, j - 1, j)  # float guard: the cell's lower end lies at or below z
        return np.where(z >= 0, j, -1).astype(np.int64)

    # ---------------------------------------------------------------- queries
    def contains(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """Is each state ``(t, x, z)`` in a safe cell (``False`` off the grid, at a negative budget)?"""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        first, _, on = self._cell_range(x, x)
        k = self.step_index(np.broadcast_to(t, (len(x),)))
        need = self.m[(k,) + tuple(first.T)]
        return on & (self._budget_floor(np.broadcast_to(np.asarray(z, dtype=np.float64), (len(x),))) >= need)

    def covered(self, t_next: np.ndarray, end_lo: np.ndarray, end_hi: np.ndarray, z_end: np.ndarray) -> np.ndarray:
        """Does a period end inside safe cells: every cell the end box ``[end_lo, end_hi]`` touches at ``t_next``
        safe at the lowest end budget ``z_end`` (and so at every higher one)?"""
        if len(end_lo) == 0:
            return np.zeros(0, bool)
        first, last, on = self._cell_range(end_lo, end_hi)
        k = self.step_index(t_next)
        need = np.full(len(end_lo), np.iinfo(np.int64).min)
        span = (last - first).max(axis=0) + 1
        for off in itertools.product(*[range(int(s)) for s in span]):
            ix = tuple(np.minimum(first[:, d] + off[d], last[:, d]) for d in range(len(self.shape)))
            need = np.maximum(need, self.m[(k,) + ix])
        return on & (self._budget_floor(z_end) >= need)

    def action(self, t: Any, x: Any) -> np.ndarray:
        """The stored safe candidate index of each state's cell (``-1`` off the grid or where none is safe)."""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        first, _, on = self._cell_range(x, x)
        k = self.step_index(np.broadcast_to(t, (len(x),)))
        return np.where(on, self.best[(k,) + tuple(first.T)], -1)

    def fraction(self, k: int, z: float) -> float:
        """The share of ``C1``'s cells safe at sample ``k`` with budget ``z``."""
        return float((self.m[k] <= self._budget_floor(np.array([float(z)]))[0]).mean())

    # ---------------------------------------------------------------- files
    def save(self, path: str | Path) -> None:
        """Write the cells (numpy ``.npz``; the key as JSON)."""
        np.savez_compressed(path, format=FORMAT, lo=self.lo, hi=self.hi, m=self.m, best=self.best,
                            candidates=self.candidates, scalars=np.array([self.dt, self.dz, self.horizon]),
                            key=json.dumps(self.key, sort_keys=True))

    @classmethod
    def load(cls, path: str | Path, key: dict[str, Any] | None = None) -> "SafeCells":
        """Read cells written by :meth:`save`; with ``key``, refuse cells built for anything else.

        :raises ValueError: not a safe-cells file, or built for another model, period or candidate set
        """
        try:
            with np.load(path, allow_pickle=False) as f:
                if str(f["format"]) != FORMAT:
                    raise ValueError(f"{path}: format {str(f['format'])!r}, expected {FORMAT!r}")
                stored = json.loads(str(f["key"]))
                dt, dz, T = (float(v) for v in f["scalars"])
                out = cls(f["lo"], f["hi"], f["m"], f["best"], f["candidates"], dt, dz, T, stored)
        except (OSError, KeyError, EOFError, ValueError) as err:
            raise ValueError(f"{path} is not a readable safe-cells file: {err}") from err
        if key is not None and json.dumps(key, sort_keys=True) != json.dumps(stored, sort_keys=True):
            raise ValueError(f"{path} was built for {stored}, not {key}")
        return out


def cell_key(lookahead: Any, shape: Any, dz: float | None = None) -> dict[str, Any]:
    """What :meth:`SafeCells.build` would record for these arguments (the cache's key)."""
    la, model = lookahead, lookahead.model
    return {"model": model.name, "parameters": model.parameters(), "dt": la.dt, "eps": la.eps,
            "horizon": la.horizon, "candidates": la.candidates.tolist(), "pieces": la.pieces,
            "target_checks": la.target_checks, "shape": [int(v) for v in shape],
            "dz": la.dt / 4 if dz is None else float(dz)}


def cache_dir() -> Path:
    """Where built cells are kept: ``$SOFTREACH_CACHE`` or ``~/.cache/softreach``."""
    return Path(os.environ.get("SOFTREACH_CACHE") or Path.home() / ".cache" / "softreach")


def cached(lookahead: Any, shape: Any, dz: float | None = None) -> SafeCells:
    """The safe cells for this look-ahead, read from :func:`cache_dir` or built and written there (a few seconds
    once per model, period, ``h_eps`` width, candidate set and shape; a cache that cannot be written is skipped
    with a warning)."""
    key = cell_key(lookahead, shape, dz)
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    path = cache_dir() / f"safe-cells-{key['model']}-{digest}.npz"
    if path.is_file():
        try:
            return SafeCells.load(path, key)
        except ValueError as err:
            warnings.warn(f"rebuilding the safe cells: {err}", stacklevel=2)
    cells = SafeCells.build(lookahead, shape, dz)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + f".{os.getpid()}.tmp.npz")
        cells.save(tmp)
        os.replace(tmp, path)
    except OSError as err:
        warnings.warn(f"safe cells not cached ({err}); they are rebuilt next time", stacklevel=2)
    return cells
