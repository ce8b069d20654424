"""softreach.envs: Gymnasium environments of the paper's landing tasks.

Importing this package registers

* ``"softreach/PointMassLanding-v0"`` (:class:`PointMassLandingEnv`, paper §VI-A; 100 steps of 0.01 s), and
* ``"softreach/GliderLanding-v0"`` (:class:`GliderLandingEnv`, paper §VI-B; 100 steps of 0.1 s), and
* ``"softreach/SoftReach-v0"`` (:class:`SoftReachEnv`): any model, ``gymnasium.make("softreach/SoftReach-v0",
  model=MyModel())`` (it ends itself at the model's horizon; no step limit is registered),

so ``import softreach.envs; gymnasium.make("softreach/PointMassLanding-v0")`` works, and so does
``gymnasium.make("softreach.envs:softreach/PointMassLanding-v0")`` without the import (Gymnasium imports the
module named before the colon). Every environment takes its options as keywords or as one
:class:`LandingConfig` (``config=``). Rendering (matplotlib) is imported only when a frame is drawn.

``render_mode="rgb_array"`` is always available; ``"human"`` is declared in ``metadata["render_modes"]`` only
where a display exists (``DISPLAY`` or ``WAYLAND_DISPLAY`` on Linux), because
``gymnasium.utils.env_checker.check_env`` opens every declared mode and a headless machine cannot open a window.
``gymnasium.utils.env_checker.check_env`` and Stable-Baselines3's ``check_env`` pass on both environments
without warnings.
"""

from __future__ import annotations

from gymnasium.envs.registration import register, registry

from softreach.reach.sim.integrator import integrate_period, rk4_stages

from ._common import LandingEnv
from .config import LandingConfig
from .wind import OrnsteinUhlenbeckGust
from .glider_landing import GliderLandingEnv
from .pointmass_landing import PointMassLandingEnv
from .softreach_env import SoftReachEnv

#: environment id -> (entry point, max_episode_steps = horizon / default control period, None: the model's)
ENV_IDS = {
    "softreach/PointMassLanding-v0": ("softreach.envs.pointmass_landing:PointMassLandingEnv", 100),
    "softreach/GliderLanding-v0": ("softreach.envs.glider_landing:GliderLandingEnv", 100),
    "softreach/SoftReach-v0": ("softreach.envs.softreach_env:SoftReachEnv", None),
}


def _register_all() -> None:
    for env_id, (entry_point, steps) in ENV_IDS.items():
        if env_id not in registry:  # importing twice (e.g. reload) must not warn about re-registration
            register(id=env_id, entry_point=entry_point, max_episode_steps=steps)


_register_all()

__all__ = [
    "ENV_IDS",
    "GliderLandingEnv",
    "LandingConfig",
    "LandingEnv",
    "OrnsteinUhlenbeckGust",
    "PointMassLandingEnv",
    "SoftReachEnv",
    "integrate_period",
    "rk4_stages",
]
