"""Dynamics of a two-player differential game ``x' = f(t, x, a, b)``.

Conventions used throughout softreach:

* the control ``a`` (player A) *minimises* the value and lies in a box ``[a_lo, a_hi]``;
* the disturbance ``b`` (player B) *maximises* it and lies in a box ``[b_lo, b_hi]``;
* states, controls, disturbances and co-states are passed as **sequences of arrays**, one array per
  component, so that a model evaluates on a grid by broadcasting (``v`` of shape ``(N1, 1, 1)`` times ``y`` of
  shape ``(1, N2, 1)``) and on a batch of points alike, with numpy or torch.

The Hamiltonian is ``H(t, x, p) = min_a max_b p . f(t, x, a, b)``. A model gives it in closed form together with
the dissipation bounds ``alpha_i >= |dH/dp_i|`` that the Lax-Friedrichs scheme needs.
"""

from __future__ import annotations

import itertools
from abc import ABC, abstractmethod
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from . import backend as B
from .boxes import box_check

Array = B.Array
Components = Sequence[Array]


class Dynamics(ABC):
    """A game's dynamics with box control and disturbance sets.

    Subclasses set ``name``, ``state_names``, ``state_units``, ``control_bounds`` and ``disturbance_bounds``
    and implement :meth:`f`, :meth:`hamiltonian`, :meth:`optimal_control`, :meth:`worst_disturbance`
    and :meth:`dissipation`.

    The declared bounds are checked where they are set: a class attribute when the class is defined, an
    instance attribute when it is assigned (``__init__`` included), each by its entry in :attr:`_CHECKS`. A box
    with ``lower > upper`` (which would invert the environment's action map and change the solved sets) is
    refused there, with a one-line error naming the model, the box and the bad values, before any work.
    """

    #: attribute -> its check ``(obj, value)`` (``obj`` the class or instance), which raises ``ValueError``;
    #: subclasses extend it
    _CHECKS: Mapping[str, Callable[[Any, Any], None]] = {
        "control_bounds": box_check("control_bounds"),
        "disturbance_bounds": box_check("disturbance_bounds"),
    }

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        for attr, check in cls._CHECKS.items():
            if attr in cls.__dict__:
                check(cls, cls.__dict__[attr])

    def __setattr__(self, attr: str, value: Any) -> None:
        check = self._CHECKS.get(attr)
        if check is not None:
            check(self, value)
        super().__setattr__(attr, value)

    name: str = "dynamics"
    state_names: tuple[str, ...] = ()
    state_units: tuple[str, ...] = ()
    #: ``(lo, hi)`` of the control box, each a tuple of floats of length ``m``
    control_bounds: tuple[tuple[float, ...], tuple[float, ...]] = ((), ())
    #: ``(lo, hi)`` of the disturbance box, each a tuple of floats of length ``k``
    disturbance_bounds: tuple[tuple[float, ...], tuple[float, ...]] = ((), ())

    @property
    def state_dim(self) -> int:
        return len(self.state_names)

    @property
    def control_dim(self) -> int:
        return len(self.control_bounds[0])

    @property
    def disturbance_dim(self) -> int:
        return len(self.disturbance_bounds[0])

    @abstractmethod
    def f(self, t: float, x: Components, a: Components, b: Components) -> list[Array]:
        """The vector field, one array per state component."""

    @abstractmethod
    def hamiltonian(self, t: float, x: Components, p: Components) -> Array:
        """``min_a max_b p . f(t, x, a, b)`` evaluated exactly."""

    @abstractmethod
    def optimal_control(self, t: float, x: Components, p: Components) -> list[Array]:
        """The minimising control for co-state ``p``."""

    @abstractmethod
    def worst_disturbance(self, t: float, x: Components, p: Components) -> list[Array]:
        """The maximising disturbance for co-state ``p`` (against the optimal control)."""

    @abstractmethod
    def dissipation(self, t: float, x: Components, p_lo: Components | None, p_hi: Components | None) -> list[Array | float]:
        """Bounds ``alpha_i >= |dH/dp_i|`` for co-states in the box ``[p_lo, p_hi]``.

        With ``p_lo = p_hi = None`` the bound must hold for every co-state (used for the CFL condition).
        """

    def running_cost(self, t: float, x: Components) -> Array | None:
        """A cost rate that the value accrues, added to the Hamiltonian and independent of both players (the
        budget surface's ``h_eps``); ``None``: none. A game that holds the control keeps it."""
        return None

    # ---------------------------------------------------------------- conveniences for batched points
    def f_array(self, t: float, x: Array, a: Array, b: Array) -> Array:
        """:meth:`f` on stacked arrays: ``x`` of shape ``(..., n)``, ``a`` ``(..., m)``, ``b`` ``(..., k)``."""
        xp = B.namespace(x, a, b)
        out = self.f(t, _unstack(x), _unstack(a), _unstack(b))
        shape = np.broadcast_shapes(*(tuple(o.shape) if hasattr(o, "shape") else () for o in out))
        out = [o + 0 * x[..., 0] if not hasattr(o, "shape") or tuple(o.shape) != shape else o for o in out]
        return xp.stack(out, -1) if xp is np else xp.stack(out, dim=-1)

    def clip_control(self, a: np.ndarray) -> np.ndarray:
        """Clip a ``(..., m)`` control to the control box."""
        return np.clip(a, self.control_bounds[0], self.control_bounds[1])

    def clip_disturbance(self, b: np.ndarray) -> np.ndarray:
        """Clip a ``(..., k)`` disturbance to the disturbance box."""
        return np.clip(b, self.disturbance_bounds[0], self.disturbance_bounds[1])

    def parameters(self) -> dict[str, Any]:
        """Model parameters recorded in table metadata (override to add more)."""
        return {}

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
    #: run it (:func:`~softreach.reach.proof.model_kernels.held_boxes`), and the filter's compiled decision calls it
    #: by address. It has no time argument: a model whose motion depends on ``t`` overrides the four methods
    #: instead. ``None``: no compiled bound
    held_box_kernel: Any = None
    held_box_params: np.ndarray = np.zeros(0)

    def validate_control(self, a: Any) -> None:
        """Raise ``ValueError`` naming a control the model cannot take; the default accepts every control."""

    def held_enclosure(self, t: float, x: np.ndarray, a: np.ndarray, dt: float):
        """Boxes containing every trajectory of one control period with the control ``a`` held and any
        disturbance signal in the box (switching at any instant): ``(tube_lo, tube_hi, end_lo, end_hi)``, each
        ``(N, n)``; the tube holds ``x(s)`` for all ``s`` in ``[0, dt]``, the end box ``x(dt)``.

        Derived from :attr:`held_box_kernel` (:meth:`held_enclosure_box` from the points). The safety filter's
        one-period look-ahead needs it; a model that cannot bound its motion is refused there.

        :param x: ``(N, n)`` states
        :param a: ``(N, m)`` physical controls (``(N,)`` for one control)
        :param dt: the control period [s]
        :raises ValueError: a bad shape or period, a state or control the model refuses, or a row the kernel
            finds no box for (NaN), naming it: the look-ahead reads that row as not admissible
        """
        from .proof.model_kernels import refuse_unbounded_rows

        return refuse_unbounded_rows(self, x, a, dt, self.held_enclosure_box(t, x, x, a, dt))

    def held_enclosure_box(self, t: float, x_lo: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float):
        """:meth:`held_enclosure` for every start in the box ``[x_lo, x_hi]`` (rows of ``(N, n)``), from
        :attr:`held_box_kernel`: the tube is its box over ``[0, dt]``, the end box over ``[dt, dt]``. A row with no
        box is NaN, which every caller reads as unbounded: not admissible. The filter's cells need it."""
        from .proof.model_kernels import kernel_boxes

        return kernel_boxes(self, "held_enclosure_box", x_lo, x_hi, a, dt)

    def held_tube_pieces_box(self, t: float, x_lo: np.ndarray, x_hi: np.ndarray, a: np.ndarray, dt: float,
                             pieces: int):
        """:meth:`held_tube_pieces` for every start in the box ``[x_lo, x_hi]``: :attr:`held_box_kernel` over each
        piece; without a kernel, the whole tube of the model's own :meth:`held_enclosure_box` for every piece."""
        from .proof.model_kernels import kernel_boxes

        if self.held_box_kernel is None:
            lo, hi, _, _ = self.held_enclosure_box(t, x_lo, x_hi, a, dt)
            return np.broadcast_to(lo, (pieces,) + lo.shape), np.broadcast_to(hi, (pieces,) + hi.shape)
        return kernel_boxes(self, "held_tube_pieces_box", x_lo, x_hi, a, dt, pieces)

    def held_tube_pieces(self, t: float, x: np.ndarray, a: np.ndarray, dt: float, pieces: int):
        """Boxes ``(lo, hi)``, each ``(pieces, N, n)``, holding the motion over each of ``pieces`` equal
        sub-intervals of the period (control held, any disturbance signal): :meth:`held_tube_pieces_box` from the
        points. The budget bound of the safety filter charges each piece by its own box. Without a kernel every
        piece gets the whole tube of the model's own :meth:`held_enclosure` (sound, a coarser budget bound)."""
        if self.held_box_kernel is None:
            lo, hi, _, _ = self.held_enclosure(t, x, a, dt)
            return np.broadcast_to(lo, (pieces,) + lo.shape), np.broadcast_to(hi, (pieces,) + hi.shape)
        return self.held_tube_pieces_box(t, x, x, a, dt, pieces)


