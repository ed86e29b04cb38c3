"""Run plots (PNG): top view over the track, altitude, velocities, path error; for a
teach-and-repeat run also the taught poses and visual_servo.png (plots_vs.py)."""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from cosim.outputs.metrics import COL  # noqa: E402


def plot_run(res, world, out: Path) -> list[Path]:
    s = res.recorded.decimated()   # bounded point count whatever the mission length
    t = s[:, COL["t"]]
    paths = []

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    for i, line in enumerate(world.centreline()):
        ax.plot(line[:, 1], line[:, 0], "-", color="tab:red", lw=3, alpha=0.5,
                label="track centreline" if i == 0 else None)
    marker = getattr(world, "marker", None)
    if marker is not None:
        c = plt.Circle((marker.center[1], marker.center[0]), marker.radius, color="tab:red",
                       alpha=0.3, label="end marker")
        ax.add_patch(c)
    _draw_scene(ax, world.scene)
    if res.reference_poses:
        from cosim.outputs.plots_vs import draw_taught

        draw_taught(ax, res.reference_poses)
    ax.plot(s[:, COL["y"]], s[:, COL["x"]], "-", color="tab:blue", lw=1.2, label="vehicle")
    est = res.estimate is not None      # sensor-fed: the vehicle's own estimate beside it
    if est:
        ax.plot(s[:, COL["est_y"]], s[:, COL["est_x"]], "--", color="tab:green", lw=1.0,
                label="vehicle's estimate")
    if res.min_clearance is not None:
        k = int(np.argmin(np.abs(t - res.min_clearance[1])))
        ax.plot(s[k, COL["y"]], s[k, COL["x"]], "o", mfc="none", color="tab:orange", ms=10,
                label=f"min clearance {res.min_clearance[0]:.2f} m")
    if res.touchdown is not None:
        ax.plot(res.touchdown[2], res.touchdown[1], "kx", ms=9, label="touchdown")
    ax.set_xlabel("East (m)")
    ax.set_ylabel("North (m)")
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    outcome = res.app_metrics.get("outcome")
    ax.set_title(f"{res.scenario.name}: {res.exit_reason.value}"
                 + (f"\napp: {outcome}" if isinstance(outcome, str) else ""), fontsize=10)
    paths.append(_save(fig, out / "trajectory.png"))

    has_track = bool(world.centreline())
    fig, axs = plt.subplots(3 if has_track else 2, 1, figsize=(8, 7 if has_track else 5),
                            sharex=True)
    axs[0].plot(t, -s[:, COL["z"]], label="altitude")
    if est:
        axs[0].plot(t, -s[:, COL["est_z"]], ":", color="tab:green", label="estimate")
    sp = -s[:, COL["sp_z"]]
    axs[0].plot(t, sp, "--", label="setpoint")
    axs[0].set_ylabel("altitude (m)")
    axs[0].legend(fontsize=8)
    for name in ("vx", "vy", "vz"):
        axs[1].plot(t, s[:, COL[name]], label=name)
    axs[1].plot(t, np.hypot(s[:, COL["vx"]], s[:, COL["vy"]]), "k", lw=0.8, label="|v_h|")
    axs[1].set_ylabel("velocity NED (m/s)")
    axs[1].legend(fontsize=8, ncol=4)
    if has_track:
        _path_error(axs[2], res, world, s, t)
    _shade_phases(axs, res, s, t)
    axs[-1].set_xlabel("time (s)")
    for a in axs:
        a.grid(True, alpha=0.3)
    paths.append(_save(fig, out / "timeseries.png"))
    if res.reference_poses:
        from cosim.outputs.plots_vs import plot_visual_servo

        p = plot_visual_servo(res, out, _save)
        if p is not None:
            paths.append(p)
    return paths


def _path_error(ax, res, world, s, t) -> None:
    """The path error of the summary (progress.py), over the same following span."""
    from cosim.outputs.coverage import track_progress
    from cosim.outputs.metrics import COVERAGE_TOL_M

    span = _following_span(res, s, t)
    ax.set_ylabel("path error (m)")
    if span is None:
        ax.text(0.5, 0.5, "never following", transform=ax.transAxes, ha="center")
        return
    k = (t >= span[0]) & (t < span[1])
    _, err = track_progress(world.centreline(), s[k][:, [COL["x"], COL["y"]]],
                            COVERAGE_TOL_M)
    ax.plot(t[k], err, label="to the part of the track the vehicle should be on")
    ax.legend(fontsize=8)


