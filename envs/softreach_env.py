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

from typing import Any

from softreach.reach.problem import Model

from ._common import LandingEnv
from .config import LandingConfig, landing_config


class SoftReachEnv(LandingEnv):
    """Reach a model's target within its horizon, never leaving ``C1``, spending at most ``Q`` seconds outside
    ``C2`` (the module docstring says where each part comes from).

    Rewards, ``info`` and the winds are those of :class:`~softreach.envs.pointmass_landing.PointMassLandingEnv`
    (``reward_landing`` on reaching the target, ``reward_failure`` on leaving ``C1`` or at the horizon, a
    progress shaping on the target function ``g``, a control-effort cost).
    """

    metadata = {"render_modes": [], "render_fps": 10}

    def __init__(self, model: Model | None = None, render_mode: str | None = None, *,
                 config: LandingConfig | None = None, **options: Any):
        """:param model: the model to simulate (a :class:`~softreach.reach.problem.Model` instance)
        :param render_mode: ``None`` only (this environment does not draw)
        :param config: the options (default :attr:`default_config`, the
            :class:`~softreach.envs.config.LandingConfig` defaults: the model's ``control_period``,
            ``substeps``, ``start_box`` and ``start_budget``, a gust of a quarter of the disturbance box's width
            with a tenth of the horizon as correlation time)
        :param options: :class:`~softreach.envs.config.LandingConfig` fields by name (in the model's units),
            applied on top of ``config``
        :raises ValueError: no model, or a model that lacks what the environment needs (the message names it)
        """
        if not isinstance(model, Model):
            raise ValueError(f"softreach/SoftReach-v0 needs model=<a softreach Model instance>, got {model!r}")
        config = landing_config(config, self.default_config, options).resolve(model)
        if render_mode is not None:
            raise ValueError(f"softreach/SoftReach-v0 does not render; render_mode must be None, got {render_mode!r}")
        super().__init__(model=model, config=config, render_mode=None)
