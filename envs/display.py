"""Drawing the landing environments: whether a window can be opened, the render modes to declare, and the
environments' ``render`` / ``close`` (frames come from :mod:`softreach.envs._render`, which imports matplotlib)."""

from __future__ import annotations

import os
import sys
from typing import Any

import gymnasium as gym


def has_display() -> bool:
    """Whether a window can be opened: on Linux, ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set; elsewhere assumed."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def render_modes() -> list[str]:
    """The render modes to declare: ``"rgb_array"`` always, ``"human"`` only where a display exists (so that
    ``gymnasium.utils.env_checker.check_env``, which opens every declared mode, passes on headless machines)."""
    return ["human", "rgb_array"] if has_display() else ["rgb_array"]


def _require_display() -> None:
    """Raise unless a window can be opened (render_mode='human')."""
    if not has_display():
        raise RuntimeError("render_mode='human' needs a display (no DISPLAY or WAYLAND_DISPLAY is set); use "
                           "render_mode='rgb_array' and save or show the frames instead")


class Rendering:
    """``render`` and ``close`` of :class:`~softreach.envs._common.LandingEnv`, a base class of it.

    It reads the environment's ``render_mode``, ``metadata``, its episode state (``_x``, ``_t``, ``_z``, ``_q``,
    ``_last_a``, ``_last_info``, ``_history``) and the subclass's :meth:`_render_layout`; it keeps the renderer in
    ``_renderer``.
    """

    def _render_view(self) -> dict[str, Any]:
        info = self._last_info
        return {"history": self._history, "t": self._t, "state": self._x, "budget": self._z,
                "budget_initial": self._q, "action": self._last_a, "wind": info.get("wind"),
                "landed": info.get("landed", False), "hard_violation": info.get("hard_violation", False)}

    def render(self):
        """Draw the current frame: an ``(H, W, 3)`` uint8 array for ``"rgb_array"``, a window for ``"human"``."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' "
                            "to the constructor (gymnasium.make(..., render_mode=...))")
            return None
        if self._x is None:
            raise gym.error.ResetNeeded("call reset() before render()")
        if self._renderer is None:
            from ._render import LandingRenderer  # matplotlib is imported only here

            self._renderer = LandingRenderer(self.render_mode, self._render_layout(), self.metadata["render_fps"])
        return self._renderer.draw(self._render_view())

    def _render_layout(self) -> dict[str, Any]:  # pragma: no cover - abstract
        raise NotImplementedError

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


__all__ = ["Rendering", "has_display", "render_modes"]
