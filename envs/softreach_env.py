"""``softreach/SoftReach-v0``: the generic environment of any :class:`~softreach.reach.problem.Model`.

    import gymnasium as gym
    import softreach.envs
    env = gym.make("softreach/SoftReach-v0", model=MyModel())

Everything that makes it a task comes from the model: the dynamics ``f`` and the input boxes, the sets (the
episode ends **reached** where the state is in the target and inside ``C1`` and ``C2``, ``Model.landed``, and
**failed** where it leaves ``C1``), the horizon, the control period ``control_period`` and its RK4 sub-steps
``substeps``, the start box ``start_box`` and the budget ``start_budget``. It is the landing environments' base
class (:class:`~softreach.envs._common.LandingEnv`) with those defaults, so it steps with the same integrator
(RK4 with the kink-aware budget quadrature), winds, rewards, checks and ``info`` keys, and the safety filter
wraps it as it wraps them. A periodic state axis (``Model.periodic``, e.g. a heading) is wrapped into its
period at every step and at reset.

Observation: the state, the remaining budget ``z`` and the time left ``T - t`` (float32). Action: the control,
normalised to ``[-1, 1]`` per component. No rendering (the landing renderer draws altitude and speed, which a
general model does not have).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from softreach.reach.problem import Model

from ._common import LandingEnv


class SoftReachEnv(LandingEnv):
    """Reach a model's target within its horizon, never leaving ``C1``, spending at most ``Q`` seconds outside
    ``C2`` (the module docstring says where each part comes from).

    Rewards, ``info`` and the winds are those of :class:`~softreach.envs.pointmass_landing.PointMassLandingEnv`
    (``reward_landing`` on reaching the target, ``reward_failure`` on leaving ``C1`` or at the horizon, a
    progress shaping on the target function ``g``, a control-effort cost).
    """

    metadata = {"render_modes": [], "render_fps": 10}

    def __init__(
        self,
        model: Model | None = None,
        render_mode: str | None = None,
        *,
        wind: str | Callable[..., Any] = "none",
        wind_value: Any = None,
        wind_table: Any = None,
        gust_std: Any = None,
        gust_tau: float | None = None,
        clip_wind: bool = True,
        budget: float | tuple[float, float] | None = None,
        eps: float = 1e-3,
        dt: float | None = None,
        n_substeps: int | None = None,
        budget_resolution: float = 1e-5,
        init_state_low: Any = None,
        init_state_high: Any = None,
        landing_reward: float = 100.0,
        failure_penalty: float = 100.0,
        progress_weight: float = 10.0,
        effort_weight: float = 10.0,
    ):
        """:param model: the model to simulate (a :class:`~softreach.reach.problem.Model` instance)
        :param render_mode: ``None`` only (this environment does not draw)
        :param wind: ``"none"``, ``"random"``, ``"constant"``, ``"adversarial"`` or a callable, as for the landings
        :param wind_value: the wind of ``wind="constant"`` (the model's disturbance units)
        :param wind_table: a ``W_eps`` table (path or object) of this model for ``wind="adversarial"``
        :param gust_std: standard deviation of ``wind="random"`` (default: a quarter of the box's width)
        :param gust_tau: correlation time of ``wind="random"`` [s] (default: a tenth of the horizon)
        :param clip_wind: clip every wind to the model's disturbance box
        :param budget: ``Q`` [s] or a ``(low, high)`` range (default: the model's ``start_budget``)
        :param eps: ``eps`` of ``h_eps`` (units of ``c2``)
        :param dt: control period [s] (default: the model's ``control_period``)
        :param n_substeps: RK4 steps per period, where reaching and ``C1`` are checked (default: the model's
            ``substeps``)
        :param budget_resolution: bisection length of the budget integral at ``C2`` crossings [s]
        :param init_state_low: lower corner of the start box (default: the model's ``start_box``)
        :param init_state_high: upper corner of the start box (default: the model's ``start_box``)
        :param landing_reward: reward on reaching the target
        :param failure_penalty: penalty on leaving ``C1`` or at the horizon without reaching the target
        :param progress_weight: weight of the target-function progress shaping
        :param effort_weight: weight of the control effort over a whole episode
        :raises ValueError: no model, or a model that lacks what the environment needs (the message names it)
        """
        if not isinstance(model, Model):
            raise ValueError(f"softreach/SoftReach-v0 needs model=<a softreach Model instance>, got {model!r}")
        period = model.control_period if dt is None else dt
        if period is None:
            raise ValueError(f"model {model.name!r} declares no control_period; pass dt= (seconds)")
        box = model.start_box
        if (init_state_low is None or init_state_high is None) and box is None:
            raise ValueError(f"model {model.name!r} declares no start_box; pass init_state_low= and init_state_high=")
        if render_mode is not None:
            raise ValueError(f"softreach/SoftReach-v0 does not render; render_mode must be None, got {render_mode!r}")
        super().__init__(
            model=model, dt=period, n_substeps=model.substeps if n_substeps is None else n_substeps, eps=eps,
            init_state_low=box[0] if init_state_low is None else init_state_low,
            init_state_high=box[1] if init_state_high is None else init_state_high,
            budget=model.start_budget if budget is None else budget, wind=wind, wind_value=wind_value,
            wind_table=wind_table, gust_std=gust_std, gust_tau=gust_tau, clip_wind=clip_wind,
            landing_reward=landing_reward, failure_penalty=failure_penalty, progress_weight=progress_weight,
            effort_weight=effort_weight, budget_resolution=budget_resolution, render_mode=None,
        )
