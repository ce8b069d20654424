"""The options of a landing environment (:class:`LandingConfig`): winds, budget, time stepping, starts and
rewards, with their defaults and the checks that need no model; :func:`landing_config` turns an environment's
keyword options into one."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from softreach.reach.problem import Model


def _check_positive(name: str, value: Any) -> None:
    if not (isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
            and math.isfinite(float(value)) and float(value) > 0):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")


@dataclass(frozen=True)
class LandingConfig:
    """Everything a landing environment is configured with, besides its model and ``render_mode``.

    Each environment accepts ``config=LandingConfig(...)`` or the same fields as keyword arguments (what
    ``gymnasium.make(id, **kwargs)`` passes); keywords given next to ``config=`` override its fields. An
    environment's own defaults are its ``default_config`` (``GliderLandingEnv.default_config.replace(wind="random")``
    starts from them). Fields left at ``None`` that the model declares are taken from the model when the
    environment is built (:meth:`resolve`). Units are the model's (the class docstrings of the environments
    list them).

    :param wind: ``"none"``, ``"random"`` (a bounded Ornstein-Uhlenbeck gust), ``"constant"``, ``"adversarial"``
        (the worst case ``b*`` of a ``W_eps`` table) or a callable ``(t, state, budget, action) -> wind``
    :param wind_value: the wind of ``wind="constant"`` (a number or one per disturbance component)
    :param wind_table: ``W_eps`` table (path or object) for ``wind="adversarial"``
    :param gust_std: stationary standard deviation of ``wind="random"`` (default: a quarter of the box's width)
    :param gust_tau: correlation time of ``wind="random"`` [s] (default: a tenth of the horizon)
    :param clip_wind: clip every wind to the model's disturbance box
    :param budget: ``Q`` [s] or a ``(low, high)`` range for the reset distribution, within ``[0, T]``
        (``None``: the model's ``start_budget``)
    :param eps: ``eps`` of ``h_eps`` (units of ``c2``)
    :param dt: control period [s] (``None``: the model's ``control_period``)
    :param n_substeps: RK4 steps per control period; their ends are where landing and ``C1`` are checked
        (``None``: the model's ``substeps``)
    :param budget_resolution: bisection length of the budget integral at ``C2`` crossings [s]
    :param init_state_low: lower corner of the start box (``None``: the model's ``start_box``)
    :param init_state_high: upper corner of the start box (``None``: the model's ``start_box``)
    :param landing_reward: reward on landing
    :param failure_penalty: penalty on a hard violation or at the horizon without landing
    :param progress_weight: weight of the target-distance progress shaping
    :param effort_weight: weight of the control effort over a whole episode
    :raises ValueError: on a value that is wrong whatever the model (a non-positive ``dt``, ``eps``,
        ``budget_resolution``, ``n_substeps``, a negative or non-finite reward weight)
    """

    wind: str | Callable[..., Any] = "none"
    wind_value: Any = None
    wind_table: Any = None
    gust_std: Any = None
    gust_tau: float | None = None
    clip_wind: bool = True
    budget: float | tuple[float, float] | None = None
    eps: float = 1e-3
    dt: float | None = None
    n_substeps: int | None = None
    budget_resolution: float = 1e-5
    init_state_low: Sequence[float] | None = None
    init_state_high: Sequence[float] | None = None
    landing_reward: float = 100.0
    failure_penalty: float = 100.0
    progress_weight: float = 10.0
    effort_weight: float = 10.0

    def __post_init__(self) -> None:
        if self.dt is not None:
            _check_positive("dt", self.dt)
        n_substeps = self.n_substeps
        if n_substeps is not None and not (isinstance(n_substeps, (int, np.integer))
                                           and not isinstance(n_substeps, bool) and n_substeps >= 1):
            raise ValueError(f"n_substeps must be a positive integer, got {n_substeps!r}")
        _check_positive("eps", self.eps)
        _check_positive("budget_resolution", self.budget_resolution)
        for name in ("landing_reward", "failure_penalty", "progress_weight", "effort_weight"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite non-negative number, got {value!r}")

    def replace(self, **changes: Any) -> LandingConfig:
        """A copy with some fields changed (and checked again).

        :param changes: field values, by name
        :raises TypeError: on a name that is not a field
        """
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise TypeError(f"unknown environment option(s) {unknown}; the LandingConfig fields are "
                            f"{[f.name for f in dataclasses.fields(self)]}")
        return dataclasses.replace(self, **changes)

    def resolve(self, model: Model) -> LandingConfig:
        """This config with every ``None`` that the model declares filled in from it.

        :param model: the environment's model
        :raises ValueError: where the model declares no ``control_period`` and ``dt`` is unset, or no
            ``start_box`` and the start box is unset
        """
        dt = model.control_period if self.dt is None else self.dt
        if dt is None:
            raise ValueError(f"model {model.name!r} declares no control_period; pass dt= (seconds)")
        box = model.start_box
        if (self.init_state_low is None or self.init_state_high is None) and box is None:
            raise ValueError(f"model {model.name!r} declares no start_box; pass init_state_low= and init_state_high=")
        return dataclasses.replace(
            self, dt=dt, n_substeps=model.substeps if self.n_substeps is None else self.n_substeps,
            init_state_low=box[0] if self.init_state_low is None else self.init_state_low,
            init_state_high=box[1] if self.init_state_high is None else self.init_state_high,
            budget=model.start_budget if self.budget is None else self.budget,
        )


def landing_config(config: LandingConfig | None, defaults: LandingConfig, options: Mapping[str, Any]
                   ) -> LandingConfig:
    """The config an environment is built with: ``config`` (or the environment's ``defaults`` where it is
    ``None``) with the keyword ``options`` applied on top.

    :param config: the ``config=`` argument, or ``None``
    :param defaults: the environment's ``default_config``
    :param options: the keyword options the environment was given, by field name
    :raises TypeError: on an option that is not a :class:`LandingConfig` field, or a ``config`` of another type
    """
    if config is None:
        config = defaults
    elif not isinstance(config, LandingConfig):
        raise TypeError(f"config must be a LandingConfig, got {type(config).__name__}")
    return config.replace(**options) if options else config


__all__ = ["LandingConfig", "landing_config"]