def _following_span(res, s, t):
    if "following" not in res.phases:
        return None
    fol = np.flatnonzero(s[:, COL["phase"]] == res.phases.index("following"))
    return (t[fol[0]], t[fol[-1]] + 1e-9) if fol.size else None


def _shade_phases(axs, res, s, t) -> None:
    """Background bands per app phase (legend on the top axes), and the wind if any."""
    ph = s[:, COL["phase"]].astype(int)
    cuts = np.flatnonzero(np.diff(ph)) + 1
    starts = np.concatenate(([0], cuts))
    ends = np.concatenate((cuts, [len(ph)]))
    cmap = plt.get_cmap("Pastel1")
    seen = set()
    for a, b in zip(starts, ends, strict=True):
        i = int(ph[a])
        name = res.phases[i] if 0 <= i < len(res.phases) else "?"
        for ax in axs:
            ax.axvspan(t[a], t[b - 1], color=cmap(i % 9), alpha=0.35, lw=0,
                       label=name if ax is axs[0] and name not in seen else None)
        seen.add(name)
    axs[0].legend(fontsize=7, ncol=4, loc="upper right")
    wn, we, wd = res.scenario.wind_ned_mps
    spec = res.scenario.wind
    extra = ""
    if spec is not None and spec.turbulence is not None:
        extra += f", turbulence sigma {spec.turbulence[0]:g} m/s"
    if wn or we or wd or extra or (spec is not None and spec.gusts):
        axs[0].set_title(f"wind N {wn:g} E {we:g} D {wd:g} m/s{extra}"
                         + (", gusts hatched" if spec is not None and spec.gusts else ""),
                         fontsize=9)
    for g in (spec.gusts if spec is not None else ()):
        for ax in axs:
            ax.axvspan(g.start_s, g.start_s + g.duration_s, facecolor="none", hatch="//",
                       edgecolor="grey", lw=0)
    last = -1e9
    for tf, what in res.faults:                   # [faults]: when each took effect
        if "->" in what or tf - last < 0.5:       # end-of-run tallies; one mark per moment
            continue
        for ax in axs:
            ax.axvline(tf, color="tab:red", ls="--", lw=1,
                       label="fault" if ax is axs[0] and last < 0 else None)
        axs[0].annotate(what.split(" (fault")[0], (tf, 1.0), xycoords=("data", "axes fraction"),
                        fontsize=6, color="tab:red", rotation=90, va="top", ha="right")
        last = tf


def _draw_scene(ax, scene) -> None:
    """Top view of a 3D world: the room's walls, boxes (grey), columns (their colour)."""
    from cosim.world.surfaces import footprint

    if scene.room is not None:
        n0, n1, e0, e1 = scene.arena
        ax.plot([e0, e1, e1, e0, e0], [n0, n0, n1, n1, n0], "-", color="0.2", lw=2.5,
                label="walls")
    for i, b in enumerate(scene.boxes):
        foot = np.array(footprint(b.center, b.size[:2], b.heading, "bar", 4))
        ax.fill(foot[:, 1], foot[:, 0], color="0.6", alpha=0.7,
                label="boxes" if i == 0 else None)
    for i, c in enumerate(scene.columns):
        foot = np.array(footprint(c.center, c.size, c.heading, c.shape, c.sides))
        ax.fill(foot[:, 1], foot[:, 0], color=np.array(c.rgb) / 255.0,
                label="columns" if i == 0 else None)


def _save(fig, path: Path) -> Path:
    """Saved as PATH.part and renamed when whole (a full disk leaves no torn PNG)."""
    fig.tight_layout()
    part = path.with_name(path.name + ".part")
    try:
        fig.savefig(part, dpi=110, format=path.suffix.lstrip(".") or "png")
        os.replace(part, path)
    except OSError:
        part.unlink(missing_ok=True)
        raise
    finally:
        plt.close(fig)
    return path
