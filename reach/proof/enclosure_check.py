"""What the safety filter's proof takes from a model, checked before any long work: that the model gives it
(:func:`require_filter_extras`) and that its held-period enclosure holds the simulated motion (:func:`check_enclosure`).

The proof trusts the boxes of the model's :attr:`~softreach.reach.model_filter.FilterPart.held_box_kernel` to hold
every motion of a held period and never compares them with ``f``; :func:`check_enclosure` does, on sampled runs:

* starts uniform over ``C1`` (``domain`` where unbounded), some on a face or corner, each a corner or inner point of
  a start box up to ``box_cells`` cells wide; actions at the control box's corners, held candidates, and uniform;
* winds with ``switches`` random switches, each piece at a corner of the disturbance box or uniform, and constant
  extreme winds (which reach an exact enclosure's bounds);
* ``f`` integrated by RK4 with ``steps`` and ``2 steps`` equal steps between breakpoints (the switches and every
  instant a claim starts or ends), so RK4 crosses only smooth motion.

A state at time ``s`` must lie in every box claiming ``s`` within an **allowance** per run and coordinate: the two
runs' largest difference at the breakpoints (RK4's error falls 16-fold as the step halves), plus ``(steps taken + 8)``
``eps`` times the coordinate's largest magnitude (an ulp per RK4 increment, 8 for the model's bound). Passing is
evidence, not proof: the samples are finite, the nodes instants, and runs start at ``t = 0``."""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ..sim.rk4 import rk4_rows
from .model_kernels import SET_INDEX, boxes_set_max, held_boxes

#: where a model's author reads what the filter needs
DOCS = "docs/models.md, '2. The motion bound the filter needs'"


@dataclass(frozen=True)
class EnclosureCheck:
    """Settings of :func:`check_enclosure`.

    :param samples: simulated runs (each a start box, a start in it, an action and a wind signal)
    :param switches: wind switches inside the period per run
    :param steps: RK4 steps between consecutive breakpoints in the coarser run (the finer takes twice as many)
    :param box_cells: start boxes are up to this many cells wide along each axis (a quarter are points)
    :param face_share, constant_share: the shares of starts on a face of ``C1`` and of runs with one extreme wind
    :param seed: the random generator's seed: the check is deterministic
    """

    samples: int = 2048
    switches: int = 3
    steps: int = 4
    box_cells: float = 2.0
    face_share: float = 0.25
    constant_share: float = 0.25
    seed: int = 0

    def __post_init__(self):
        for name, least, kind in (("samples", 1, "positive"), ("switches", 0, "non-negative"),
                                  ("steps", 1, "positive")):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < least:
                raise ValueError(f"EnclosureCheck.{name} must be a {kind} integer, got {v!r}")
        for name in ("face_share", "constant_share"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"EnclosureCheck.{name} must lie in [0, 1], got {getattr(self, name)!r}")
        if not (math.isfinite(self.box_cells) and self.box_cells >= 0):
            raise ValueError(f"EnclosureCheck.box_cells must be a finite number >= 0, got {self.box_cells!r}")


class EnclosureError(ValueError):
    """A simulated run left the box the model's enclosure claims, or the model lacks what the filter needs. :attr:`run`
    (``None`` for a missing method): ``claim``, ``period``, ``box_lo``, ``box_hi``, ``start``, ``action``, ``wind``,
    ``until`` (each wind value's end), ``s``, ``axis``, ``value``, ``side`` (the box side crossed)."""

    def __init__(self, message: str, run: dict[str, Any] | None = None):
        super().__init__(message)
        self.run = run