def bounds_motion(model: Any) -> bool:
    """Whether ``model`` bounds its held motion from states: a :attr:`Dynamics.held_box_kernel`, or its own
    :meth:`Dynamics.held_enclosure` or :meth:`Dynamics.held_enclosure_box` (from which the points' one follows)."""
    return model.held_box_kernel is not None or type(model).held_enclosure is not Dynamics.held_enclosure or (
        bounds_boxes(model))


def bounds_boxes(model: Any) -> bool:
    """Whether ``model`` bounds the motion from boxes of starts (a :attr:`Dynamics.held_box_kernel`, or its own
    :meth:`Dynamics.held_enclosure_box`): what the filter's cells and its "the next state is certified again" rule
    need."""
    return model.held_box_kernel is not None or type(model).held_enclosure_box is not Dynamics.held_enclosure_box


def _unstack(x: Array) -> list[Array]:
    return [x[..., i] for i in range(x.shape[-1])]


def _dot_column(p: Components, column: Sequence[Any]) -> Array | float:
    """``sum_i p_i * M_ij`` skipping structural zeros (entries that are the Python number 0)."""
    out: Any = 0.0
    for pi, mij in zip(p, column):
        if isinstance(mij, (int, float)) and mij == 0:
            continue
        out = out + pi * mij
    return out


