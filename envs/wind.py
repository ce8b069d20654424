"""The environments' winds: none, an Ornstein-Uhlenbeck gust, a constant, or a table's worst case ``b*``."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

import gymnasium as gym

from softreach.reach.problem import Model

WIND_MODES = ("none", "random", "constant", "adversarial")


class OrnsteinUhlenbeckGust:
    """A bounded Ornstein-Uhlenbeck gust, sampled exactly at the control period and clipped to a box.

    ``b' = -(b - mean) / tau + std sqrt(2 / tau) xi`` (white noise ``xi``): stationary law
    ``N(mean, std^2)`` (before clipping), correlation time ``tau``. Each period the exact transition
    ``b <- mean + (b - mean) e^{-h/tau} + std sqrt(1 - e^{-2h/tau}) N(0, 1)`` is drawn from the environment's
    ``np_random`` and the result clipped to ``[lo, hi]``.

    :param mean: mean wind, per component (physical units)
    :param std: stationary standard deviation, per component
    :param tau: correlation time [s]
    :param lo: lower bound per component
    :param hi: upper bound per component
    """

    def __init__(self, mean: Sequence[float], std: Sequence[float], tau: float, lo: Sequence[float],
                 hi: Sequence[float]):
        self.mean = [float(m) for m in mean]
        self.std = [float(s) for s in std]
        self.tau = float(tau)
        self.lo = [float(v) for v in lo]
        self.hi = [float(v) for v in hi]
        self.value = list(self.mean)
        self._h = None
        self._decay = 1.0
        self._spread = [0.0] * len(self.mean)

    def reset(self, rng: np.random.Generator) -> list[float]:
        """Draw the initial wind from the (clipped) stationary law."""
        self.value = [min(hi, max(lo, m + s * float(rng.standard_normal())))
                      for m, s, lo, hi in zip(self.mean, self.std, self.lo, self.hi)]
        return self.value

    def advance(self, rng: np.random.Generator, h: float) -> list[float]:
        """Move the gust on by ``h`` seconds and return the new value."""
        if h != self._h:
            self._h = h
            self._decay = math.exp(-h / self.tau)
            q = math.sqrt(max(0.0, 1.0 - self._decay * self._decay))
            self._spread = [s * q for s in self.std]
        d = self._decay
        self.value = [min(hi, max(lo, m + (v - m) * d + s * float(rng.standard_normal())))
                      for v, m, s, lo, hi in zip(self.value, self.mean, self._spread, self.lo, self.hi)]
        return self.value


def _as_float_list(name: str, value: Any, k: int, unit: str = "") -> list[float]:
    """``value`` (a number when ``k == 1``, or a sequence of ``k`` numbers) as finite floats, or a clear error."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or a sequence of {k} numbers{unit}, got {value!r}") from None
    if arr.shape == () and k == 1:
        arr = arr.reshape(1)
    if arr.shape != (k,):
        raise ValueError(f"{name} must have shape ({k},){unit}, got shape {arr.shape}: {value!r}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr.tolist()


def _table_type() -> type:
    from softreach.reach.query import Table

    return Table


def load_wind_table(wind_table: Any, model: Model, eps: float | None = None) -> Any:
    """Resolve ``wind_table=`` to an object with ``worst_disturbance(t, x, z)``, checking it fits ``model``.

    :param wind_table: a path to a saved ``W_eps`` table (loaded with :func:`softreach.reach.load_table`) or
        an object with a ``worst_disturbance`` method (a :class:`softreach.reach.Table` or a stand-in)
    :param model: the environment's model; a table with ``model_metadata`` must describe the same model
    :param eps: the environment's ``eps``; a table solved with another ``eps`` gets a warning (its ``b*`` is
        still a valid wind, but the budget it plays against is measured differently)
    :raises ValueError: when the table was computed for another model or other parameters
    """
    if isinstance(wind_table, (str, os.PathLike)):
        import softreach.reach as reach

        load = getattr(reach, "load_table", None)
        if load is None:
            raise ImportError("wind_table= was given as a path but softreach.reach.load_table is not available "
                              "in this installation; pass a loaded table object instead")
        table = load(wind_table)
    else:
        table = wind_table
    if not callable(getattr(table, "worst_disturbance", None)):
        raise TypeError("wind_table must be a path to a W_eps table or an object with a "
                        f"worst_disturbance(t, x, z) method, got {type(wind_table).__name__}")
    meta = getattr(table, "model_metadata", None)
    if meta is not None:
        name = meta.get("name")
        if name is not None and name != model.name:
            raise ValueError(f"wind_table was computed for model {name!r}, but this environment simulates "
                             f"{model.name!r}")
        params = meta.get("parameters")
        if params is not None:
            mine = model.parameters()
            diff = sorted(k for k in set(params) | set(mine) if not _same_value(params.get(k), mine.get(k)))
            if diff:
                detail = ", ".join(f"{k}: table {params.get(k)!r} vs env {mine.get(k)!r}" for k in diff)
                raise ValueError(f"wind_table was computed with other {model.name} parameters ({detail})")
    table_eps = getattr(table, "eps", None)
    if eps is not None and isinstance(table_eps, (int, float)) and not math.isclose(table_eps, eps, rel_tol=1e-9):
        gym.logger.warn(f"wind_table was solved with eps={table_eps!r}, the environment uses eps={eps!r}")
    return table


def _same_value(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same_value(u, v) for u, v in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=1e-12)
    return a == b