def missing_extras(model: Any, cells: bool = True) -> list[str]:
    """What the filter needs of ``model`` that it does not give, each naming what to add (with ``cells``, also what
    the cells need); empty: nothing."""
    out = []
    if getattr(model, "held_box_kernel", None) is None:
        out.append("held_box_kernel(params, x_lo, x_hi, a, s0, s1, lo, hi) with held_box_params: a compiled function "
                   "writing into lo, hi a box that holds every state at some time in [s0, s1] of a period with the "
                   "action a held, from every start in [x_lo, x_hi], for every wind signal")
    kernel, n = getattr(model, "set_max_kernel", None), model.state_dim
    if kernel is None:
        out.append("set_boxes (box-distance sets), or a set_max_kernel(params, which, lo, hi) with set_max_params: "
                   "each set's largest value over a box, compiled")
    # the default kernel knows box distances only, not a model's own set_box_max
    elif kernel is boxes_set_max and any(model.set_box_max(w, 0.0, np.zeros((1, n)), np.zeros((1, n))) is not None
                                         for w in SET_INDEX):
        out.append("set_max_kernel(params, which, lo, hi) with set_max_params computing what set_box_max does")
    if cells and model.hard_box is None:
        out.append("hard_box = ((lo, ...), (hi, ...)): the box holding C1, which the cells tile")
    if cells and getattr(model, "cell_shape", None) is None:
        out.append("cell_shape = (cells per state axis over hard_box, ...): the cells on which the filter proves what "
                   "it certifies (docs/models.md's cart: (320, 320))")
    return out


def lacking(model: Any) -> str | None:
    """What the safety filter needs that ``model`` lacks, in one line naming what to add; ``None``: nothing."""
    missing = missing_extras(model)
    return f"add to {type(model).__name__}: " + "; ".join(missing) + f" ({DOCS})" if missing else None


def require_filter_extras(model: Any, job: str, cells: bool) -> None:
    """Refuse, before ``job`` starts, a model without what the filter's proof needs (:func:`missing_extras`).

    :raises EnclosureError: naming each missing part with its signature, and where the docs describe them
    """
    missing = missing_extras(model, cells)
    if missing:
        raise EnclosureError(
            f"{model.name} ({type(model).__module__}.{type(model).__qualname__}) lacks what the safety filter needs "
            f"for {job}; add to the class: " + "; ".join(missing) + ". The base class derives every enclosure the "
            f"filter reads from the kernel, as the cart of docs/models.md shows; see {DOCS}")


def _region(model: Any) -> tuple[np.ndarray, np.ndarray]:
    """``C1``'s box, the model's domain along the sides ``C1`` leaves unbounded."""
    lo, hi = (np.asarray(v, dtype=np.float64) for v in model.domain)
    if model.hard_box is not None:
        c_lo, c_hi = (np.asarray(v, dtype=np.float64) for v in model.hard_box)
        lo, hi = np.where(np.isfinite(c_lo), c_lo, lo), np.where(np.isfinite(c_hi), c_hi, hi)
    return lo, hi


def _corners(lo: Any, hi: Any) -> np.ndarray:
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    bits = (np.arange(2 ** len(lo))[:, None] >> np.arange(len(lo))) & 1
    return np.where(bits == 1, hi, lo)


def _samples(model: Any, dt: float, cell_width: np.ndarray, s: EnclosureCheck, rng: np.random.Generator):
    """Start boxes, starts, actions, switch instants and wind values of the runs."""
    N, n = s.samples, model.state_dim
    lo, hi = _region(model)
    c = lo + rng.random((N, n)) * (hi - lo)
    r = rng.random((N, n))
    face = rng.random(N) < s.face_share
    corner = face & (rng.random(N) < 0.1)
    axis = rng.integers(n, size=N)
    snap = (corner[:, None] | (face[:, None] & (np.arange(n) == axis[:, None])))
    side = rng.random((N, n)) < 0.5
    c = np.where(snap, np.where(side, hi, lo), c)
    r = np.where(snap, np.where(side, 1.0, 0.0), r)  # a box on a face lies inside C1, the face its side
    width = cell_width * rng.random((N, n)) * s.box_cells * (rng.random(N) >= 0.25)[:, None]
    b_lo, b_hi = c - r * width, c + (1.0 - r) * width
    q = np.where(rng.random((N, 1)) < 0.5, (rng.random((N, n)) < 0.5).astype(float), rng.random((N, n)))
    x0 = np.where(snap, c, np.clip(b_lo + q * (b_hi - b_lo), b_lo, b_hi))
    a_lo, a_hi = (np.asarray(v, dtype=np.float64) for v in model.control_bounds)
    cands = np.asarray(model.held_candidates(), dtype=np.float64).reshape(-1, len(a_lo))
    kind = rng.integers(3, size=N)
    a = np.where((kind == 0)[:, None], _corners(a_lo, a_hi)[rng.integers(2 ** len(a_lo), size=N)],
                 np.where((kind == 1)[:, None], cands[rng.integers(len(cands), size=N)],
                          a_lo + rng.random((N, len(a_lo))) * (a_hi - a_lo)))
    d_lo, d_hi = (np.asarray(v, dtype=np.float64) for v in model.disturbance_bounds)
    d_corners = _corners(d_lo, d_hi)
    pieces = (N, s.switches + 1)  # each piece of the signal at a corner of the box or uniform in it, half and half
    wind = np.where((rng.random(pieces) < 0.5)[..., None], d_corners[rng.integers(len(d_corners), size=pieces)],
                    d_lo + rng.random(pieces + (len(d_lo),)) * (d_hi - d_lo))
    constant = rng.random(N) < s.constant_share
    wind = np.where(constant[:, None, None], d_corners[rng.integers(len(d_corners), size=N)][:, None, :], wind)
    tau = np.sort(rng.uniform(0.0, dt, (N, s.switches)), axis=1)
    return b_lo, b_hi, x0, a, tau, wind