class ControlAndDisturbanceAffine(Dynamics):
    """``f = drift(t, x) + G(t, x) a + E(t, x) b`` with box sets: Hamiltonian, optimal inputs and
    dissipation in closed form.

    ``control_matrix`` and ``disturbance_matrix`` return nested lists ``M[i][j]`` (state row ``i``, input
    column ``j``) whose entries are arrays or numbers; write structural zeros as the number ``0`` so that the
    scheme skips them.
    """

    @abstractmethod
    def drift(self, t: float, x: Components) -> list[Array | float]:
        """The input-free part of ``f``."""

    @abstractmethod
    def control_matrix(self, t: float, x: Components) -> list[list[Array | float]]:
        """``G(t, x)`` as ``G[i][j]``."""

    @abstractmethod
    def disturbance_matrix(self, t: float, x: Components) -> list[list[Array | float]]:
        """``E(t, x)`` as ``E[i][k]``."""

    def f(self, t, x, a, b):
        f0 = self.drift(t, x)
        G = self.control_matrix(t, x)
        E = self.disturbance_matrix(t, x)
        out = []
        for i in range(self.state_dim):
            fi = f0[i]
            for j, aj in enumerate(a):
                if not (isinstance(G[i][j], (int, float)) and G[i][j] == 0):
                    fi = fi + G[i][j] * aj
            for k, bk in enumerate(b):
                if not (isinstance(E[i][k], (int, float)) and E[i][k] == 0):
                    fi = fi + E[i][k] * bk
            out.append(fi)
        return out

    def _switching(self, t, x, p):
        G = self.control_matrix(t, x)
        E = self.disturbance_matrix(t, x)
        s_a = [_dot_column(p, [G[i][j] for i in range(self.state_dim)]) for j in range(self.control_dim)]
        s_b = [_dot_column(p, [E[i][k] for i in range(self.state_dim)]) for k in range(self.disturbance_dim)]
        return s_a, s_b

    def hamiltonian(self, t, x, p):
        f0 = self.drift(t, x)
        h: Any = _dot_column(p, f0)
        s_a, s_b = self._switching(t, x, p)
        (a_lo, a_hi), (b_lo, b_hi) = self.control_bounds, self.disturbance_bounds
        for s, lo, hi in zip(s_a, a_lo, a_hi):
            h = h + B.minimum(s * lo, s * hi) if hasattr(s, "shape") else h + min(s * lo, s * hi)
        for s, lo, hi in zip(s_b, b_lo, b_hi):
            h = h + B.maximum(s * lo, s * hi) if hasattr(s, "shape") else h + max(s * lo, s * hi)
        return h

    def optimal_control(self, t, x, p):
        s_a, _ = self._switching(t, x, p)
        lo, hi = self.control_bounds
        # On a switching surface (s = 0) every input is optimal; the midpoint avoids a bias.
        return [_bang(s, l, h) for s, l, h in zip(s_a, lo, hi)]

    def worst_disturbance(self, t, x, p):
        _, s_b = self._switching(t, x, p)
        lo, hi = self.disturbance_bounds
        return [_bang(s, h, l) for s, l, h in zip(s_b, lo, hi)]

    def dissipation(self, t, x, p_lo=None, p_hi=None):
        """Interval bound on ``|f_i|`` over the inputs that are optimal somewhere in the co-state box.

        For an input whose switching function ``s_j = (p^T G)_j`` keeps one sign over the box only one end of
        its interval can be optimal, which is what makes this local Lax-Friedrichs bound tighter than the
        global ``max |f_i|`` (the idea of the LLLF scheme of Osher and Shu). For a row of ``f`` that no input
        enters (e.g. ``y' = v``) the bound is ``|f_i|`` itself, so the scheme upwinds that direction exactly.
        """
        f0 = self.drift(t, x)
        G = self.control_matrix(t, x)
        E = self.disturbance_matrix(t, x)
        n = self.state_dim
        parts = [(G, self.control_bounds, self.control_dim, True), (E, self.disturbance_bounds, self.disturbance_dim, False)]
        switching = None
        if p_lo is not None:
            switching = [_interval_dot(p_lo, p_hi, M, n, m) for M, _, m, _ in parts]
        out = []
        for i in range(n):
            lo: Any = f0[i]
            hi: Any = f0[i]
            for part, (M, (b_lo, b_hi), m, minimiser) in enumerate(parts):
                for j in range(m):
                    g = M[i][j]
                    if isinstance(g, (int, float)) and g == 0:
                        continue
                    c_lo, c_hi = g * b_lo[j], g * b_hi[j]
                    if switching is None:
                        lo = lo + B.minimum(c_lo, c_hi) if hasattr(c_lo, "shape") else lo + min(c_lo, c_hi)
                        hi = hi + B.maximum(c_lo, c_hi) if hasattr(c_lo, "shape") else hi + max(c_lo, c_hi)
                        continue
                    s_lo, s_hi = switching[part][0][j], switching[part][1][j]
                    if not hasattr(s_lo, "shape"):
                        s_lo, s_hi = s_lo + 0 * p_lo[0], s_hi + 0 * p_lo[0]
                    ref = 0 * s_lo
                    c_lo, c_hi = c_lo + ref, c_hi + ref
                    # the minimiser takes b_lo where s > 0, the maximiser takes b_hi there
                    lo_possible = ~(s_hi < 0) if minimiser else ~(s_lo > 0)
                    hi_possible = ~(s_lo > 0) if minimiser else ~(s_hi < 0)
                    inf = float("inf")
                    lo = lo + B.minimum(B.where(lo_possible, c_lo, ref + inf), B.where(hi_possible, c_hi, ref + inf))
                    hi = hi + B.maximum(B.where(lo_possible, c_lo, ref - inf), B.where(hi_possible, c_hi, ref - inf))
            out.append(_abs_max(lo, hi))
        return out


