"""``softreach/PointMassLanding-v0``: the vertical point-mass landing of the paper's §VI-A."""

from __future__ import annotations

from typing import Any

from softreach.reach.models import get_model
from softreach.reach.models.pointmass import PointMass, PointMassParams

from ._common import LandingEnv
from .config import LandingConfig, landing_config
from .display import render_modes


class PointMassLandingEnv(LandingEnv):
    """Land a vertical point mass softly within one second, with a budget for exceeding the recommended speed.

    ## Description

    The model of the paper's §VI-A (:class:`softreach.reach.models.pointmass.PointMass`, used as is):
    ``y'' = u - g + d`` with altitude ``y`` [m], vertical speed ``v = y'`` [m/s], thrust acceleration
    ``u in [-60, 60]`` m/s^2 (the agent), gravity ``g = 9.8`` m/s^2 and a disturbance ("wind")
    ``d in [-10, 10]`` m/s^2. The task is to reach the touchdown set ``T = {v in [-1, 0], y in [0, 0.7]}`` by the
    horizon ``T = 1 s`` without ever leaving the design speed range ``C1 = {|v| <= 15, y in [0, 18]}`` (hard) and
    spending at most ``Q`` seconds outside the recommended range ``C2 = {|v| <= 10, y in [0, 18]}`` (soft).

    The remaining budget ``z`` starts at ``Q`` and follows the paper's augmented dynamics ``z' = -h_eps(x)``,
    ``h_eps = min(1, max(0, c2 / eps))`` (``eps`` in m/s, default ``1e-3``): it drains at unit rate while the
    speed is outside ``C2``. An episode goes on after ``z < 0``; ``info["budget_exceeded"]`` reports it.

    **Time stepping.** One step is a control period of ``dt = 0.01 s`` (100 steps per episode). The action and
    the wind are held over the period and the state is advanced by RK4 with ``n_substeps`` steps (default 10;
    RK4 is exact at any count here, since with inputs held the solution is a quadratic polynomial in time). The
    budget uses the same RK4 stages, with bisection where ``h_eps`` has a kink (``budget_resolution``). ``C1``
    and the target are checked at every sub-step end (every millisecond by default): the episode ends at the
    first one where the vehicle has landed or left ``C1``, so a touchdown inside a period counts as a landing. If the start time is not a multiple of ``dt``, the last
    period is shortened so that the episode ends exactly at ``T``.

    ## Action Space

    ``Box(-1, 1, (1,), float32)``: the normalised thrust. ``u = 60 * action`` m/s^2 (affine map of ``[-1, 1]``
    onto the model's control box). Out-of-range finite actions are clipped to ``[-1, 1]``; non-finite or wrongly
    shaped actions raise ``ValueError``. :meth:`physical_action` and :meth:`normalized_action` convert
    between the two (``env.unwrapped.normalized_action([9.8])`` is the hover action).

    ## Observation Space

    ``Box(float32)`` of shape ``(4,)``:

    | index | observation            | min  | max | unit |
    |-------|------------------------|------|-----|------|
    | 0     | vertical speed ``v``   | -20  | 20  | m/s  |
    | 1     | altitude ``y``         | -5   | 20  | m    |
    | 2     | remaining budget ``z`` | -1   | 1   | s    |
    | 3     | time left ``T - t``    | 0    | 1   | s    |

    The state bounds are the model's grid domain; episodes end (leaving ``C1``) well inside them, unless an
    unclipped wind (``clip_wind=False``) pushes harder than the model's disturbance box. The time left makes the
    task Markov.

    ## Rewards

    ``reward = reward_landing + reward_failure + reward_shaping``, each also in ``info``:

    * ``reward_landing = +landing_reward`` (100) on the step that lands (touchdown set reached with the speed
      inside ``C2``), else 0;
    * ``reward_failure = -failure_penalty`` (100) on the step that leaves ``C1`` (crash or over-speed) or that
      reaches the horizon without landing (late), else 0;
    * ``reward_shaping`` = progress ``progress_weight * (d(x) - d(x'))`` with ``d = max(g, 0)`` the model's
      target distance (``g`` in m or m/s; potential-based, it sums to ``progress_weight * d(x_0)`` along a
      landing) minus control effort ``effort_weight * action^2 * dt / T`` (full thrust for a whole episode costs
      ``effort_weight`` = 10).

    The budget is not part of the reward: it is in the observation and in ``info`` (``cost`` per step,
    ``budget``, ``budget_used``, ``budget_exceeded``), for constrained RL or a safety filter to use.

    ## Starting State

    ``v ~ U[-5, 5]`` m/s, ``y ~ U[1, 12]`` m (``init_state_low/high``), ``Q ~ U[0, 0.6]`` s (``budget``; the
    paper's budgets are 0, 0.06, 0.3, 0.6), ``t = 0``. ``reset(options={"state": [v, y], "budget": Q,
    "time": t0})`` sets any of them; the state must lie in the domain ``v in [-20, 20]``, ``y in [-5, 20]``.

    ## Episode End

    * ``terminated``: landed (``info["landed"]``), or the state left the hard constraint ``C1``
      (``info["hard_violation"]``), whichever comes first at a sub-step end (the step then ends there);
    * ``truncated``: the horizon ``T = 1 s`` was reached without either (the registered id also has
      ``max_episode_steps = 100``).

    ## Info

    ``t``, ``budget`` (``z``), ``budget_used`` (``Q - z``), ``budget_exceeded``
    (``z < 0``), ``cost`` (violation time in this step, ``int h_eps dt``; safety-gymnasium's convention),
    ``soft_violation`` / ``hard_violation`` (end state outside ``C2`` / ``C1``), ``landed`` and ``is_success``,
    ``action_physical`` (m/s^2), ``wind`` (m/s^2), ``reward_landing``, ``reward_failure``, ``reward_shaping``.

    ## Arguments

    ``gymnasium.make("softreach/PointMassLanding-v0", **kwargs)`` after ``import softreach.envs``; every option
    but ``model_params`` and ``render_mode`` is a field of :class:`~softreach.envs.config.LandingConfig`, and
    ``config=LandingConfig(...)`` passes them all at once (``PointMassLandingEnv.default_config.replace(...)``
    starts from this environment's defaults; keywords given next to it override its fields):

    * ``wind``: ``"none"`` (default), ``"random"`` (bounded Ornstein-Uhlenbeck gust from ``self.np_random``:
      ``gust_std`` m/s^2, default 5, correlation ``gust_tau`` s, default 0.1), ``"constant"`` (``wind_value``
      m/s^2), ``"adversarial"`` (the worst case ``b*`` of a ``W_eps`` table, ``wind_table=`` path or table), or a
      callable ``(t, state, budget, action) -> wind`` (physical units). Winds are clipped to ``[-10, 10]``
      unless ``clip_wind=False``; the wind is held over each period.
    * ``budget``: ``Q`` or a ``(low, high)`` range drawn at reset; ``eps``: the ``h_eps`` width (m/s).
    * ``dt``, ``n_substeps``, ``budget_resolution``: time stepping (see above). The registered step limit is
      ``T / 0.01 = 100``; with another ``dt`` pass ``max_episode_steps=ceil(T / dt)`` to ``gymnasium.make`` too
      (the env truncates itself at ``T`` in any case).
    * ``init_state_low`` / ``init_state_high``: the start box ``(v, y)``.
    * ``landing_reward``, ``failure_penalty``, ``progress_weight``, ``effort_weight``: reward terms.
    * ``model_params``: overrides of :class:`PointMassParams` (e.g. ``{"d_max": 5.0}``).
    * ``render_mode``: ``"rgb_array"`` or ``"human"`` (needs a display); matplotlib is imported on first render.
    """

    metadata = {"render_modes": render_modes(), "render_fps": 100}  # one frame per control period, real time

    default_config = LandingConfig(budget=(0.0, 0.6), dt=0.01, budget_resolution=1e-6,
                                   init_state_low=(-5.0, 1.0), init_state_high=(5.0, 12.0))

    def __init__(self, render_mode: str | None = None, *, config: LandingConfig | None = None,
                 model_params: dict[str, Any] | None = None, **options: Any):
        """:param render_mode: ``None``, ``"rgb_array"`` or ``"human"``
        :param config: the options (default :attr:`default_config`: ``budget=(0, 0.6)``, ``dt=0.01``,
            ``budget_resolution=1e-6``, the start box above, ``n_substeps`` the model's 10, and the
            :class:`~softreach.envs.config.LandingConfig` defaults)
        :param model_params: overrides of :class:`PointMassParams`
        :param options: :class:`~softreach.envs.config.LandingConfig` fields by name (the class docstring's
            "Arguments", in m/s^2, m/s and s), applied on top of ``config``
        """
        model = get_model("pointmass", **(model_params or {}))
        super().__init__(model=model, config=landing_config(config, self.default_config, options),
                         render_mode=render_mode)

    model: PointMass

    @property
    def params(self) -> PointMassParams:
        """The model's parameters."""
        return self.model.params

    def _render_layout(self) -> dict[str, Any]:
        p = self.model.params
        return {
            "title": "PointMassLanding",
            "horizon": self.horizon,
            "altitude_range": (self.state_low[1], self.state_high[1]),
            "altitude_limits": p.altitude,
            "target_altitude": p.target_altitude,
            "speed_name": "v [m/s]",
            "speed_range": (self.state_low[0], self.state_high[0]),
            "speed_soft": p.soft_speed,
            "speed_hard": p.hard_speed,
            "speed_target": p.target_speed,
            "action_name": "u [m/s²]",
            "action_scale": 1.0,
            "wind_name": "d [m/s²]",
            "wind_scale": 1.0,
            "altitude_index": 1,
            "speed_index": 0,
            "pitch_index": None,
        }