def _simulate(model: Any, t0: float, x0: np.ndarray, a: np.ndarray, breaks: np.ndarray, wind: np.ndarray,
              steps: int) -> tuple[np.ndarray, np.ndarray]:
    """RK4 with ``steps`` equal steps between ``breaks``, ``wind[:, q]`` on gap ``q``: every node's times and states."""
    N, B = breaks.shape
    xs, ts = [x0], [breaks[:, 0]]
    x = x0
    varying = not getattr(model, "time_invariant", True)
    for q in range(B - 1):
        h = (breaks[:, q + 1] - breaks[:, q]) / steps
        b = wind[:, q]
        for i in range(steps):
            s = breaks[:, q] + i * h
            tc, tm, te = (t0 + s, t0 + s + 0.5 * h, t0 + s + h) if varying else (t0, t0, t0)
            x = rk4_rows(model.f, tc, tm, te, h, x, a, b)
            xs.append(x)
            ts.append(breaks[:, q + 1] if i == steps - 1 else s + h)
    return np.stack(ts, axis=1), np.stack(xs, axis=1)


def _claims(model: Any, b_lo: np.ndarray, b_hi: np.ndarray, x0: np.ndarray, a: np.ndarray, dt: float,
            pieces: int, checks: int) -> list[tuple[str, float, float, float, bool, Any]]:
    """Every box the filter may read for these runs: ``(name, period, s0, s1, from_box, (lo, hi))``."""
    out = []
    # the periods the filter bounds: the landing test's check instants, ``dt`` last (as in ``Motion.check_edges``)
    for D in [dt * j / checks for j in range(1, checks + 1)]:
        edges = np.linspace(0.0, D, pieces + 1)
        for name, s0, s1 in [("tube", 0.0, D), ("end", D, D)] + [
                (f"piece {j + 1} of {pieces}", edges[j], edges[j + 1]) for j in range(pieces)]:
            for from_box, lo, hi in ((True, b_lo, b_hi), (False, x0, x0)):
                out.append((f"held_box_kernel ({name}, from {'a box' if from_box else 'a point'})", D, float(s0),
                            float(s1), from_box, held_boxes(model, lo, hi, a, float(s0), float(s1))))
    return out


