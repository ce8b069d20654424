"""What the safety filter reads of a model beside its dynamics and sets: a group of its own
(``docs/models.md``, section 2, "The motion bound the filter needs").

* the candidate actions a period holds (:attr:`FilterPart.held_levels`, :attr:`FilterPart.trim_controls`,
  :meth:`FilterPart.held_candidates`; the sampled-data solve holds the same);
* the motion bound of a held period, written once as a compiled kernel (:attr:`FilterPart.held_box_kernel`), from
  which every enclosure the filter and the cells read is derived;
* the sets' maxima over boxes of states (:attr:`FilterPart.set_boxes`, :attr:`FilterPart.set_max_kernel`,
  :meth:`FilterPart.set_box_max`) and a box around the target (:attr:`FilterPart.target_box`);
* the cells on which the filter proves what it certifies (:attr:`FilterPart.cell_shape`,
  :attr:`FilterPart.cell_holds`, :attr:`FilterPart.start_segments`).

:class:`~softreach.reach.problem.Model` is a :class:`FilterPart`; it reads the model's ``name``, boxes and
dimensions from :class:`~softreach.reach.dynamics.Dynamics`.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from .boxes import box_check
from .proof.model_kernels import box_params, boxes_set_max, held_boxes


class FilterPart:
    """The part of a model the safety filter (and the sampled-data solve's candidates) reads; see the module
    docstring."""

    #: the declared boxes this part checks where they are set (:class:`~softreach.reach.dynamics.Dynamics`):
    #: ``target_box`` may be unbounded
    _CHECKS = {"target_box": box_check("target_box", states=True, optional=True, unbounded=True)}

    #: extra actions worth holding for a control period (e.g. the point mass's hover thrust ``u = g``)
    trim_controls: tuple[tuple[float, ...], ...] = ()
    #: evenly spaced values per control axis of the actions the sampled-data game and the filter hold for a period
    #: (:meth:`held_candidates`' default; ``softreach solve --held`` takes it from here)
    held_levels: int = 5

    def held_candidates(self, levels: int | None = None) -> list[tuple[float, ...]]:
        """Actions a sampled-data controller may hold for one period: ``levels`` evenly spaced values along each
        control axis (the box's corners and, for odd ``levels``, its centre among them) and :attr:`trim_controls`.

        :param levels: values per control axis (>= 2); ``None``: :attr:`held_levels`
        """
        if levels is None:
            levels = self.held_levels
        if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 2:
            raise ValueError(f"levels must be an integer >= 2, got {levels!r}")
        axes = [np.linspace(lo, hi, int(levels)) for lo, hi in zip(*self.control_bounds)]
        out = [tuple(float(v) for v in a) for a in itertools.product(*axes)]
        for a in self.trim_controls:
            a = tuple(float(v) for v in a)
            if len(a) != self.control_dim or not all(lo <= v <= hi for v, lo, hi in zip(a, *self.control_bounds)):
                raise ValueError(f"{self.name}: trim control {a!r} is not in the control box {self.control_bounds}")
            if a not in out:
                out.append(a)
        return out

    #: the motion bound of a held period, compiled: a numba ``njit`` function ``(params, x_lo, x_hi, a, s0, s1, lo,
    #: hi)`` writing into ``lo``, ``hi`` the box of every state reachable at some time in ``[s0, s1]`` of a period
    #: with the control ``a`` held, from every start in ``[x_lo, x_hi]`` and for every disturbance signal of the box
    #: (switching at any instant), for the numbers :attr:`held_box_params` (1-d float arrays; NaN where it finds no
    #: box). The model writes it once: :meth:`held_enclosure`, :meth:`held_tube_pieces` and their ``_box`` versions
    #: run it (:func:`~softreach.reach.proof.model_kernels.held_boxes`), and the filter's compiled decision and cells
    #: call it by address. It has no time argument: a model whose motion depends on ``t`` bounds it over every ``t``
    #: of the horizon. ``None``: no bound, and no filter
    held_box_kernel: Any = None
    held_box_params: np.ndarray = np.zeros(0)

    def held_enclosure(self, t: float, x: np.ndarray, a: np.ndarray, dt: float):
        """Boxes containing every trajectory of one control period with the control ``a`` held and any
        disturbance signal in the box (switching at any instant): ``(tube_lo, tube_hi, end_lo, end_hi)``, each
        ``(N, n)``; the tube holds ``x(s)`` for all ``s`` in ``[0, dt]``, the end box ``x(dt)``. From
        :attr:`held_box_kernel` (:meth:`held_enclosure_box` from the points).

        :param x: ``(N, n)`` states
        :param a: ``(N, m)`` physical controls (``(N,)`` for one control)
        :param dt: the control period [s]
        :raises ValueError: a bad shape or period, a state or control the model refuses, or a row the kernel
            finds no box for (NaN), naming it
        :raises NotImplementedError: the model gives no :attr:`held_box_kernel`
        """
        return _refuse_unbounded_rows(self, x, a, dt, self.held_enclosure_box(t, x, x, a, dt))

    def held_enclosure_box(self, t: float, x_lo: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float):
        """:meth:`held_enclosure` for every start in the box ``[x_lo, x_hi]`` (rows of ``(N, n)``), from
        :attr:`held_box_kernel`: the tube is its box over ``[0, dt]``, the end box over ``[dt, dt]``. A row with no
        box is NaN, which every caller reads as unbounded: not admissible."""
        return _kernel_boxes(self, "held_enclosure_box", x_lo, x_hi, a, dt)

    def held_tube_pieces_box(self, t: float, x_lo: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float,
                             pieces: int):
        """:meth:`held_tube_pieces` for every start in the box ``[x_lo, x_hi]``: :attr:`held_box_kernel` over each
        piece."""
        return _kernel_boxes(self, "held_tube_pieces_box", x_lo, x_hi, a, dt, pieces)

    def held_tube_pieces(self, t: float, x: np.ndarray, a: np.ndarray, dt: float, pieces: int):
        """Boxes ``(lo, hi)``, each ``(pieces, N, n)``, holding the motion over each of ``pieces`` equal
        sub-intervals of the period (control held, any disturbance signal): :meth:`held_tube_pieces_box` from the
        points. The budget bound of the safety filter charges each piece by its own box."""
        return self.held_tube_pieces_box(t, x, x, a, dt, pieces)

    def rk4_error(self, h: float) -> np.ndarray | None:
        """How far, per state axis, one RK4 sub-step of ``h`` seconds (the environments' integrator,
        :mod:`softreach.reach.sim.rk4`) may end from the exact motion of :attr:`held_box_kernel`'s bound, rounding
        aside, for every held control and disturbance signal: the environment's state after the sub-step is that of
        an exact motion within this distance. Zero where RK4 is exact for the motion: with the control and the
        disturbance held over a sub-step, a motion polynomial in time of degree at most 4 (the point mass's and the
        cart's are quadratic). ``None`` (the default): not known; then the filter proves the exact motion only
        (docs/filters.md, "Sound to the last bit"). The budget needs :meth:`rk4_stage_error` too."""
        return None

    def rk4_stage_error(self, h: float) -> np.ndarray | None:
        """How far, per state axis, the stage states of an RK4 sub-step of ``h`` seconds, where the environment reads
        the budget's rate, may lie outside :attr:`held_box_kernel`'s box over any interval holding the instant each
        stands for (the sub-step's start, middle and end), rounding aside. ``None`` (the default): not known; the
        filter then proves only the exact motion, as without :meth:`rk4_error`."""
        return None

    #: ``(lo, hi)`` of a box that holds the target set (``-inf``/``inf`` where unbounded), or ``None``. The safety
    #: filter skips its landing test for periods whose motion cannot meet this box; only speed depends on it
    target_box: tuple[tuple[float, ...], tuple[float, ...]] | None = None
    #: ``{"target": (lo, hi), "hard_constraint": ..., "soft_constraint": ...}`` where each of these set functions
    #: is exactly :func:`~softreach.reach.sets.box` of that box (``(lo, hi, scale)`` with a scale), time-invariant
    #: (``tests/test_compiled_filter.py`` checks it). It gives the default :attr:`set_max_kernel`; ``None``: not
    #: declared
    set_boxes: dict[str, tuple[tuple[float, ...], ...]] | None = None

    @property
    def set_max_kernel(self) -> Any:
        """The largest value of each set function over a box of states, compiled: a numba ``njit`` function ``(params,
        which, lo, hi) -> float`` for the numbers :attr:`set_max_params`, ``which`` the set's index in
        :data:`~softreach.reach.proof.model_kernels.SET_INDEX`, ``lo``, ``hi`` 1-d arrays. It must be the largest
        value of the (time-invariant) set function at the box's corners, which the safety filter's one-period test
        takes (:meth:`set_box_max`); ``tests/test_compiled_filter.py`` checks it for every model that gives one. The
        default is :func:`~softreach.reach.proof.model_kernels.boxes_set_max` where :attr:`set_boxes` are declared;
        ``None``: the filter evaluates the set functions at the corners in numpy, and has no compiled decision."""
        return boxes_set_max if self.set_boxes else None

    @property
    def set_max_params(self) -> np.ndarray:
        """The numbers :attr:`set_max_kernel` reads."""
        return box_params(self.set_boxes, self.state_dim) if self.set_boxes else np.zeros(0)

    def set_box_max(self, which: str, t: Any, lo: Any, hi: Any) -> Any:
        """An upper bound of a set function over boxes of states, or ``None`` when the largest value at the
        boxes' corners is one (the default: true for box distances and every function that is convex, or
        monotone, along each axis). The safety filter's one-period test bounds ``c1``, ``c2`` and ``g`` over
        boxes of reachable states this way; a model whose sets are not of that kind (the complement of a disc,
        as an obstacle) must override this, else that test is unsound.

        :param which: ``"target"``, ``"hard_constraint"`` or ``"soft_constraint"``
        :param t: time(s) [s]
        :param lo: ``(N, n)`` lower corners
        :param hi: ``(N, n)`` upper corners
        :return: ``(N,)`` upper bounds, or ``None``
        """
        return None

    #: cells per state axis over :attr:`hard_box` of the certificate the safety filter solves on cells
    #: (:mod:`softreach.reach.proof.cell_certificate`; ``None``: none, and the filter refuses the model), and the plan
    #: lengths [periods] of the landing game's cells
    cell_shape: tuple[int, ...] | None = None
    cell_holds: tuple[int, ...] = (1,)
    #: candidates a start's own plan may hold in sequence, 1 or 2
    #: (:meth:`softreach.filters.compiled.CompiledDecision.start_plans`)
    start_segments: int = 1


def _kernel_boxes(model: Any, method: str, x_lo: Any, x_hi: Any, a: Any, dt: Any, pieces: int | None = None
                 ) -> tuple[np.ndarray, ...]:
    """:class:`~softreach.reach.model_filter.FilterPart`'s boxes on checked arguments: the tube over ``[0, dt]`` and
    the end ``[dt, dt]``, ``(tube_lo, tube_hi, end_lo, end_hi)``; with ``pieces``, ``(lo, hi)`` over each equal part."""
    x_lo, x_hi, a, dt = _checked_rows(model, method, x_lo, x_hi, a, dt)
    if pieces is None:
        return held_boxes(model, x_lo, x_hi, a, 0.0, dt) + held_boxes(model, x_lo, x_hi, a, dt, dt)
    edges = np.linspace(0.0, dt, int(pieces) + 1)[:, None]  # every piece at once: (pieces, 1) against N rows
    return held_boxes(model, x_lo, x_hi, a, edges[:-1], edges[1:])


def _checked_rows(model: Any, method: str, x_lo: Any, x_hi: Any, a: Any, dt: Any
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """``model.method``'s arguments checked (shapes, corners, period, the model's validators), controls ``(N, m)``.

    :raises NotImplementedError: the model gives no ``held_box_kernel``
    :raises ValueError: naming the bad value
    """
    if model.held_box_kernel is None:
        raise NotImplementedError(f"{model.name} gives no held_box_kernel, from which {method} is derived; the safety "
                                  f"filter needs a validated bound of its motion over a held period")
    n, m = model.state_dim, model.control_dim
    x_lo, x_hi, a = (np.asarray(v, dtype=np.float64) for v in (x_lo, x_hi, a))
    if x_lo.ndim != 2 or x_lo.shape[1] != n or x_hi.shape != x_lo.shape:
        raise ValueError(f"{model.name}: states must have shape (N, {n}) ({', '.join(model.state_names)}), got "
                         f"{x_lo.shape}" + (f" (upper corners {x_hi.shape})" if x_hi.shape != x_lo.shape else ""))
    N = len(x_lo)
    if a.shape != (N, m) and not (m == 1 and a.shape == (N,)):
        raise ValueError(f"{model.name}: controls must have shape ({N}, {m}), one row per state, got {a.shape}")
    if x_hi is not x_lo and np.any(x_hi < x_lo):
        i = int(np.flatnonzero((x_hi < x_lo).any(axis=1))[0])
        raise ValueError(f"{model.name}: start box {i} has an upper corner below its lower one: {x_lo[i].tolist()} "
                         f".. {x_hi[i].tolist()}")
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"{model.name}: dt must be a finite positive period [s], got {dt!r}")
    validate_state = getattr(model, "validate_state", None)  # a Model's (reach.problem); plain Dynamics have none
    if N and validate_state is not None:
        validate_state(x_lo)
        if x_hi is not x_lo:
            validate_state(x_hi)
    if N:
        model.validate_control(a)
    return x_lo, x_hi, a.reshape(N, m), dt


def _refuse_unbounded_rows(model: Any, x: Any, a: Any, dt: float, boxes: tuple[np.ndarray, ...]
                          ) -> tuple[np.ndarray, ...]:
    """``boxes`` if every row is bounded, else ``ValueError`` naming the first NaN row (look-ahead: not admissible)."""
    failed = ~(np.isfinite(boxes[0]).all(axis=1) & np.isfinite(boxes[2]).all(axis=1))
    if not failed.any():
        return boxes
    i = int(np.flatnonzero(failed)[0])
    state = ", ".join(repr(float(v)) for v in np.asarray(x, dtype=np.float64)[i])
    action = ", ".join(repr(float(v)) for v in np.asarray(a, dtype=np.float64).reshape(len(failed), -1)[i])
    raise ValueError(f"{model.name}: no enclosure for row {i}: state ({', '.join(model.state_names)}) = ({state}), "
                     f"action ({action}), dt = {float(dt)!r} s ({int(failed.sum())} rows failed): its held_box_kernel "
                     f"found no box for this period (too long for that state); shorten dt")
