"""Certificates solved on cells for the held-action game: proofs, where the table only interpolates.

Cells: ``C1``'s box (:attr:`~softreach.reach.problem.Model.hard_box`) cut into ``shape`` state cells, times budget
cells ``[j dz, (j + 1) dz]``. A **plan** holds a candidate action for ``K`` periods (``K`` in ``holds``). A cell
``(c, j)`` is **good at** ``t_k = k dt`` when some plan satisfies, from every state of the cell and for every wind
(the enclosures :meth:`~softreach.reach.model_filter.FilterPart.held_enclosure_box`, chained, boxes and spends widened
for the environment's rounding: :func:`~softreach.reach.proof.lookahead.state_allowance`, ``budget_allowance``):

1. every period's motion stays in ``C1`` (the convex ``c1`` at each tube box's corners);
2. the budget spent ``S`` (each period's pieces charged at their largest ``h_eps``) leaves ``j dz - S >= 0``;
3. every run surely lands at a check instant, or ``k + K <= N`` and every cell the end box touches is good at
   ``t_{k+K}`` at every budget the plan can leave.

No cell is good at ``T``. If ``(c, j)`` is good so is ``(c, j + 1)`` (the same plan works, by induction from ``T``), so
a column is one number ``m_k[c]``, the lowest good budget index, and condition 3 reads ``j >= S / dz + max m_{k+K}``.
**What it proves:** a controller applying at every step an action whose end box good cells cover
(:meth:`CellCertificate.covered`) or its plan's next action (:meth:`CellCertificate.plan`) keeps ``C1`` and the budget
and lands by ``T``, from any good start and for every wind. Plans of several periods let a cell progress where a
period moves less than a cell; plans whose end box touches over ``span_cap`` cells are not used.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from . import cell_game
from .enclosure_check import check_model_for_filter
from ..jit import cache_root, source_stamp
from .kernels import WRAP_ULPS, cover_rows, frozen, plan_rows

#: file format of :meth:`CellCertificate.save`
FORMAT = "softreach-cell-certificate-1"
#: the arrays of a cell certificate that scale with the cells (memory-mapped from a cache folder)
_LARGE = ("m", "action", "hold")
#: the game the cells are solved for, named in their key and files: land by ``T``
GAME = "land"
#: budget cells per control period by default: a plan's spend is rounded up to whole budget cells, so each plan step
#: gives away less than ``1 / BUDGET_CELLS_PER_PERIOD`` of a period of budget
BUDGET_CELLS_PER_PERIOD = 64
#: the most budget cells a horizon may hold: ``m`` is int16 and ``never`` is one past the top
MAX_BUDGET_CELLS = 32000


def default_dz(dt: float, horizon: float) -> float:
    """The budget cell [s]: :data:`BUDGET_CELLS_PER_PERIOD` a period, coarser only where the horizon would hold more
    than :data:`MAX_BUDGET_CELLS`."""
    return max(dt / BUDGET_CELLS_PER_PERIOD, horizon / MAX_BUDGET_CELLS)


def budget_top(dz: float, horizon: float) -> int:
    """The highest budget index the cells store: no run spends more than the horizon, so budgets above are equal."""
    return int(round(horizon / dz))


class CellCertificate:
    """The lowest good budget index ``m[k, c]`` and a plan ``(action[k, c], hold[k, c])`` per sample time and cell.

    :param lo, hi: the cell grid's box (the model's ``hard_box``)
    :param m: ``(N + 1, *shape)`` int16, ``never`` where no budget suffices
    :param action, hold: ``(N + 1, *shape)`` int8: the plan's candidate index (``-1``: none) and periods held
    :param candidates: ``(J, m)`` physical held actions
    :param dt, dz, horizon: control period, budget cell, horizon [s]
    :param key: what the cells were built for (:func:`cell_key`)
    """

    def __init__(self, lo: Any, hi: Any, m: np.ndarray, action: np.ndarray, hold: np.ndarray, candidates: Any,
                 dt: float, dz: float, horizon: float, key: dict[str, Any]):
        self.lo, self.hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        self.m, self.action, self.hold = np.asarray(m), np.asarray(action), np.asarray(hold)
        self.shape = self.m.shape[1:]
        self.width = (self.hi - self.lo) / np.asarray(self.shape, dtype=np.float64)
        self.candidates = np.asarray(candidates, dtype=np.float64)
        self.dt, self.dz, self.horizon = float(dt), float(dz), float(horizon)
        self.steps, self.top = self.m.shape[0] - 1, budget_top(self.dz, self.horizon)
        self.never = self.top + 1
        self.key = dict(key)
        #: per state axis whether it is periodic (the model's, in ``key``), and its outward allowance where it is
        #: (:data:`~softreach.reach.proof.kernels.WRAP_ULPS`): the cells tile its period once, read modulo its cells
        self.periodic = np.asarray(key.get("periodic", [False] * len(self.shape)), dtype=bool)
        self.wrap = np.where(self.periodic, WRAP_ULPS * np.spacing(self.hi - self.lo), 0.0)
        #: what :func:`softreach.reach.proof.kernels.cover_row` reads: a row of cells per sample (a memmap stays mapped)
        self.kernel_args = (frozen(np.asarray(self.m).reshape(self.steps + 1, -1)),
                            frozen(np.asarray(self.shape, dtype=np.int64)), frozen(self.lo), frozen(self.width),
                            frozen(self.periodic), frozen(self.wrap), self.dt, self.dz, self.top, self.steps,
                            self.horizon)
        #: the plans as :func:`softreach.reach.proof.kernels.plan_row` reads them
        self.plan_args = (frozen(np.asarray(self.action).reshape(self.steps + 1, -1)),
                          frozen(np.asarray(self.hold).reshape(self.steps + 1, -1)))

    @classmethod
    def build(cls, lookahead: Any, shape: Any, dz: float | None = None, holds: Any = (1,),
              span_cap: int = 32) -> "CellCertificate":
        """Solve the cell game backwards from ``T`` (:func:`softreach.reach.proof.cell_game.solve`).

        :param lookahead: a :class:`~softreach.reach.proof.lookahead.Lookahead` (model, enclosures, budget bound)
        :param shape: cells per state axis over the model's ``hard_box``
        :param dz: budget cell [s]; default :func:`default_dz`
        :param holds, span_cap: the plan lengths, in periods; the most cells a plan's end box may touch
        """
        la, model = lookahead, lookahead.model
        key = cell_key(la, shape, dz, holds, span_cap)
        if model.hard_box is None:
            raise ValueError(f"{model.name} declares no hard_box; the cells tile it")
        shape = tuple(key["shape"])
        if len(shape) != model.state_dim or min(shape) < 1:
            raise ValueError(f"shape must give {model.state_dim} positive cell counts, got {shape!r}")
        for i, per in enumerate(model.periodic_axes()):
            if per and (model.hard_box[0][i], model.hard_box[1][i]) != (model.domain[0][i], model.domain[1][i]):
                raise ValueError(f"{model.name}: the cells tile hard_box, whose periodic axis {model.state_names[i]} "
                                 f"must be its period {model.domain[0][i]!r}..{model.domain[1][i]!r} (domain), got "
                                 f"{model.hard_box[0][i]!r}..{model.hard_box[1][i]!r}")
        holds = tuple(key["holds"])
        if not holds or min(holds) < 1 or max(holds) > 127:
            raise ValueError(f"holds must be periods in 1..127, got {holds!r}")
        dt, T, dz = la.dt, la.horizon, key["dz"]
        if not (math.isfinite(dz) and dz > 0 and budget_top(dz, T) <= MAX_BUDGET_CELLS):
            raise ValueError(f"dz must be a positive number of seconds, at least the horizon / {MAX_BUDGET_CELLS} = "
                             f"{T / MAX_BUDGET_CELLS:g} s, got {dz!r}")
        N = int(round(T / dt))
        if not math.isclose(N * dt, T, rel_tol=1e-9):
            raise ValueError(f"the horizon {T} s is not a whole number of periods {dt} s")
        # the cells rest on the model's enclosure: checked against simulated runs first (hard_box is asked above)
        check_model_for_filter(model, dt, "building the filter's cells", la.pieces, la.target_checks, cells=False,
                               cell_width=(np.asarray(model.hard_box[1]) - model.hard_box[0]) / np.asarray(shape))
        return cell_game.solve(cls, la, key)

    @classmethod
    def empty(cls, lookahead: Any, holds: Any = (1,)) -> "CellCertificate":
        """Cells good nowhere: sound, and run by solved cells' compiled code (:mod:`softreach.filters.background`)."""
        la, model = lookahead, lookahead.model
        if model.hard_box is None:
            raise ValueError(f"{model.name} declares no hard_box; the cells tile it")
        shape = (1,) * model.state_dim
        key = cell_key(la, shape, None, holds)
        m = np.zeros((int(round(la.horizon / la.dt)) + 1,) + shape, np.int16)
        cells = cls(model.hard_box[0], model.hard_box[1], m, np.full(m.shape, -1, np.int8),
                    np.zeros(m.shape, np.int8), la.candidates, la.dt, key["dz"], la.horizon, key)
        m[...] = cells.never  # the certificate's own "no budget suffices" (its kernel arguments view m)
        return cells

    def contains(self, t: Any, x: Any, z: Any) -> np.ndarray:
        """Is each state ``(t, x, z)`` in a good cell (``False`` off the grid, at a negative budget, after ``T``)?"""
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        return self.covered(t, x, x, z)

    def covered(self, t_next: Any, end_lo: np.ndarray, end_hi: np.ndarray, z_end: Any) -> np.ndarray:
        """Are all cells the box ``[end_lo, end_hi]`` touches at ``t_next`` good at the lowest end budget ``z_end``?"""
        N = len(end_lo)
        out = np.empty(N, bool)
        if N:
            t_next, z_end = (np.ascontiguousarray(np.broadcast_to(np.asarray(v, dtype=np.float64), (N,)))
                             for v in (t_next, z_end))
            cover_rows(self.kernel_args, t_next, np.asarray(end_lo, dtype=np.float64),
                       np.asarray(end_hi, dtype=np.float64), z_end, out)
        return out

    def plan(self, t: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """Each state's cell's plan ``(candidate, periods held)``, ``(-1, 0)`` if none; sound where :meth:`contains`."""
        x = np.ascontiguousarray(np.atleast_2d(np.asarray(x, dtype=np.float64)))
        t = np.ascontiguousarray(np.broadcast_to(np.asarray(t, dtype=np.float64), (len(x),)))
        act, hold = np.empty(len(x), np.int64), np.empty(len(x), np.int64)
        plan_rows(self.kernel_args, *self.plan_args, t, x, act, hold)
        return act, hold

    def save(self, path: str | Path, compressed: bool = True) -> None:
        """Write one ``.npz`` (the key as JSON), or with ``compressed=False`` a folder of ``.npy`` arrays that
        :meth:`load` memory-maps (the cache's form: only touched pages are read, and shared between processes)."""
        small = dict(format=FORMAT, lo=self.lo, hi=self.hi, candidates=self.candidates, game=GAME,
                     scalars=np.array([self.dt, self.dz, self.horizon]), key=json.dumps(self.key, sort_keys=True))
        if compressed:
            np.savez_compressed(path, **{name: getattr(self, name) for name in _LARGE}, **small)
            return
        path = Path(path)
        path.mkdir()
        for name in _LARGE:
            np.save(path / f"{name}.npy", getattr(self, name))
        np.savez(path / "meta.npz", **small)

    @classmethod
    def load(cls, path: str | Path, key: dict[str, Any] | None = None) -> "CellCertificate":
        """Read cells written by :meth:`save` (a folder memory-mapped); with ``key``, refuse cells built for another.

        :raises ValueError: not a cell-certificate file, or built for another key
        """
        path = Path(path)
        folder = path.is_dir()
        try:
            with np.load(path / "meta.npz" if folder else path, allow_pickle=False) as f:
                if str(f["format"]) != FORMAT or str(f["game"]) != GAME:
                    raise ValueError(f"format {str(f['format'])!r} of the {str(f['game'])!r} game, expected "
                                     f"{FORMAT!r} of the {GAME!r} game")
                stored = json.loads(str(f["key"]))
                dt, dz, T = (float(v) for v in f["scalars"])
                large = [np.load(path / f"{n}.npy", mmap_mode="r", allow_pickle=False) if folder else f[n]
                         for n in _LARGE]
                out = cls(f["lo"], f["hi"], *large, f["candidates"], dt, dz, T, stored)
        except (OSError, KeyError, EOFError, ValueError) as err:
            raise ValueError(f"{path} is not a readable cell-certificate file: {err}") from err
        if key is not None and json.dumps(key, sort_keys=True) != json.dumps(stored, sort_keys=True):
            raise ValueError(f"{path} was built for {stored}, not {key}")
        return out


def cell_key(lookahead: Any, shape: Any, dz: float | None = None, holds: Any = (1,), span_cap: int = 32
             ) -> dict[str, Any]:
    """What :meth:`CellCertificate.build` records for these arguments (the cache's key)."""
    la, model = lookahead, lookahead.model
    key = {"model": model.name, "parameters": model.parameters(), "dt": la.dt, "eps": la.eps,
           "horizon": la.horizon, "candidates": la.candidates.tolist(), "pieces": la.pieces,
           "target_checks": la.target_checks, "shape": [int(v) for v in shape],
           "dz": default_dz(la.dt, la.horizon) if dz is None else float(dz), "game": GAME,
           "holds": sorted({int(h) for h in holds}), "span_cap": int(span_cap)}
    if any(model.periodic_axes()):
        key["periodic"] = list(model.periodic_axes())
    # the allowances for the environment's numbers: the budget's always, the state's where Lookahead.env_covered
    key["allowance"] = {"budget": la.budget_slack}
    if la.env_covered:
        key["allowance"].update(state=la.slack.tolist(), stages=la.stage_slack.tolist(), c1_from=la.first_check,
                                spends_from=0.5 * la.first_check)
    return key


#: cells shipped for :class:`~softreach.filters.SafetyFilter`'s default configurations (``tests/test_packaged_cells.py``
#: rechecks them), written by ``python benchmarks/cell_certificate.py --table TABLE --write-packaged [--checks N]``
PACKAGED = Path(__file__).parent / "cells"
#: names a cache folder's origin: the packaged file's digest, or ``built:`` and the building code's ``source_stamp()``
_MADE_WITH = "packaged.sha256"


@functools.lru_cache(maxsize=32)
def _digest_of(path: str, size: int, mtime_ns: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _file_digest(path: Path) -> str:
    """The sha256 of a file, computed once per process for each size and modification time."""
    st = path.stat()
    return _digest_of(str(path), st.st_size, st.st_mtime_ns)


def cache_file(key: dict[str, Any], folder: Path) -> Path:
    """The file that holds the cells of ``key`` (:func:`cell_key`) in ``folder``."""
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    return folder / f"cells-{key['model']}-{key['game']}-{digest}.npz"


def cached(lookahead: Any, shape: Any, dz: float | None = None, holds: Any = (1,), span_cap: int = 32
           ) -> CellCertificate:
    """The cells, memory-mapped from a folder in the package's cache (:func:`softreach.reach.jit.cache_root`) first
    written from :data:`PACKAGED` or a build; a folder of another origin (:data:`_MADE_WITH`) is replaced, and an
    unwritable cache skipped with a warning."""
    key = cell_key(lookahead, shape, dz, holds, span_cap)
    folder = cache_file(key, cache_root()).with_suffix("")
    packaged = cache_file(key, PACKAGED)
    shipped = _file_digest(packaged) if packaged.is_file() else None
    origin = shipped if shipped is not None else f"built:{source_stamp()}"
    if folder.is_dir():
        made_with = folder / _MADE_WITH
        if (made_with.read_text() if made_with.is_file() else None) != origin:
            shutil.rmtree(folder, ignore_errors=True)
        else:
            try:
                return CellCertificate.load(folder, key)
            except ValueError as err:
                warnings.warn(f"rebuilding the cells: {err}", stacklevel=2)
                shutil.rmtree(folder, ignore_errors=True)
    cells = None
    if shipped is not None:
        try:
            cells = CellCertificate.load(packaged, key)
        except ValueError as err:
            warnings.warn(f"rebuilding the cells: {err}", stacklevel=2)
    if cells is None:
        cells = CellCertificate.build(lookahead, shape, dz, holds, span_cap)
    tmp = folder.with_name(folder.name + f".{os.getpid()}.tmp")
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        cells.save(tmp, compressed=False)
        (tmp / _MADE_WITH).write_text(origin)
        os.replace(tmp, folder)
    except OSError as err:
        shutil.rmtree(tmp, ignore_errors=True)
        if not folder.is_dir():  # (another process may have written it first)
            warnings.warn(f"cells not cached ({err}); they are read or rebuilt again next time", stacklevel=2)
            return cells
    return CellCertificate.load(folder, key)