def check_enclosure(model: Any, dt: float, pieces: int = 4, checks: int = 1, cell_width: Any = None,
                    settings: EnclosureCheck = EnclosureCheck()) -> dict[str, Any]:
    """Compare the model's held-period enclosures with simulated runs (the module docstring).

    :param dt: the control period [s]
    :param pieces, checks: the budget bound's pieces and the landing test's instants per period (as in the look-ahead)
    :param cell_width: a cell's width per axis; ``None``: from the model's ``cell_shape``, else its ``default_shape``
    :return: ``{"runs", "claims", "tightest", "seconds"}``; ``tightest``: the largest excess over a box less allowance
    :raises EnclosureError: a run outside a box, naming the claim, start, action, wind and coordinate
    """
    started = time.perf_counter()
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"the control period must be a finite number > 0, got {dt!r}")
    lo, hi = _region(model)
    if cell_width is None:
        shape = model.cell_shape if model.cell_shape is not None else tuple(k - 1 for k in model.default_shape)
        cell_width = (hi - lo) / np.asarray(shape, dtype=np.float64)
    cell_width = np.broadcast_to(np.asarray(cell_width, dtype=np.float64), (model.state_dim,))
    rng = np.random.default_rng(settings.seed)
    b_lo, b_hi, x0, a, tau, wind = _samples(model, dt, cell_width, settings, rng)
    claims = _claims(model, b_lo, b_hi, x0, a, dt, pieces, checks)
    fixed = np.unique([0.0, dt] + [float(c[2]) for c in claims] + [float(c[3]) for c in claims])
    F, N = len(fixed), len(x0)
    marks = np.concatenate([np.broadcast_to(fixed, (N, F)), tau], axis=1)
    order = np.argsort(marks, axis=1, kind="stable")
    breaks = np.take_along_axis(marks, order, axis=1)
    # the wind of each gap: the piece of the signal its start lies in
    piece = (tau[:, None, :] <= breaks[:, :-1, None]).sum(axis=2)
    gap_wind = np.take_along_axis(wind, piece[:, :, None], axis=1)
    _, coarse = _simulate(model, 0.0, x0, a, breaks, gap_wind, settings.steps)
    times, xs = _simulate(model, 0.0, x0, a, breaks, gap_wind, 2 * settings.steps)
    if not np.isfinite(xs).all():
        r = int(np.flatnonzero(~np.isfinite(xs).all(axis=(1, 2)))[0])
        raise EnclosureError(f"{model.name}: the simulation of a held period diverged from {_state(model, x0[r])}, "
                             f"{_action(model, a[r])}; is f defined over C1?")
    B, M, fine = breaks.shape[1], xs.shape[1], 2 * settings.steps
    difference = np.abs(xs[:, ::fine] - coarse[:, ::settings.steps]).max(axis=1)
    allowance = difference + (fine * (B - 1) + 8) * np.finfo(np.float64).eps * np.abs(xs).max(axis=1)
    # each fixed instant's node, and each row's extremes between consecutive fixed instants (end excluded)
    node = np.argsort(order, axis=1)[:, :F] * fine
    at = np.take_along_axis(xs, node[:, :, None], axis=1)
    flat = (node + M * np.arange(N)[:, None]).ravel()
    seg_lo = np.minimum.reduceat(xs.reshape(N * M, -1), flat, axis=0).reshape(N, F, -1)
    seg_hi = np.maximum.reduceat(xs.reshape(N * M, -1), flat, axis=0).reshape(N, F, -1)
    tightest = -np.inf
    for name, D, s0, s1, from_box, (c_lo, c_hi) in claims:
        c_lo, c_hi = np.asarray(c_lo, dtype=np.float64), np.asarray(c_hi, dtype=np.float64)
        i, j = int(np.searchsorted(fixed, s0)), int(np.searchsorted(fixed, s1))
        low = np.minimum(seg_lo[:, i:j].min(axis=1), at[:, j]) if j > i else at[:, j]
        high = np.maximum(seg_hi[:, i:j].max(axis=1), at[:, j]) if j > i else at[:, j]
        with np.errstate(invalid="ignore"):
            excess = np.maximum(c_lo - low, high - c_hi) - allowance
        excess[np.isnan(c_lo).any(axis=1) | np.isnan(c_hi).any(axis=1)] = -np.inf  # no box: no claim
        r, k = np.unravel_index(int(np.argmax(excess)), excess.shape)
        tightest = max(tightest, float(excess[r, k]))
        if excess[r, k] > 0:
            inside = np.flatnonzero((times[r] >= s0) & (times[r] <= s1))
            out = np.maximum(c_lo[r, k] - xs[r, inside, k], xs[r, inside, k] - c_hi[r, k])
            raise EnclosureError(*_refutation(model, name, D, from_box, b_lo, b_hi, x0, a, tau, wind, times, xs,
                                              c_lo, c_hi, allowance, (r, int(inside[np.argmax(out)]), k)))
    return {"runs": len(x0), "claims": len(claims), "tightest": tightest, "seconds": time.perf_counter() - started}


