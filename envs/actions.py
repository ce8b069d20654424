"""The action map of the landing environments: the agent acts in ``[-1, 1]^m``, the model takes its physical
control box; affine both ways, with the checks of the step's hot path."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class ActionMapping:
    """Normalised <-> physical actions of :class:`~softreach.envs._common.LandingEnv`, a base class of it.

    It reads the environment's ``_m`` (control dimension), ``action_space``, and ``_a_mid`` / ``_a_half`` (the
    centre and half-width of the control box per component).
    """

    def physical_action(self, action: Any) -> np.ndarray:
        """Map a normalised action in ``[-1, 1]^m`` to the model's physical control (clipped first).

        :param action: normalised action(s), shape ``(..., m)``
        :return: physical control(s) of the same shape, in the model's units
        """
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return np.asarray(self._a_mid) + np.asarray(self._a_half) * a

    def normalized_action(self, physical: Any) -> np.ndarray:
        """Map a physical control to the normalised action space (inverse of :meth:`physical_action`).

        :param physical: control(s) in the model's units, shape ``(..., m)``
        :return: normalised action(s) as float32, not clipped (values outside ``[-1, 1]`` are out of range)
        """
        u = np.asarray(physical, dtype=np.float64)
        return ((u - np.asarray(self._a_mid)) / np.asarray(self._a_half)).astype(np.float32)

    def _action_to_physical(self, action: Any) -> list[float]:
        """Check an action and return the clipped physical control as floats (the hot path)."""
        if isinstance(action, np.ndarray) and action.shape == (self._m,) and action.dtype.kind in "fiu":
            vals = action.tolist()
        else:
            try:
                arr = np.asarray(action, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"action must be an array of shape ({self._m},), got {action!r}") from None
            if arr.shape != (self._m,):
                raise ValueError(f"action must have shape ({self._m},) (the action space is {self.action_space}), "
                                 f"got shape {arr.shape}: {action!r}")
            vals = arr.tolist()
        out = []
        for v, mid, half in zip(vals, self._a_mid, self._a_half):
            if not math.isfinite(v):
                raise ValueError(f"action must be finite, got {vals}")
            out.append(mid + half * (1.0 if v > 1.0 else (-1.0 if v < -1.0 else v)))
        return out


__all__ = ["ActionMapping"]
