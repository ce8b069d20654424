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

    def validate_control(self, a: Any) -> None:
        """Raise ``ValueError`` naming a control the model cannot take; the default accepts every control."""


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