def _abs_max(lo: Any, hi: Any) -> Any:
    if hasattr(lo, "shape") or hasattr(hi, "shape"):
        a = abs(lo)
        b = abs(hi)
        return B.maximum(a, b) if hasattr(a, "shape") else B.maximum(b, a)
    return max(abs(lo), abs(hi))


def _interval_dot(p_lo, p_hi, M, n, m):
    """Interval of ``s_j = sum_i p_i M_ij`` for ``p`` in the box ``[p_lo, p_hi]``."""
    s_lo, s_hi = [], []
    for j in range(m):
        lo: Any = 0.0
        hi: Any = 0.0
        for i in range(n):
            mij = M[i][j]
            if isinstance(mij, (int, float)) and mij == 0:
                continue
            u, w = p_lo[i] * mij, p_hi[i] * mij
            lo = lo + B.minimum(u, w)
            hi = hi + B.maximum(u, w)
        s_lo.append(lo)
        s_hi.append(hi)
    return s_lo, s_hi


def _bang(s: Any, when_positive: float, when_negative: float) -> Any:
    mid = 0.5 * (when_positive + when_negative)
    if not hasattr(s, "shape"):
        return when_positive if s > 0 else (when_negative if s < 0 else mid)
    xp = B.namespace(s)
    ref = xp.zeros_like(s)
    return B.where(s > 0, ref + when_positive, B.where(s < 0, ref + when_negative, ref + mid))


def row_time(t: np.ndarray) -> Any:
    """The time argument of a model's methods for rows at times ``t``: one float where every row has the same time
    (the models evaluate faster on a scalar), else the array."""
    return float(t[0]) if len(t) and np.all(t == t[0]) else t
