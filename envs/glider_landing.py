"""``softreach/GliderLanding-v0``: the fixed-wing emergency landing (propulsion failure) of the paper's §VI-B."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from softreach.reach.models import get_model

from ._common import LandingEnv
from .config import LandingConfig, landing_config
from .display import render_modes


class GliderLandingEnv(LandingEnv):
    """Glide a DC9-30 without thrust to a soft touchdown within 10 s, with a budget for the speed margins.

    ## Description

    The model of the paper's §VI-B (:class:`softreach.reach.models.glider.Glider`, used as is): state
    ``(h, V, gamma)`` = altitude [m], airspeed [m/s], flight-path angle [rad];
    ``h' = V sin(gamma)``, ``V' = (-D(alpha, V) - m g sin(gamma) + F_wind) / m``,
    ``gamma' = L(alpha, V) / (m V) - g cos(gamma) / V`` with the DC9-30 lift and drag of Bayen et al. (2007).
    The agent sets the angle of attack ``alpha in [0, 13] deg``; the wind force ``F_wind in [-10, 10] kN``
    disturbs it. The hard constraint ``C1 = {V in [61, 83] m/s, gamma in [-3, 0] deg, h >= 0}`` (stall, maximum
    descent speed, glide corridor, ground) must never be left; the soft constraint ``C2 = {V in [66, 78] m/s}``
    (5 m/s margins) may be left for at most ``Q`` seconds in total. The target is touchdown: ``|h| <= 0.5 m``
    with sink rate ``-V sin(gamma) <= 0.91 m/s``, within the horizon ``T = 10 s``.

    The remaining budget ``z`` starts at ``Q`` and follows ``z' = -h_eps(x)``,
    ``h_eps = min(1, max(0, c2 / eps))`` (``c2`` and ``eps`` in m/s, default ``eps = 1e-3``): it drains at unit
    rate while ``V`` is outside ``[66, 78]``. An episode goes on after ``z < 0``; ``info["budget_exceeded"]``
    reports it.

    **Time stepping.** One step is a control period of ``dt = 0.1 s`` (100 steps per episode); the action and
    the wind are held over it and the state is advanced by ``n_substeps = 2`` RK4 steps (0.05 s; against a
    tolerance-1e-12 solution of the same ``f`` the error is below 1e-9 in every component). The budget uses the
    RK4 stages with bisection at the kinks of ``h_eps`` (``budget_resolution``); ``C1`` and the target are checked
    at every sub-step end, and the episode ends at the first one where the aircraft has landed or left ``C1``. Inside ``C1`` the aircraft sinks at most ``83 sin(3 deg) = 4.3 m/s``,
    i.e. 0.43 m per period, less than the 0.5 m touchdown band: a descent always ends a period inside the band
    before it reaches the ground.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the normalised angle of attack, ``alpha = 6.5 deg * (1 + action)`` (affine map
    of ``[-1, 1]`` onto ``[0, 13] deg``; the model and ``info["action_physical"]`` use radians). Out-of-range
    finite actions are clipped; non-finite or wrongly shaped actions raise ``ValueError``. Conversions:
    :meth:`physical_action` / :meth:`normalized_action` (radians), :meth:`alpha_degrees` /
    :meth:`normalized_action_from_degrees` (degrees).

    ## Observation Space

    ``Box(float32)`` of shape ``(5,)``:

    | index | observation                | min    | max    | unit |
    |-------|----------------------------|--------|--------|------|
    | 0     | altitude ``h``             | -5     | 45     | m    |
    | 1     | airspeed ``V``             | 58     | 86     | m/s  |
    | 2     | flight-path angle ``gamma``| -0.0698| 0.0175 | rad  |
    | 3     | remaining budget ``z``     | -10    | 10     | s    |
    | 4     | time left ``T - t``        | 0      | 10     | s    |

    The state bounds are the model's grid domain (``gamma`` from -4 to 1 deg).

    ## Rewards

    ``reward = reward_landing + reward_failure + reward_shaping``, each also in ``info``:

    * ``reward_landing = +landing_reward`` (100) on the step that touches down inside ``C2``;
    * ``reward_failure = -failure_penalty`` (100) on the step that leaves ``C1`` (stall, over-speed, out of the
      glide corridor, below ground) or reaches the horizon without landing;
    * ``reward_shaping`` = progress ``progress_weight * (d(x) - d(x'))``, ``d = max(g, 0)`` the model's target
      distance (m and m/s; default weight 2.5, so a landing from 40 m collects about 100) minus control effort
      ``effort_weight * action^2 * dt / T`` (``effort_weight`` = 10 for a whole episode at an end of the range).

    The budget is not part of the reward; it is observed and reported in ``info``.

    ## Starting State

    ``h ~ U[2, 40]`` m (the paper's start altitudes, less the lowest 2 m where the first period would decide the
    episode), ``V ~ U[66, 78]`` m/s, ``gamma ~ U[-2.5, -0.5]`` deg, ``Q ~ U[0, 10]`` s (paper: 0, 5, 10), ``t = 0``.
    ``reset(options={"state": [h, V, gamma], "budget": Q, "time": t0})`` sets any of them; ``gamma`` is in
    radians and the state must lie in the domain above (an angle that looks like degrees is refused).

    ## Episode End

    ``terminated`` on landing (``info["landed"]``) or on leaving ``C1`` (``info["hard_violation"]``), whichever comes
    first at a sub-step end (the step then ends there);
    ``truncated`` at ``T = 10 s`` otherwise (``max_episode_steps = 100``).

    ## Info

    As for ``PointMassLanding-v0``: ``t``, ``budget``, ``budget_used``,
    ``budget_exceeded``, ``cost``, ``soft_violation``, ``hard_violation``, ``landed``, ``is_success``,
    ``action_physical`` (``alpha`` in rad), ``wind`` (``F_wind`` in N), ``reward_landing``, ``reward_failure``,
    ``reward_shaping``.

    ## Arguments

    As for ``PointMassLanding-v0`` (keywords or ``config=LandingConfig(...)``; this environment's defaults are
    ``GliderLandingEnv.default_config``) with glider units: ``wind_value`` / ``gust_std`` in N (gust default: std
    5 kN, ``gust_tau`` 1 s), ``model_params`` overrides :class:`GliderParams`, ``init_state_low/high`` are
    ``(h, V, gamma)`` with ``gamma`` in radians. With another ``dt`` than 0.1 s pass
    ``max_episode_steps=ceil(T / dt)`` to ``gymnasium.make`` too (the env truncates itself at ``T`` in any case).
    """

    metadata = {"render_modes": render_modes(), "render_fps": 10}  # one frame per control period, real time

    default_config = LandingConfig(budget=(0.0, 10.0), dt=0.1, budget_resolution=1e-5,
                                   init_state_low=(2.0, 66.0, math.radians(-2.5)),
                                   init_state_high=(40.0, 78.0, math.radians(-0.5)), progress_weight=2.5)

    def __init__(self, render_mode: str | None = None, *, config: LandingConfig | None = None,
                 model_params: dict[str, Any] | None = None, **options: Any):
        """:param render_mode: ``None``, ``"rgb_array"`` or ``"human"``
        :param config: the options (default :attr:`default_config`: ``budget=(0, 10)``, ``dt=0.1``,
            ``progress_weight=2.5``, the start box above, ``n_substeps`` the model's 2, and the
            :class:`~softreach.envs.config.LandingConfig` defaults)
        :param model_params: overrides of :class:`softreach.reach.models.glider.GliderParams`
        :param options: :class:`~softreach.envs.config.LandingConfig` fields by name (the class docstring's
            "Arguments": forces in N, angles in rad), applied on top of ``config``
        """
        model = get_model("glider", **(model_params or {}))
        super().__init__(model=model, config=landing_config(config, self.default_config, options),
                         render_mode=render_mode)

    @property
    def params(self):
        """The model's :class:`~softreach.reach.models.glider.GliderParams`."""
        return self.model.params

    def alpha_degrees(self, action: Any) -> np.ndarray:
        """The angle of attack [deg] that a normalised action commands (after clipping to ``[-1, 1]``)."""
        return np.degrees(self.physical_action(action))

    def normalized_action_from_degrees(self, alpha_deg: Any) -> np.ndarray:
        """The normalised action for an angle of attack given in degrees.

        :param alpha_deg: angle(s) of attack [deg], shape ``(..., 1)``
        """
        return self.normalized_action(np.radians(np.asarray(alpha_deg, dtype=np.float64)))

    def _render_layout(self) -> dict[str, Any]:
        p = self.model.params
        return {
            "title": "GliderLanding",
            "horizon": self.horizon,
            "altitude_range": (self.state_low[0], self.state_high[0]),
            # C1's ground is the bottom of the touchdown band (see GliderParams): draw what the model checks
            "altitude_limits": (p.min_altitude - p.touchdown_altitude, math.inf),
            "target_altitude": (p.min_altitude - p.touchdown_altitude, p.min_altitude + p.touchdown_altitude),
            "speed_name": "V [m/s]",
            "speed_range": (self.state_low[1], self.state_high[1]),
            "speed_soft": p.soft_speed,
            "speed_hard": p.hard_speed,
            "speed_target": None,
            "action_name": "α [deg]",
            "action_scale": 180.0 / math.pi,
            "wind_name": "F_wind [kN]",
            "wind_scale": 1e-3,
            "altitude_index": 0,
            "speed_index": 1,
            "pitch_index": 2,
        }