def _fmt(values: Any) -> str:
    return "(" + ", ".join(f"{float(v):.17g}" for v in np.atleast_1d(values)) + ")"


def _state(model: Any, x: Any) -> str:
    return f"state ({', '.join(model.state_names)}) = {_fmt(x)}"


def _action(model: Any, a: Any) -> str:
    return f"action {_fmt(a)}" + (f" [{', '.join(model.control_units)}]" if model.control_units else "")


def _refutation(model, name, D, from_box, b_lo, b_hi, x0, a, tau, wind, times, xs, c_lo, c_hi, allowance, worst
                ) -> tuple[str, dict[str, Any]]:
    """The error of a run outside a claimed box, and the run (:attr:`EnclosureError.run`): enough to reproduce it."""
    r, node, i = (int(v) for v in worst)
    s, v = float(times[r, node]), float(xs[r, node, i])
    below = v < c_lo[r, i]
    side = float(c_lo[r, i] if below else c_hi[r, i])
    unit = model.state_units[i] if i < len(model.state_units) else ""
    switch = [float(t) for t in tau[r] if t < D] + [D]
    signal = ", ".join(f"{_fmt(w)} until {t:.17g} s" for w, t in zip(wind[r], switch))
    start = (f"the start box {_fmt(b_lo[r])} .. {_fmt(b_hi[r])} (simulated from its point {_fmt(x0[r])})"
             if from_box else _state(model, x0[r]))
    run = {"claim": name, "period": D, "box_lo": b_lo[r].copy(), "box_hi": b_hi[r].copy(), "start": x0[r].copy(),
           "action": a[r].copy(), "wind": wind[r, :len(switch)].copy(), "until": switch, "s": s, "axis": i,
           "value": v, "side": side}
    units = f" [{', '.join(model.disturbance_units)}]" if model.disturbance_units else ""
    return (f"{model.name}'s held enclosure does not hold its own motion: {name} for a hold of {D:.17g} s from "
            f"{start}, {_action(model, a[r])}, wind{units} {signal}: at s = {s:.17g} s the simulated "
            f"{model.state_names[i]} = {v:.17g} {unit} is {'below' if below else 'above'} the box's "
            f"{'lower' if below else 'upper'} side {side:.17g} {unit} by {abs(v - side):.3g} {unit} (integration "
            f"allowance {float(allowance[r, i]):.3g}). The filter's proof rests on this box; fix the enclosure "
            f"({DOCS})"), run


_PASSED: set[str] = set()


def check_model_for_filter(model: Any, dt: float, job: str, pieces: int = 4, checks: int | None = None,
                           cells: bool = False, cell_width: Any = None, settings: EnclosureCheck | None = None) -> None:
    """:func:`require_filter_extras`, then :func:`check_enclosure`, before ``job`` starts; not repeated in a process
    for the same class, parameters, period and settings (an enclosure changed another way is not checked again).

    :param checks: the landing test's check instants per period; ``None``: the model's ``substeps``
    :param cells: also ask what the filter's own cells need (:func:`missing_extras`)
    :raises EnclosureError: what is missing, or the run that left a box
    """
    require_filter_extras(model, job, cells)
    settings = settings or EnclosureCheck()
    checks = int(model.substeps if checks is None else checks)
    width = None if cell_width is None else [float(v) for v in np.ravel(cell_width)]
    key = json.dumps([type(model).__module__, type(model).__qualname__, id(type(model)), model.parameters(),
                      np.asarray(model.held_box_params, dtype=np.float64).tolist(), float(dt), int(pieces), checks,
                      width, asdict(settings)], sort_keys=True, default=str)
    if key in _PASSED:
        return
    check_enclosure(model, dt, pieces, checks, cell_width, settings)
    _PASSED.add(key)
