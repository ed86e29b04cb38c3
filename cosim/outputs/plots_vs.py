"""Plots of a teach-and-repeat run (visual_servo app), like paper 2's figures:
visual_servo.png: eps and the 6-D error with the key switches, the commanded body velocities
with the feed-forward, and the activations h_a, h_m, h_t; taught poses on the top view."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np


def draw_taught(ax, poses) -> None:
    """The taught key poses on a top view (East right, North up), with their headings."""
    P = np.array(poses, dtype=float)
    ax.plot(P[:, 1], P[:, 0], "s", color="tab:green", ms=4, label="taught key poses")
    L = 0.15
    for n, e, _, yaw in P:
        ax.plot([e, e + L * math.sin(math.radians(yaw))], [n, n + L * math.cos(
            math.radians(yaw))], "-", color="tab:green", lw=1)


def plot_visual_servo(res, out: Path, save) -> Path | None:
    cols = res.frame_columns
    if not res.frame_log or cols is None or "eps_px" not in cols:
        return None
    F = np.array(res.frame_log, dtype=float)
    c = {name: i for i, name in enumerate(cols)}
    t = F[:, c["t"]]
    switches = res.app_metrics.get("switch_times_s") or []
    fig, axs = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    axs[0].plot(t, F[:, c["eps_px"]], "k", lw=1, label="eps (mean pixel error)")
    axs[0].set_ylabel("eps (px)")
    axs[0].set_yscale("log")
    for name, style in (("e_vx", "-"), ("e_vy", "-"), ("e_vz", "-"), ("e_wx", "--"),
                        ("e_wy", "--"), ("e_wz", "--")):
        axs[1].plot(t, F[:, c[name]], style, lw=1, label=name)
    axs[1].set_ylabel("visual error e")
    for name in ("vx", "vy", "vz", "wz"):
        line, = axs[2].plot(t, F[:, c[name]], lw=1, label=name)
        ff = F[:, c["ff_" + name]]
        if np.any(ff != 0.0):
            axs[2].plot(t, ff, ":", color=line.get_color(), lw=1, label="ff " + name)
    axs[2].set_ylabel("command, body (m/s, rad/s)")
    for name, label in (("h_a", "avoidance h_a"), ("h_m", "visibility h_m"),
                        ("h_t", "smoothing h_t")):
        axs[3].plot(t, F[:, c[name]], lw=1, label=label)
    axs[3].set_ylabel("activation")
    axs[3].set_xlabel("time (s)")
    for a in axs:
        for ts in switches:
            a.axvline(ts, color="grey", lw=0.6, alpha=0.6)
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7, ncol=6, loc="upper right")
    axs[0].set_title(f"{res.scenario.name}: {res.app_metrics.get('outcome', '')} "
                     "(grey: key switches)")
    return save(fig, out / "visual_servo.png")
