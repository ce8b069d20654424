"""The environments' winds: none, an Ornstein-Uhlenbeck gust, a constant, or a table's worst case ``b*``; and
:class:`WindInputs`, which picks the wind an environment holds over each control period."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

import gymnasium as gym

from softreach.reach.problem import Model

from .config import _check_positive

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
    from softreach.reach.tables.query import Table

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


class WindInputs:
    """The wind of :class:`~softreach.envs._common.LandingEnv` (a base class of it): set up from the wind
    options, and the value held over each control period.

    It reads the environment's ``model``, ``horizon``, ``eps``, ``_k`` (disturbance dimension), ``_b_lo`` /
    ``_b_hi`` (the disturbance box) and the episode state ``_t``, ``_x``, ``_z``.
    """

    def _setup_wind(self, wind, wind_value, wind_table, gust_std, gust_tau, clip_wind) -> None:
        k = self._k
        self.clip_wind = bool(clip_wind)
        self.wind_mode = wind if isinstance(wind, str) else "callable"
        self._wind_fn = None
        self._gust = None
        self.wind_table = None
        self._wind_table_path: str | None = None
        if isinstance(wind, str):
            if wind not in WIND_MODES:
                raise ValueError(f"wind must be one of {WIND_MODES} or a callable (t, state, budget, action) -> "
                                 f"wind, got {wind!r}")
        elif not callable(wind):
            raise ValueError(f"wind must be one of {WIND_MODES} or a callable, got {wind!r}")
        else:
            self._wind_fn = wind
        used = {"wind_value": "constant", "wind_table": "adversarial", "gust_std": "random", "gust_tau": "random"}
        for name, value in (("wind_value", wind_value), ("wind_table", wind_table), ("gust_std", gust_std),
                            ("gust_tau", gust_tau)):
            if value is not None and self.wind_mode != used[name]:
                raise ValueError(f"{name}= is used only with wind={used[name]!r}, but wind={self.wind_mode!r}")
        units = f" [{', '.join(self.model.disturbance_units) or 'model units'}]"
        if self.wind_mode == "constant":
            if wind_value is None:
                raise ValueError("wind='constant' needs wind_value= (the physical wind"
                                 f"{units}, a number or {k} numbers)")
            value = _as_float_list("wind_value", wind_value, k, units)
            if self.clip_wind:
                out = [v for v, lo, hi in zip(value, self._b_lo, self._b_hi) if not lo <= v <= hi]
                if out:
                    raise ValueError(f"wind_value={value} lies outside the disturbance box [{self._b_lo}, "
                                     f"{self._b_hi}]{units}; pass clip_wind=False to apply it anyway")
            self.wind_value = value
        elif self.wind_mode == "random":
            half = [0.5 * (hi - lo) for lo, hi in zip(self._b_lo, self._b_hi)]
            mean = [0.5 * (hi + lo) for lo, hi in zip(self._b_lo, self._b_hi)]
            std = [0.5 * w for w in half] if gust_std is None else _as_float_list("gust_std", gust_std, k, units)
            if any(s < 0 for s in std):
                raise ValueError(f"gust_std must be non-negative, got {std}")
            tau = self.horizon / 10.0 if gust_tau is None else gust_tau
            _check_positive("gust_tau", tau)
            lo = self._b_lo if self.clip_wind else [-math.inf] * k
            hi = self._b_hi if self.clip_wind else [math.inf] * k
            self._gust = OrnsteinUhlenbeckGust(mean, std, float(tau), lo, hi)
        elif self.wind_mode == "adversarial":
            if wind_table is None:
                raise ValueError("wind='adversarial' needs wind_table= (a path to a W_eps table of this model, or a "
                                 "loaded Table): the worst-case wind b* is read from the table's gradient")
            self.wind_table = load_wind_table(wind_table, self.model, self.eps)
            if isinstance(wind_table, (str, os.PathLike)):
                self._wind_table_path = os.fspath(wind_table)

    def _wind(self, a: list[float]) -> list[float]:
        """The wind held over the coming period (physical units)."""
        mode = self.wind_mode
        if mode == "none":
            return [0.0] * self._k
        if mode == "random":
            return list(self._gust.value)
        if mode == "constant":
            return list(self.wind_value)
        if mode == "adversarial":
            table = self.wind_table
            args = (self._t, np.array([self._x], dtype=np.float64), np.array([self._z], dtype=np.float64))
            # a softreach Table refuses gradients off its grid; the wind keeps blowing there (an episode goes on
            # with z < 0, below the table's budgets), read at the nearest grid point
            out = (table.worst_disturbance(*args, outside="nearest") if isinstance(table, _table_type())
                   else table.worst_disturbance(*args))
            b = np.asarray(out, dtype=np.float64).reshape(-1)
            if b.shape != (self._k,) or not np.all(np.isfinite(b)):
                raise ValueError(f"wind_table.worst_disturbance returned {out!r} at t={self._t}, x={self._x}, "
                                 f"z={self._z}; expected {self._k} finite values")
            b = b.tolist()
        else:
            out = self._wind_fn(self._t, np.array(self._x, dtype=np.float64), self._z, np.array(a, dtype=np.float64))
            b = _as_float_list("the wind callable's result", out, self._k)
        if self.clip_wind:
            b = [min(hi, max(lo, v)) for v, lo, hi in zip(b, self._b_lo, self._b_hi)]
        return b

    def _wind_now(self) -> list[float]:
        if self.wind_mode == "random":
            return list(self._gust.value)
        if self.wind_mode == "constant":
            return list(self.wind_value)
        return [0.0] * self._k
