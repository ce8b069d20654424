"""Cartesian grids of 1 to 5 dimensions with uniform spacing."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import backend as B

MAX_DIMS = 5


@dataclass(frozen=True)
class Grid:
    """A uniform Cartesian grid.

    Non-periodic axes have nodes at both ends (``lo`` and ``hi`` are nodes, spacing ``(hi - lo) / (N - 1)``);
    periodic axes have ``N`` nodes on ``[lo, hi)`` (spacing ``(hi - lo) / N``).

    :param lo: lower corner
    :param hi: upper corner
    :param shape: nodes per axis
    :param periodic: per-axis periodicity (default: none)
    :param names: per-axis names (for messages and metadata)
    """

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    shape: tuple[int, ...]
    periodic: tuple[bool, ...] = field(default=())
    names: tuple[str, ...] = field(default=())

    def __post_init__(self):
        lo, hi, shape = tuple(map(float, self.lo)), tuple(map(float, self.hi)), tuple(self.shape)
        n = len(shape)
        if not 1 <= n <= MAX_DIMS:
            raise ValueError(f"a grid has 1 to {MAX_DIMS} dimensions, got shape {shape!r}")
        if len(lo) != n or len(hi) != n:
            raise ValueError(f"lo {lo!r}, hi {hi!r} and shape {shape!r} must have the same length")
        for i, s in enumerate(shape):
            if isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s < 2:
                raise ValueError(f"grid size along axis {i} must be an integer >= 2, got {s!r}")
        for i, (a, b) in enumerate(zip(lo, hi)):
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ValueError(f"grid bounds along axis {i} must be finite, got [{a!r}, {b!r}]")
            if not a < b:
                raise ValueError(f"grid bounds along axis {i} must satisfy lo < hi, got [{a!r}, {b!r}]")
        periodic = tuple(bool(p) for p in self.periodic) or (False,) * n
        names = tuple(self.names) or tuple(f"x{i}" for i in range(n))
        if len(periodic) != n or len(names) != n:
            raise ValueError("periodic and names must have one entry per axis")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "shape", tuple(int(s) for s in shape))
        object.__setattr__(self, "periodic", periodic)
        object.__setattr__(self, "names", names)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def spacing(self) -> tuple[float, ...]:
        return tuple((h - l) / (n if p else n - 1) for l, h, n, p in zip(self.lo, self.hi, self.shape, self.periodic))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def cell_volume(self) -> float:
        return float(np.prod(self.spacing))

    def axis(self, i: int) -> np.ndarray:
        """Node coordinates along axis ``i``."""
        return self.lo[i] + self.spacing[i] * np.arange(self.shape[i])

    def coordinates(self, backend: str = "numpy", dtype: str = "float64", device: str = "cpu") -> list[Any]:
        """Node coordinates as broadcastable arrays: axis ``i`` has shape ``(1, .., N_i, .., 1)``."""
        out = []
        for i in range(self.ndim):
            shape = [1] * self.ndim
            shape[i] = self.shape[i]
            out.append(B.asarray(self.axis(i).reshape(shape), backend, dtype, device))
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"lo": list(self.lo), "hi": list(self.hi), "shape": list(self.shape),
                "periodic": list(self.periodic), "names": list(self.names)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Grid":
        return cls(tuple(d["lo"]), tuple(d["hi"]), tuple(d["shape"]), tuple(d["periodic"]), tuple(d["names"]))


def budget_axis(horizon: float, n_points: int, below_zero: int | None = None) -> tuple[float, float, int]:
    """The budget axis ``z``: ``n_points`` nodes with ``z = 0`` a node and ``z = horizon`` the last one.

    Nodes below zero (about a tenth of them, at least 3 so that WENO5's stencil at ``z = 0`` reads no ghost
    cell) carry the inflow side of the ``z`` axis: budget only decreases, so information enters from below.

    :return: ``(z_lo, z_hi, n_points)``
    """
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 8:
        raise ValueError(f"budget points must be an integer >= 8, got {n_points!r}")
    if not (math.isfinite(horizon) and horizon > 0):
        raise ValueError(f"horizon must be positive and finite, got {horizon!r}")
    k = below_zero if below_zero is not None else max(3, round((n_points - 1) / 11))
    dz = horizon / (n_points - 1 - k)
    return -k * dz, horizon, int(n_points)
