"""The :class:`LandingEnv` base class of the landing environments: the episode (reset, step, observation,
``info``) and the checks of starts and budgets.

The environments simulate the models of :mod:`softreach.reach.models` with the model objects themselves:
the vector field is ``model.f``, the budget drains at ``model.violation_rate``, landing and crashing are read off
``model.target``, ``model.hard_constraint`` and ``model.soft_constraint``. Nothing here re-implements a model.
The integrator (:mod:`softreach.reach.sim.integrator`) advances one control period and ends it at the first sub-step
that lands or leaves ``C1``. The other parts are base classes from their own modules: the options
(:class:`~softreach.envs.config.LandingConfig`), the action map (:mod:`softreach.envs.actions`), the winds
(:mod:`softreach.envs.wind`) and drawing (:mod:`softreach.envs.display`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np

import gymnasium as gym
from gymnasium import spaces

from softreach.reach.sim.integrator import ScalarModel, episode_ends, integrate_period, scalar_model, stage_rates
from softreach.reach.problem import Model

from .actions import ActionMapping
from .config import LandingConfig, _check_positive
from .display import Rendering, _require_display, has_display, render_modes
from .wind import WindInputs, _as_float_list, load_wind_table


class LandingEnv(ActionMapping, WindInputs, Rendering, gym.Env):
    """Base class of the landing environments (see :class:`PointMassLandingEnv` for the documentation of the
    common behaviour). Subclasses set :attr:`default_config`, pass their model and a
    :class:`~softreach.envs.config.LandingConfig` to :meth:`__init__` (built by
    :func:`~softreach.envs.config.landing_config`) and implement :meth:`_render_layout` (the static parts of a
    frame: ranges, limits, labels).
    """

    metadata: dict[str, Any] = {"render_modes": render_modes(), "render_fps": 25}

    #: keys accepted in ``reset(options=...)``
    OPTION_KEYS = ("state", "budget", "time")

    #: the options of an environment built without any (subclasses set their own)
    default_config: LandingConfig = LandingConfig()

    def __init__(self, *, model: Model, config: LandingConfig, render_mode: str | None):
        """:param model: the model to simulate
        :param config: the environment's options; the fields left at ``None`` are taken from the model
            (:meth:`LandingConfig.resolve`)
        :param render_mode: ``None``, ``"rgb_array"`` or ``"human"`` (where the subclass declares them)
        """
        super().__init__()
        self.model = model
        self.horizon = float(model.horizon)
        n, m, k = model.state_dim, model.control_dim, model.disturbance_dim
        self._n, self._m, self._k = n, m, k

        config = self.config = config.resolve(model)
        dt = config.dt
        if dt > self.horizon:
            raise ValueError(f"dt must not exceed the horizon {self.horizon} s, got {dt!r}")
        self.dt = float(dt)
        self.n_substeps = int(config.n_substeps)
        self.eps = float(config.eps)
        self.budget_resolution = float(config.budget_resolution)

        # physical ranges of the inputs; the agent acts in [-1, 1], normalised by each axis' half-width
        from softreach.reach.boxes import check_action_box

        check_action_box(model)
        self.action_low_physical = np.array(model.control_bounds[0], dtype=np.float64)
        self.action_high_physical = np.array(model.control_bounds[1], dtype=np.float64)
        self._a_lo = [float(v) for v in model.control_bounds[0]]
        self._a_hi = [float(v) for v in model.control_bounds[1]]
        self._a_mid = [0.5 * (lo + hi) for lo, hi in zip(self._a_lo, self._a_hi)]
        self._a_half = [0.5 * (hi - lo) for lo, hi in zip(self._a_lo, self._a_hi)]
        self.wind_low = np.array(model.disturbance_bounds[0], dtype=np.float64)
        self.wind_high = np.array(model.disturbance_bounds[1], dtype=np.float64)
        self._b_lo = [float(v) for v in model.disturbance_bounds[0]]
        self._b_hi = [float(v) for v in model.disturbance_bounds[1]]

        # the domain (grid box of the model) bounds the states a user may start from and the observation
        self.state_low = np.array(model.domain[0], dtype=np.float64)
        self.state_high = np.array(model.domain[1], dtype=np.float64)
        # periodic axes (a heading) are wrapped into their period [lo, hi) instead of being bounded
        self._periodic = model.periodic_axes()
        self._wraps = any(self._periodic)

        lo = _as_float_list("init_state_low", config.init_state_low, n)
        hi = _as_float_list("init_state_high", config.init_state_high, n)
        for i in range(n):
            if not lo[i] <= hi[i]:
                raise ValueError(f"init_state_low must not exceed init_state_high, got {lo} and {hi}")
        self._check_state(lo, "init_state_low")
        self._check_state(hi, "init_state_high")
        self.init_state_low, self.init_state_high = np.array(lo), np.array(hi)

        budget = config.budget
        if isinstance(budget, (tuple, list)):
            if len(budget) != 2:
                raise ValueError(f"budget must be a number or a (low, high) pair, got {budget!r}")
            b_lo, b_hi = (self._check_budget(v, "budget") for v in budget)
            if b_lo > b_hi:
                raise ValueError(f"budget range must have low <= high, got {budget!r}")
            self.budget_range = (b_lo, b_hi)
        else:
            q = self._check_budget(budget, "budget")
            self.budget_range = (q, q)

        self.landing_reward = float(config.landing_reward)
        self.failure_penalty = float(config.failure_penalty)
        self.progress_weight = float(config.progress_weight)
        self.effort_weight = float(config.effort_weight)

        self._setup_wind(config.wind, config.wind_value, config.wind_table, config.gust_std, config.gust_tau,
                         config.clip_wind)

        self.action_space = spaces.Box(-1.0, 1.0, shape=(m,), dtype=np.float32)
        T = self.horizon
        obs_lo = np.concatenate([self.state_low, [-T, 0.0]]).astype(np.float32)
        obs_hi = np.concatenate([self.state_high, [T, T]]).astype(np.float32)
        self.observation_space = spaces.Box(obs_lo, obs_hi, dtype=np.float32)

        if render_mode == "human":
            _require_display()
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        self.render_mode = render_mode
        self._renderer = None
        self._history: list[tuple[float, float]] | None = [] if render_mode is not None else None

        # episode state (set by reset)
        self._x: list[float] | None = None
        self._t = 0.0
        self._z = 0.0
        self._q = 0.0
        self._g = 0.0
        self._last_a = list(self._a_mid)
        self._last_info: dict[str, Any] = {}
        # the model's scalar fast path (looked up at each reset) and h_eps at the current (t, x), reused as the
        # first RK4 stage of the next step: (t, x, rate), x compared by identity
        self._fast: ScalarModel | None = None
        self._fast_event = None
        self._rate_now: tuple[float, Any, float] | None = None

    # ------------------------------------------------------------------------------------------ checks
    def _check_budget(self, value: Any, name: str) -> float:
        if not (isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
                and math.isfinite(float(value))):
            raise ValueError(f"{name} must be a finite number of seconds, got {value!r}")
        value = float(value)
        if not 0.0 <= value <= self.horizon:
            raise ValueError(f"{name} must lie in [0, T] = [0, {self.horizon}] s (a budget above the horizon is "
                             f"never binding), got {value!r}")
        return value

    def _check_state(self, x: Sequence[float], name: str) -> None:
        units = self.model.state_units
        bad = [f"{self.model.state_names[i]}={x[i]!r} not in [{self.state_low[i]:.6g}, {self.state_high[i]:.6g}] "
               f"{units[i]}" + (" (radians expected; this looks like degrees)" if units[i] == "rad"
                                and abs(x[i]) > 0.5 else "")
               for i in range(self._n) if not (self.state_low[i] <= x[i] <= self.state_high[i]
                                               or (self._periodic[i] and math.isfinite(x[i])))]
        if bad:
            raise ValueError(f"{name} lies outside the {self.model.name} domain: " + "; ".join(bad))
        self.model.validate_state(list(x))

    # ------------------------------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode.

        :param seed: seeds ``self.np_random`` (initial state, budget and gusts)
        :param options: optional ``{"state": ..., "budget": Q, "time": t0}``; ``state`` is the physical state
            (must lie in the model's domain), ``budget`` the violation-time budget ``Q`` in ``[0, T]`` seconds,
            ``time`` the start time ``t0`` in ``[0, T)``. Unset entries are drawn/defaulted as documented.
        :return: ``(observation, info)``
        """
        super().reset(seed=seed)
        if options is None:
            options = {}
        elif not isinstance(options, Mapping):
            raise ValueError(f"options must be a dict with keys from {self.OPTION_KEYS}, got {options!r}")
        unknown = sorted(str(key) for key in options if key not in self.OPTION_KEYS)
        if unknown:
            raise ValueError(f"unknown reset option(s) {unknown}; accepted keys: {list(self.OPTION_KEYS)}")
        rng = self.np_random
        if options.get("state") is not None:
            x = _as_float_list("options['state']", options["state"], self._n)
            self._check_state(x, "options['state']")
        else:
            x = rng.uniform(self.init_state_low, self.init_state_high).tolist()
        if self._wraps:
            x = self.model.wrap_state(x)
        if options.get("budget") is not None:
            q = self._check_budget(options["budget"], "options['budget']")
        else:
            lo, hi = self.budget_range
            q = lo if lo == hi else float(rng.uniform(lo, hi))
        t0 = options.get("time")
        if t0 is None:
            t0 = 0.0
        elif not (isinstance(t0, (int, float, np.floating, np.integer)) and not isinstance(t0, bool)
                  and math.isfinite(float(t0)) and 0.0 <= float(t0) < self.horizon):
            raise ValueError(f"options['time'] must be a start time in [0, T) = [0, {self.horizon}) s, got {t0!r}")
        self._x, self._q, self._z, self._t = x, q, q, float(t0)
        fast = self._fast = scalar_model(self.model)
        # the sub-steps' end test, bound once: a partial costs no Python frame of its own per sub-step
        self._fast_event = None if fast is None else partial(episode_ends, fast)
        if fast is not None:
            self._g = fast.target(self._t, x)
            rate = fast.violation_rate(self._t, x, self.eps)
            c1 = fast.hard_constraint(self._t, x)
        else:
            self._g = float(self.model.target(self._t, x))
            rate = float(stage_rates(self.model, [self._t], [x], self.eps)[0, 0])
            c1 = float(self.model.hard_constraint(self._t, x))
        self._rate_now = (self._t, x, rate)
        if self._gust is not None:
            self._gust.reset(rng)
        self._last_a = list(self._a_mid)
        info = self._info(0.0, rate > 0.0, c1 > 0.0, False, self._a_mid, self._wind_now(), 0.0, 0.0, 0.0)
        self._last_info = info
        if self._history is not None:
            self._history.clear()
            self._history.append((self._t, *x))
        if self.render_mode == "human":
            self.render()
        return self._get_obs(), info

    def step(self, action: Any):
        """Apply ``action`` (normalised, clipped to ``[-1, 1]``) for one control period.

        :return: ``(observation, reward, terminated, truncated, info)``
        :raises ValueError: on a non-finite or wrongly shaped action
        """
        x0 = self._x
        if x0 is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        a = self._action_to_physical(action)
        model = self.model
        t = self._t
        b = self._wind(a)
        T = self.horizon
        h = min(self.dt, T - t)
        fast = self._fast
        known = self._rate_now  # h_eps at (t, x0) when the last step or reset left it there
        rate0 = known[2] if known is not None and known[0] == t and known[1] is x0 else None
        if fast is not None:
            x, cost, rate_end, h = integrate_period(model, t, x0, a, b, h, self.n_substeps, self.eps,
                                                    self.budget_resolution, fast=fast, rate0=rate0,
                                                    stop=self._fast_event)
        else:
            x, cost, rate_end, h = integrate_period(model, t, x0, a, b, h, self.n_substeps, self.eps,
                                                    self.budget_resolution, fast=None, stop=self._event)
        t_new = t + h
        if self._wraps:  # the sets are periodic along these axes, so rate_end holds for the wrapped state too
            x = self.model.wrap_state(x)
        self._rate_now = (t_new, x, rate_end)
        if T - t_new <= 1e-9 * T:
            t_new = T
        self._x, self._t = x, t_new
        z = self._z = self._z - cost
        if self._gust is not None:
            self._gust.advance(self.np_random, h)

        soft = rate_end > 0.0
        if fast is not None:
            hard = fast.hard_constraint(t_new, x) > 0.0
            g = fast.target(t_new, x)
        else:
            hard = float(model.hard_constraint(t_new, x)) > 0.0
            g = float(model.target(t_new, x))
        landed = (not hard) and (not soft) and g <= 0.0
        terminated = hard or landed
        truncated = (not terminated) and t_new >= T

        # reward: terminal terms + shaping (progress potential and control effort)
        r_land = self.landing_reward if landed else 0.0
        r_fail = -self.failure_penalty if (hard or truncated) else 0.0
        effort = 0.0
        for ai, mid, half in zip(a, self._a_mid, self._a_half):
            u = (ai - mid) / half
            effort += u * u
        g_old = self._g
        r_shape = (self.progress_weight * ((g_old if g_old > 0.0 else 0.0) - (g if g > 0.0 else 0.0))
                   - self.effort_weight * effort / self._m * h / T)
        self._g = g
        self._last_a = a
        info = self._last_info = self._info(cost, soft, hard, landed, a, b, r_land, r_fail, r_shape)
        if self._history is not None:
            self._history.append((t_new, *x))
        if self.render_mode == "human":
            self.render()
        return (np.array(x + [z, T - t_new], dtype=np.float32), r_land + r_fail + r_shape, terminated, truncated,
                info)

    def _event(self, t: float, x: list[float], rate: float) -> bool:
        """Does the episode end at this sub-step end: :func:`~softreach.reach.sim.integrator.episode_ends`, the
        rollouts' rule (a model with a scalar fast path gets it bound to that at reset, ``_fast_event``)."""
        return bool(episode_ends(self.model, t, [np.float64(v) for v in x], rate))

    def _get_obs(self) -> np.ndarray:
        # step() builds the same observation inline
        return np.array(self._x + [self._z, self.horizon - self._t], dtype=np.float32)

    def _info(self, cost: float, soft: bool, hard: bool, landed: bool, a: list[float], b: list[float],
              r_land: float, r_fail: float, r_shape: float) -> dict[str, Any]:
        z = self._z
        return {
            "t": self._t,
            "budget": z,
            "budget_used": self._q - z,
            "budget_exceeded": z < 0.0,
            "cost": cost,
            "soft_violation": soft,
            "hard_violation": hard,
            "landed": landed,
            "is_success": landed,
            "action_physical": np.array(a, dtype=np.float64),
            "wind": np.array(b, dtype=np.float64),
            "reward_landing": r_land,
            "reward_failure": r_fail,
            "reward_shaping": r_shape,
        }

    @property
    def state(self) -> np.ndarray | None:
        """The physical state (float64 copy), or ``None`` before the first reset."""
        return None if self._x is None else np.array(self._x, dtype=np.float64)

    @property
    def time(self) -> float:
        """The current time ``t`` [s]."""
        return self._t

    @property
    def budget(self) -> float:
        """The remaining budget ``z`` [s] (negative once exceeded)."""
        return self._z

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_renderer"] = None  # figures do not pickle; a copy draws its own
        if state.get("_wind_table_path") is not None:
            state["wind_table"] = None  # a table loaded from a file travels as its path, not as its data
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self._wind_table_path is not None and self.wind_table is None:
            self.wind_table = load_wind_table(self._wind_table_path, self.model)


# re-exported: the display checks and the positive-number check are imported from this module
__all__ = ["LandingEnv", "LandingConfig", "_check_positive", "has_display", "render_modes"]
