"""Parameters of the glider model (:class:`GliderParams`) and its angle units: every angle is in radians, and
the checks here refuse values that look like degrees."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .. import backend as B

#: an angle above this many radians (about 28.6 degrees) is far outside every set of this model and far more
#: likely a value in degrees; the checks below refuse it rather than fly a 5-radian dive
DEGREES_SUSPECT = 0.5


def degrees_to_radians(value: Any) -> Any:
    """Degrees to radians for a Python number, a numpy array or a torch tensor.

    :param value: angle(s) in degrees
    :return: the same angle(s) in radians, of the same kind
    """
    return value * (math.pi / 180.0)


def radians_to_degrees(value: Any) -> Any:
    """Radians to degrees for a Python number, a numpy array or a torch tensor.

    :param value: angle(s) in radians
    :return: the same angle(s) in degrees, of the same kind
    """
    return value * (180.0 / math.pi)


def _sin(v: Any) -> Any:
    # a component may be a Python number next to torch tensors; torch.sin refuses numbers
    return math.sin(v) if isinstance(v, (int, float)) else B.namespace(v).sin(v)


def _cos(v: Any) -> Any:
    return math.cos(v) if isinstance(v, (int, float)) else B.namespace(v).cos(v)


def _as_numpy(value: Any) -> np.ndarray:
    """A numpy copy of a number, array or tensor, for the (rare, user-facing) checks below."""
    return np.asarray(B.to_numpy(value), dtype=float)


def _check_radians(name: str, value: Any) -> None:
    """Raise if ``value`` is non-finite or large enough in magnitude to be an angle in degrees."""
    arr = _as_numpy(value)
    if arr.size == 0:
        return
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    worst = float(arr.flat[np.argmax(np.abs(arr))])
    if abs(worst) > DEGREES_SUSPECT:
        raise ValueError(
            f"radians expected for {name}, got {worst!r} (looks like degrees; "
            f"convert with softreach.reach.models.glider.degrees_to_radians)"
        )


@dataclass(frozen=True)
class GliderParams:
    """Parameters of the fixed-wing emergency landing (paper §VI-B, spec §3). Angles are in **radians**.

    Aircraft (DC9-30, Bayen et al. 2007):

    :param mass: ``m`` [kg]
    :param gravity: ``g`` [m/s^2]
    :param half_rho_s: ``rho S / 2`` [kg/m], the lift factor ``L = half_rho_s C_L V^2``; ``68.6`` is
        ``1.225 kg/m^3 * 112 m^2 / 2``
    :param cl0: lift coefficient at ``alpha = 0`` [-]
    :param cl_alpha: lift slope ``dC_L/dalpha`` [1/rad]; positive, so ``C_L`` grows with ``alpha``
    :param cd0: zero-lift drag factor [kg/m] in ``D = (cd0 + cd_k C_L^2) V^2`` (``rho S/2`` is folded in)
    :param cd_k: induced drag factor [kg/m] in the same formula

    Inputs:

    :param alpha_bounds: angle of attack range ``(lo, hi)`` [rad], default ``[0, 13 deg]``
    :param wind_max: wind force bound, ``F_wind in [-wind_max, wind_max]`` [N]

    Sets and horizon:

    :param hard_speed: stall / maximum descent speed, ``C1`` [m/s]
    :param hard_gamma: flight-path corridor, ``C1`` [rad], default ``[-3 deg, 0 deg]``
    :param min_altitude: ground level [m]; the touchdown band is centred on it and ``C1`` requires
        ``h >= min_altitude - touchdown_altitude`` (see :class:`Glider`, "Touchdown")
    :param soft_speed: recommended speed range (5 m/s margins inside ``hard_speed``), ``C2`` [m/s]
    :param touchdown_altitude: half-width ``hb`` of the touchdown band ``|h - min_altitude| <= hb`` [m]
    :param max_sink_rate: largest touchdown sink rate ``-V sin(gamma)`` [m/s] (3 ft/s)
    :param horizon: ``T`` [s]

    Scales of the implicit functions (each set function is a distance divided by these):

    :param altitude_scale: [m] per unit of the implicit functions
    :param speed_scale: [m/s] per unit
    :param gamma_scale: [rad] per unit, default one degree, so flight-path distances count in degrees
    :param sink_rate_scale: [m/s] per unit of the sink-rate term of the target
    """

    mass: float = 60000.0
    gravity: float = 9.8
    half_rho_s: float = 68.6
    cl0: float = 1.25
    cl_alpha: float = 4.2
    cd0: float = 2.7
    cd_k: float = 3.08
    alpha_bounds: tuple[float, float] = (0.0, math.radians(13.0))
    wind_max: float = 10000.0
    hard_speed: tuple[float, float] = (61.0, 83.0)
    hard_gamma: tuple[float, float] = (math.radians(-3.0), 0.0)
    min_altitude: float = 0.0
    soft_speed: tuple[float, float] = (66.0, 78.0)
    touchdown_altitude: float = 0.5
    max_sink_rate: float = 0.91
    horizon: float = 10.0
    altitude_scale: float = 1.0
    speed_scale: float = 1.0
    gamma_scale: float = math.radians(1.0)
    sink_rate_scale: float = 1.0

    def __post_init__(self):
        for name, value in asdict(self).items():
            values = value if isinstance(value, tuple) else (value,)
            if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values):
                raise ValueError(f"GliderParams.{name} must be finite numbers, got {value!r}")
        positive = ("mass", "gravity", "half_rho_s", "cl_alpha", "horizon", "touchdown_altitude", "max_sink_rate",
                    "altitude_scale", "speed_scale", "gamma_scale", "sink_rate_scale")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"GliderParams.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("cd0", "cd_k", "wind_max"):  # drag never pushes forward; the wind box is symmetric
            if getattr(self, name) < 0:
                raise ValueError(f"GliderParams.{name} must be non-negative, got {getattr(self, name)!r}")
        for name in ("alpha_bounds", "hard_speed", "hard_gamma", "soft_speed"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"GliderParams.{name} must be an interval lo < hi, got {(lo, hi)!r}")
        for name in ("alpha_bounds", "hard_gamma"):
            _check_radians(f"GliderParams.{name}", getattr(self, name))
        if self.hard_speed[0] <= 0:
            # gamma' divides by V; the hard constraint keeps trajectories away from V = 0
            raise ValueError(f"GliderParams.hard_speed must be positive, got {self.hard_speed!r}")


__all__ = ["GliderParams", "degrees_to_radians", "radians_to_degrees", "DEGREES_SUSPECT"]
