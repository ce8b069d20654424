"""Drawing of the landing environments with matplotlib (imported only when an environment renders).

A frame shows, left, the altitude against time so far with the ground, the touchdown band, the deadline ``T``
and the vehicle (for the glider, tilted by the flight-path angle, exaggerated ten times); right, a speed gauge
(recommended range ``C2`` in green, design limits ``C1`` in red, target speeds in grey) and a budget gauge
(remaining ``z`` against the episode's ``Q``; red once exceeded).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


class LandingRenderer:
    """One figure per environment, updated in place.

    :param mode: ``"rgb_array"`` (off-screen Agg canvas) or ``"human"`` (a pyplot window)
    :param layout: static description from the environment (ranges, limits, labels, state indices)
    :param fps: frames per second of ``"human"`` playback
    """

    def __init__(self, mode: str, layout: dict[str, Any], fps: float):
        self.mode = mode
        self.layout = layout
        self.fps = float(fps)
        if mode == "human":
            import matplotlib.pyplot as plt

            self._plt = plt
            plt.ion()
            self.fig = plt.figure(figsize=(6.4, 4.0), dpi=100)
            self.canvas = self.fig.canvas
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            self._plt = None
            self.fig = Figure(figsize=(6.4, 4.0), dpi=100)
            self.canvas = FigureCanvasAgg(self.fig)
        self._build()

    def _build(self) -> None:
        from matplotlib.patches import Rectangle

        L = self.layout
        fig = self.fig
        gs = fig.add_gridspec(1, 3, width_ratios=(6, 1, 1), wspace=0.6, left=0.09, right=0.97, top=0.86,
                              bottom=0.12)
        ax = fig.add_subplot(gs[0])
        a_lo, a_hi = L["altitude_range"]
        T = L["horizon"]
        ax.set_xlim(0.0, T * 1.02)
        ax.set_ylim(a_lo, a_hi)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("altitude [m]")
        ground = L["altitude_limits"][0]
        ax.add_patch(Rectangle((0.0, a_lo), T * 1.02, ground - a_lo, color="#8b6b4a", alpha=0.6, zorder=0))
        top = L["altitude_limits"][1]
        if math.isfinite(top):
            ax.axhline(top, color="#c0392b", lw=1, ls="--")
        t_lo, t_hi = L["target_altitude"]
        ax.add_patch(Rectangle((0.0, t_lo), T, t_hi - t_lo, color="#7f8c8d", alpha=0.5, zorder=1))
        ax.axvline(T, color="k", lw=1, ls=":")
        (self._trace,) = ax.plot([], [], color="#2c7fb8", lw=1.5, zorder=2)
        (self._vehicle,) = ax.plot([], [], marker=(3, 0, 0), markersize=12, color="#08306b", zorder=3, ls="none")
        self._ax = ax

        gv = fig.add_subplot(gs[1])
        s_lo, s_hi = L["speed_range"]
        gv.set_ylim(s_lo, s_hi)
        gv.set_xlim(0, 1)
        gv.set_xticks([])
        gv.set_title(L["speed_name"], fontsize=8)
        h_lo, h_hi = L["speed_hard"]
        c_lo, c_hi = L["speed_soft"]
        gv.add_patch(Rectangle((0, s_lo), 1, h_lo - s_lo, color="#c0392b", alpha=0.5))
        gv.add_patch(Rectangle((0, h_hi), 1, s_hi - h_hi, color="#c0392b", alpha=0.5))
        gv.add_patch(Rectangle((0, h_lo), 1, c_lo - h_lo, color="#f39c12", alpha=0.4))
        gv.add_patch(Rectangle((0, c_hi), 1, h_hi - c_hi, color="#f39c12", alpha=0.4))
        gv.add_patch(Rectangle((0, c_lo), 1, c_hi - c_lo, color="#27ae60", alpha=0.3))
        if L["speed_target"] is not None:
            g_lo, g_hi = L["speed_target"]
            gv.add_patch(Rectangle((0.25, g_lo), 0.5, g_hi - g_lo, color="#7f8c8d", alpha=0.8))
        (self._speed,) = gv.plot([0, 1], [0, 0], color="k", lw=3)
        gv.tick_params(labelsize=7)

        gb = fig.add_subplot(gs[2])
        gb.set_xlim(0, 1)
        gb.set_xticks([])
        gb.set_title("budget z [s]", fontsize=8)
        gb.tick_params(labelsize=7)
        self._budget_bar = Rectangle((0.15, 0.0), 0.7, 0.0, color="#2c7fb8")
        gb.add_patch(self._budget_bar)
        (self._budget_q,) = gb.plot([0, 1], [0, 0], color="k", lw=1, ls="--")
        gb.axhline(0.0, color="k", lw=0.8)
        self._gb = gb
        self._title = fig.suptitle("", fontsize=9)

    def draw(self, view: dict[str, Any]) -> np.ndarray | None:
        """Update the figure to ``view`` and return the frame (``rgb_array``) or show it (``human``)."""
        L = self.layout
        hist = view["history"] or []
        ia, isp = L["altitude_index"], L["speed_index"]
        ts = [row[0] for row in hist]
        alts = [row[1 + ia] for row in hist]
        self._trace.set_data(ts, alts)
        x = view["state"]
        if L["pitch_index"] is not None:
            pitch = math.degrees(x[L["pitch_index"]]) * 10.0  # exaggerated for visibility
            self._vehicle.set_marker((3, 0, pitch - 90.0))
        else:
            self._vehicle.set_marker("s")
        self._vehicle.set_data([view["t"]], [x[ia]])
        speed = x[isp]
        self._speed.set_ydata([speed, speed])
        q, z = view["budget_initial"], view["budget"]
        top = max(q, 1e-3 * L["horizon"])
        self._gb.set_ylim(min(0.0, z) - 0.05 * top, 1.1 * top)
        self._budget_bar.set_height(z)
        self._budget_bar.set_color("#c0392b" if z < 0 else "#2c7fb8")
        self._budget_q.set_ydata([q, q])
        a = view["action"][0] * L["action_scale"]
        wind = view["wind"]
        w = 0.0 if wind is None else float(np.asarray(wind).reshape(-1)[0]) * L["wind_scale"]
        status = "LANDED" if view["landed"] else ("HARD VIOLATION" if view["hard_violation"] else "")
        self._title.set_text(f"{L['title']}  t={view['t']:.2f} s  {L['action_name']}={a:.2f}  "
                             f"{L['wind_name']}={w:.2f}  {status}")
        if self.mode == "human":
            self.canvas.draw_idle()
            self.canvas.flush_events()
            self._plt.pause(1.0 / self.fps)
            return None
        self.canvas.draw()
        return np.asarray(self.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Release the figure (closes the window in ``human`` mode)."""
        if self._plt is not None:
            self._plt.close(self.fig)
        self.fig = None
