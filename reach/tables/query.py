"""Query a solved table: values, gradients, optimal inputs, ``Q_min`` and the reach-avoid sets."""

from __future__ import annotations

import math
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ..inputs import column, points
from ..numerics.grid import Grid
from ..numerics.budget_surface import no_budget_suffices
from .interpolation import Interpolant
from .table import TableError, field_grid, open_field, read_header, verify

#: the paper's conservative proxy for ``Q > 0`` (§VI-A): ``W_eps + 1e-3 <= 0``, in seconds of budget
PAPER_PROXY_SECONDS = 1e-3


def load_table(path: str | Path, verify_checksum: bool = True) -> "Table":
    """Open a table written by ``softreach solve``.

    :param path: the ``.srt`` file
    :param verify_checksum: recompute the SHA-256 of the data (streamed; turn off only for trusted files)
    :raises TableError: corrupted, truncated, incomplete or unsupported file (the message says which)
    """
    path = Path(path)
    header = read_header(path)
    if verify_checksum:
        verify(path, header)
    return Table(path, header)


class Table:
    """A solved table: the classical value ``V(t, x)`` and/or the soft value ``W_eps(t, x, z)``.

    All queries are batched: ``x`` has shape ``(N, n)`` (or ``(n,)``), ``t`` and ``z`` are scalars or ``(N,)``.
    Outside the grid or the table's time span the value is ``+inf`` (unsafe), never NaN. A budget above the grid's
    top (the horizon) is treated as the top: no trajectory can spend more than the horizon. A negative budget is
    unsafe.
    """

    def __init__(self, path: Path, header: dict[str, Any]):
        self.path = path
        self.header = header
        self.fields = sorted(header["fields"])
        self._arrays: dict[str, np.ndarray] = {}
        self._interpolants: dict[str, Interpolant] = {}

    # ------------------------------------------------------------------ metadata
    @property
    def model_metadata(self) -> dict[str, Any]:
        return self.header["model"]

    @cached_property
    def model(self):
        """The model the table was solved for, rebuilt from its metadata."""
        from ..models import model_from_metadata

        return model_from_metadata(self.model_metadata)

    @property
    def has_budget(self) -> bool:
        return "W_eps" in self.header["fields"]

    @property
    def has_budget_surface(self) -> bool:
        """Whether the table holds ``Q_min(t, x)`` on the state grid (``softreach solve --budget-surface``)."""
        return "Q_min" in self.header["fields"]

    @property
    def eps(self) -> float | None:
        for name in ("W_eps", "Q_min"):
            if name in self.header["fields"]:
                return self.header["fields"][name]["problem"]["eps"]
        return None

    @property
    def budget_scale(self) -> float:
        return self.header["fields"]["W_eps"]["problem"]["budget_scale"] if self.has_budget else 1.0

    @property
    def control_period(self) -> float | None:
        """The period [s] of the sampled-data game the table was solved for (actions held that long, snapshots
        at the sample times); ``None`` for the continuous-time game."""
        value = self.header["fields"][self._default_field()].get("control_period")
        return None if value is None else float(value)

    def grid(self, field: str | None = None) -> Grid:
        return field_grid(self.header, field or self._default_field())

    def times(self, field: str | None = None) -> np.ndarray:
        return np.asarray(self.header["fields"][field or self._default_field()]["times"], dtype=np.float64)

    @property
    def horizon(self) -> float:
        return float(self.times()[-1])

    @property
    def budget_resolution(self) -> float:
        """Half a budget cell: the smallest budget the grid resolves (see :meth:`set_mask`); 0 for a budget-surface
        table, which resolves every budget."""
        if not self.has_budget:
            return 0.0
        return 0.5 * self.grid("W_eps").spacing[-1]

    def values(self, field: str) -> np.ndarray:
        """The memory-mapped block of ``field``: shape ``(n_times, *grid.shape)``."""
        if field not in self.header["fields"]:
            raise KeyError(f"table {self.path} has no field {field!r}; it has {self.fields}")
        if field not in self._arrays:
            self._arrays[field] = open_field(self.path, self.header, field)
        return self._arrays[field]

    def interpolant(self, field: str) -> Interpolant:
        """The interpolation engine of ``field`` (values, gradients along every axis, slices); ``W_eps``'s last
        axis is the budget: below its grid is outside, above it is read at its top."""
        if field not in self._interpolants:
            self._interpolants[field] = Interpolant(self.values(field), self.times(field), self.grid(field),
                                                    budget_last=field == "W_eps",
                                                    gradient_axes=range(self.grid(field).ndim))
        return self._interpolants[field]

    def summary(self) -> dict[str, Any]:
        return self.header.get("summary", {})

    def check_compatible(self, model: Any) -> None:
        """Raise :class:`TableError` unless the table was solved for ``model`` (name and parameters)."""
        from .table import _first_mismatch

        mine, theirs = self.model_metadata, model.metadata()
        if mine["name"] != theirs["name"]:
            raise TableError(f"table {self.path} was solved for model {mine['name']!r}, not {theirs['name']!r}")
        mismatch = _first_mismatch(mine["parameters"], theirs["parameters"])
        if mismatch:
            raise TableError(f"table {self.path} was solved for other {mine['name']} parameters: {mismatch}")

    def _default_field(self) -> str:
        return "W_eps" if self.has_budget else "V"

    # ------------------------------------------------------------------ values
    def _field_for(self, z: Any) -> str:
        if z is None:
            if "V" not in self.header["fields"]:
                raise ValueError(f"table {self.path} holds only W_eps: pass the budget z")
            return "V"
        if self.has_budget:
            return "W_eps"
        if self.has_budget_surface:
            return "Q_min"
        raise ValueError(f"table {self.path} holds only the classical V: call without z")

    def _rows(self, t: Any, x: Any) -> tuple[np.ndarray, np.ndarray]:
        """The query's times ``(N,)`` and states ``(N, n)``, checked (:mod:`softreach.reach.inputs`)."""
        names = self.model_metadata["state_names"]
        pts = points(x, len(names), "x", names)[0]
        return column(t, len(pts), "t"), pts

    def _queries(self, t: Any, x: Any, z: Any) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
        field = self._field_for(z)
        tt, pts = self._rows(t, x)
        unsafe = np.zeros(len(pts), bool)
        if field == "W_eps":  # below the budget grid and above it: the interpolant's budget_last rule
            pts = np.concatenate([pts, column(z, len(pts), "z")[:, None]], axis=1)
        elif field == "Q_min":
            unsafe = column(z, len(pts), "z") < 0
        return field, tt, pts, unsafe

    def value(self, t: Any, x: Any, z: Any = None) -> np.ndarray:
        """``V(t, x)`` (``z=None``) or ``W_eps(t, x, z)`` by multilinear interpolation; ``+inf`` outside.

        A budget above the table's largest is read at the largest: exact when that is at least the horizon (no
        episode can spend more than its time), conservative otherwise (``W_eps`` falls with the budget).
        """
        field, tt, pts, unsafe = self._queries(t, x, z)
        val = self.interpolant(field).value(tt, pts)
        if field == "Q_min":
            # the certificate of a budget-surface table: Q_min - z, <= 0 exactly where the budget z suffices
            # (RA~_0 from V, as set_mask reads it)
            val = val - column(z, len(pts), "z")
            v = self.interpolant("V").value(tt, pts)
            val = np.where(np.isfinite(val) & (v <= 0), np.minimum(val, v), val)
        return np.where(unsafe, np.inf, val)

    def inside(self, t: Any, x: Any, z: Any = None) -> np.ndarray:
        """Whether each query lies inside the table's grid and time span."""
        return np.isfinite(self.value(t, x, z))

    def gradient(self, t: Any, x: Any, z: Any = None, outside: str = "raise") -> np.ndarray:
        """Spatial gradient (including ``dW/dz`` for ``W_eps``): the central difference of the interpolant over one
        grid spacing on either side (shifted inwards at the grid's edges), :class:`~.interpolation.Interpolant`.

        :param outside: for queries off the table's grid or time span: ``"raise"`` (a ``ValueError`` naming the
            first such query) or ``"nearest"`` (use the nearest point of the grid box and time span: a
            feedback that keeps acting, e.g. a wind model, where :meth:`inside` says it is extrapolating)
        """
        if outside not in ("raise", "nearest"):
            raise ValueError(f"outside must be 'raise' or 'nearest', got {outside!r}")
        field, tt, pts, _ = self._queries(t, x, z)
        _, grad, loc = self.interpolant(field).value_and_gradient(tt, pts)
        if outside == "raise" and not loc.inside.all():
            i = int(np.argmin(loc.inside))
            grid, times = self.grid(field), self.times(field)
            raise ValueError(f"query t={tt[i]!r}, point {pts[i].tolist()} lies outside table {self.path} (grid "
                             f"box {list(grid.lo)}..{list(grid.hi)}, times {times[0]}..{times[-1]}): no gradient "
                             f"there; pass outside='nearest' to use the nearest grid point")
        return grad

    def _inputs(self, t: Any, x: Any, z: Any, which: str, outside: str) -> np.ndarray:
        if z is not None and self.has_budget:
            # at z = 0 the exact W_eps is flat (>= 0 everywhere, = 0 on RA~_0): its gradient says nothing. Use the
            # smallest budget the grid resolves, as set_mask does.
            z = np.maximum(np.asarray(z, dtype=np.float64), self.budget_resolution)
        field, tt, pts, _ = self._queries(t, x, z)
        p = self.gradient(t, x, z, outside)
        if field == "Q_min":
            # on the classical RA Q_min is 0, flat: its gradient says nothing there (both players would idle). The
            # certificate is V where V <= 0 and below Q_min - z (value()), so its gradient is V's
            zz = column(z, len(pts), "z")
            v = self.interpolant("V").value(tt, pts)
            on_v = (zz >= 0) & (v <= 0) & (v < self.interpolant("Q_min").value(tt, pts) - zz)
            if on_v.any():
                p = np.where(on_v[:, None], self.gradient(t, x, None, outside), p)
        n = len(self.model_metadata["state_names"])
        xs = [pts[:, i] for i in range(n)]
        ps = [p[:, i] for i in range(n)]
        fn = self.model.optimal_control if which == "control" else self.model.worst_disturbance
        # z' does not depend on either player, so dW/dz does not enter the optimal inputs
        out = fn(float(tt[0]) if np.all(tt == tt[0]) else tt, xs, ps)
        return np.stack([np.broadcast_to(np.asarray(o, dtype=np.float64), (len(pts),)) for o in out], axis=1)

    def optimal_control(self, t: Any, x: Any, z: Any = None, outside: str = "raise") -> np.ndarray:
        """``a* = argmin_a max_b grad W . f`` at each query, shape ``(N, m)``, physical units.

        :param outside: off the table: ``"raise"`` or ``"nearest"`` (see :meth:`gradient`)
        """
        return self._inputs(t, x, z, "control", outside)

    def worst_disturbance(self, t: Any, x: Any, z: Any = None, outside: str = "raise") -> np.ndarray:
        """``b* = argmax_b`` against the optimal control, shape ``(N, k)``, physical units.

        :param outside: off the table: ``"raise"`` or ``"nearest"`` (see :meth:`gradient`)
        """
        return self._inputs(t, x, z, "disturbance", outside)

    # ------------------------------------------------------------------ budgets and sets
    def q_min(self, t: Any, x: Any) -> np.ndarray:
        """``Q_min(t, x)``: the smallest budget with ``W_eps <= 0`` (eq. Q_min); ``inf`` if none up to the horizon.

        Found along the budget nodes and refined linearly between them; budgets below
        :attr:`budget_resolution` are reported as 0, consistently with :meth:`set_mask`.
        """
        tt, pts = self._rows(t, x)
        if self.has_budget_surface and not self.has_budget:
            q = self.interpolant("Q_min").value(tt, pts)
            q = np.where(np.isfinite(q) & ~no_budget_suffices(q, self.horizon - tt), np.maximum(q, 0.0), np.inf)
            return np.where(self.value(tt, pts) <= 0, 0.0, q)  # RA~_0 from V, as set_mask reads it
        grid = self.grid("W_eps")
        z_nodes = grid.axis(grid.ndim - 1)
        z_nodes = np.concatenate([[self.budget_resolution], z_nodes[z_nodes > self.budget_resolution]])
        vals = np.stack([self.value(tt, pts, np.full(len(pts), z)) for z in z_nodes], axis=1)
        out = np.full(len(pts), np.inf)
        ok = vals <= 0
        first = np.argmax(ok, axis=1)
        has = ok.any(axis=1)
        for i in np.nonzero(has)[0]:
            j = first[i]
            if j == 0:
                out[i] = 0.0
            else:
                w0, w1 = vals[i, j - 1], vals[i, j]
                frac = w0 / (w0 - w1) if np.isfinite(w0) and w0 != w1 else 1.0
                out[i] = z_nodes[j - 1] + frac * (z_nodes[j] - z_nodes[j - 1])
        return out

    def slice(self, field: str, t: float, z: float | None = None) -> np.ndarray:
        """``field`` at time ``t`` on its state grid's nodes, at budget ``z`` for ``W_eps`` (clamped to the budget
        grid): the raw slice; :meth:`set_mask` applies the budget rule to it.

        :raises ValueError: ``t`` outside the table's time span
        """
        return self.interpolant(field).slice(float(t), None if z is None else float(z))

    def set_mask(self, t: float = 0.0, budget: float | None = None, margin: float | None = None) -> np.ndarray:
        """The reach-avoid set at time ``t`` as a boolean mask over the state grid (:meth:`_in_set`'s rule at the
        nodes).

        * ``budget=None``: the classical ``RA = {V + margin <= 0}``.
        * ``budget=Q``: ``RA~_Q = {W_eps(t, x, max(Q, r)) + margin <= 0}`` with ``r`` the
          :attr:`budget_resolution`. The exact ``W_eps(t, x, 0)`` is ``>= 0`` everywhere (``l >= -kappa z``), so
          ``RA~_0`` is the flat face ``{W_eps = 0}`` of the set in ``(x, z)``: a slice along it is ill-posed on a
          grid. It is taken as the limit from above (``RA~_0 = ∩_{Q>0} RA~_Q``, Prop. 4) at the smallest budget
          the grid resolves, half a budget cell.
        * ``margin`` (value units) defaults to 0 for every budget, which keeps the sets nested in ``Q`` (Prop. 4).
          The paper's conservative proxy for ``Q > 0`` (§VI-A) is ``W_eps + 1e-3 <= 0`` with ``kappa = 1``: one
          millisecond of budget. Here ``W_eps`` is scaled by the table's ``kappa`` (:attr:`budget_scale`), so the
          proxy is ``W_eps + kappa * 1e-3 <= 0``, ``margin = paper_proxy_margin()`` (0.05 for the point mass,
          ``kappa = 50``). Applied to ``Q > 0`` only it would break the nesting with ``Q = 0`` at a few boundary
          nodes.
        * A budget-surface table (``Q_min`` on the state grid): ``RA~_Q = {Q_min(t, x) + margin <= Q}`` (where
          ``Q_min`` says some budget suffices), together with ``RA``.
        """
        return self.set_level(t, budget, margin) <= 0

    def set_level(self, t: float = 0.0, budget: float | None = None, margin: float | None = None) -> np.ndarray:
        """A function over the state grid's nodes whose zero sublevel set is :meth:`set_mask` (``set_mask`` is
        ``set_level <= 0``): ``V + margin``, ``W_eps(t, x, max(Q, r)) + margin``, or for a budget-surface table
        the smaller (``nan`` ignored) of ``Q_min + margin - Q`` (``+inf`` where no budget suffices) and ``V + margin``. Its zero
        contour, interpolated between nodes, is the set's smooth outline; a boolean mask only gives a staircase.
        """
        if margin is None:
            margin = 0.0
        if budget is None:
            return self._level(lambda field, z: self.slice(field, t), None, margin, t)
        q = float(budget)
        if not (math.isfinite(q) and q >= 0):
            raise ValueError(f"budget must be a finite number >= 0, got {budget!r}")
        return self._level(lambda field, z: self.slice(field, t, z), q, margin, float(t))

    def contains(self, t: Any, x: Any, budget: Any = None, margin: float = 0.0) -> np.ndarray:
        """Membership of states in the set :meth:`set_mask` draws, by the same rule (:meth:`_in_set`) evaluated at
        the states themselves (interpolated): ``RA`` with ``budget=None``, else ``RA~_Q``. Off the table: not
        contained.

        :param x: ``(N, n)`` or ``(n,)`` states; ``t`` and ``budget`` scalars or ``(N,)``
        """
        tt, pts = self._rows(t, x)

        def read(field: str, z: Any) -> np.ndarray:
            X = pts if z is None else np.concatenate([pts, np.broadcast_to(z, (len(pts),))[:, None]], axis=1)
            return self.interpolant(field).value(tt, X)

        if budget is None:
            return self._in_set(read, None, margin, tt)
        q = column(budget, len(pts), "budget")
        if np.any(q < 0):
            raise ValueError(f"budget must be >= 0, got {q[q < 0][0]!r}")
        return self._in_set(read, q, margin, tt)

    def _in_set(self, read: Any, q: Any, margin: float, t: Any) -> np.ndarray:
        """The one membership rule of :meth:`set_mask` (nodes) and :meth:`contains` (states): :meth:`_level`
        ``<= 0``."""
        return self._level(read, q, margin, t) <= 0

    def _level(self, read: Any, q: Any, margin: float, t: Any) -> np.ndarray:
        """The level function of the sets on values that ``read(field, z)`` gives at the nodes or at the states,
        at budget ``z`` along ``W_eps``'s last axis. ``a + m - q <= 0`` is ``a + m <= q`` exactly in IEEE
        arithmetic (the difference of two unequal floats is never zero)."""
        if q is None:
            return read("V", None) + margin
        if not self.has_budget and self.has_budget_surface:
            # {Q_min <= 0} is a flat face of Q_min, as {W_eps(., 0) <= 0} is of W_eps: the classical V beside it
            # gives RA~_0 (Prop. 3), and every RA~_Q contains it
            qm = read("Q_min", None)
            by_budget = np.where(no_budget_suffices(qm, self.horizon - t), np.inf, qm + margin - q)
            return np.fmin(by_budget, read("V", None) + margin)
        return read("W_eps", np.maximum(q, self.budget_resolution)) + margin

    def paper_proxy_margin(self) -> float:
        """The margin of the paper's proxy ``W_eps + 1e-3 <= 0`` (``kappa = 1`` there) in this table's value units:
        ``kappa * 1e-3``, one millisecond of budget (see :meth:`set_mask`)."""
        return self.budget_scale * PAPER_PROXY_SECONDS

    def cell_volume(self, field: str | None = None) -> float:
        g = self.grid(field)
        n = len(self.model_metadata["state_names"])
        return float(np.prod(g.spacing[:n]))

    def set_measure(self, t: float = 0.0, budget: float | None = None, margin: float | None = None) -> float:
        """Measure of :meth:`set_mask` in state units (node count times cell volume)."""
        field = "V" if budget is None else self._field_for(budget)
        return float(self.set_mask(t, budget, margin).sum()) * self.cell_volume(field)

    def budget_band_mask(self, t: float, q1: float, q2: float) -> np.ndarray:
        """``RA~_(q1, q2] = RA~_q2 minus RA~_q1`` (Thm. 4): the states whose ``Q_min`` lies in ``(q1, q2]``."""
        if not q1 < q2:
            raise ValueError(f"need q1 < q2, got q1={q1!r}, q2={q2!r}")
        return self.set_mask(t, q2) & ~self.set_mask(t, q1)

    def state_axes(self, field: str | None = None) -> list[np.ndarray]:
        g = self.grid(field)
        n = len(self.model_metadata["state_names"])
        return [g.axis(i) for i in range(n)]
