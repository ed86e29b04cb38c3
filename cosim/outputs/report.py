"""Writes a run folder: summary.json, timeseries.csv, frames.csv, camera_frames.csv,
flight.tlog, plots, video."""

from __future__ import annotations

import contextlib
import math
import os
import platform
import shutil
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from cosim import numerics
from cosim.errors import output_error
from cosim.outputs.folder import check_inputs_kept, clean_run_folder
from cosim.outputs.metrics import COL, compute_metrics, evaluate
from cosim.outputs.result import RunResult
from cosim.outputs.series import ESTIMATE_COLUMNS, SERIES_COLUMNS
from cosim.outputs.strict import dumps as strict_dumps
from mav.params import EST_RELEASE
from onesource import switch as compiled

FAILED_EXITS = {"component_error", "crashed", "left_arena", "collision", "interrupted",
                "app_aborted"}
def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("cosim", "fmpy", "pymavlink", "numpy", "opencv-python-headless", "control"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def summarize(res: RunResult) -> dict[str, Any]:
    metrics = compute_metrics(res, res.scenario.world)
    crit = evaluate(res.scenario.criteria, metrics, res.exit_reason)
    sc = res.scenario
    return {
        "scenario": sc.name,
        "source": sc.source,
        "description": sc.description,
        "vehicle": sc.vehicle.name,
        "app": sc.app.name,
        "sensors": sc.sensors.describe() if sc.sensors is not None else "truth ODOMETRY",
        "estimator": estimator_name(sc),
        "seed": sc.seed,
        "mode": res.mode,
        "exit_reason": res.exit_reason.value,
        "message": res.message,
        "sim_time_s": res.t_end_s,
        "wall_time_s": res.wall_s,
        "real_time_factor": res.real_time_factor,
        "realtime_stalls": res.realtime_stalls,        # real time: host stalls skipped
        "realtime_lost_s": res.realtime_lost_s,        # s of wall time they lost
        "ticks": res.ticks,
        "metrics": metrics,
        "criteria": crit,
        # a run that ended in an error never passes, whatever the criteria say
        "passed": all(c["passed"] for c in crit.values())
        and res.exit_reason.value not in FAILED_EXITS,
        "events": [[t, name] for t, name in res.events],
        "faults": [[t, what] for t, what in res.faults],   # [faults]: when each took effect
        # the camera's stream: latency, jitter, frames delivered, their delay and blur
        "camera_stream": res.camera_stream,
        "onboard_stats": res.onboard_stats,
        "warnings": res.warnings,          # e.g. a full TMPDIR (the series held in memory)
        "versions": versions(),
        # compiled or interpreted, and why (onesource/switch.py; the flight is the same either way)
        "implementation": compiled.describe(),
        # the CPU code each library ran: "portable" = the same bits on every x86-64 CPU
        "numerics": numerics.describe(),
        "platform": f"{platform.system()} {platform.machine()}, {sys.implementation.name}",
    }


LINE_FRAME_COLUMNS = ("t", "flag_track", "flag_marker", "e_x_px", "e_y_px")


def write_run(res: RunResult, out: Path, *, plots: bool = True,
              extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write everything the run recorded into `out`; returns the summary dict.

    The run streamed its tlog, video and PNG frames into `res.run_dir`; they are copied when
    `out` is another folder. `extra`: more summary fields from the caller (`cosim sitl`: the
    vehicle's instance, links and respawns).

    Every file is written to `NAME.part` and renamed when complete, so no truncated file is
    left under its real name; `summary.json` comes last. A file that cannot be written (disk
    full, ...) is listed in the summary's `output_errors` and the run does not pass; if the
    summary itself cannot be written, OutputError says so.
    """
    out.mkdir(parents=True, exist_ok=True)
    same = out.resolve() == res.run_dir.resolve()
    if not same:
        from cosim.apps.registry import app_inputs

        check_inputs_kept(out, app_inputs(res.scenario.app, res.scenario.source))
        clean_run_folder(out)
    summary = summarize(res)
    summary.update(extra or {})
    errors: list[str] = []

    def put(name: str, write) -> None:
        path = out / name
        part = out / (name + ".part")
        try:
            write(part)
            os.replace(part, path)
        except OSError as exc:
            errors.append(f"{name}: {exc.strerror or exc}")
            with contextlib.suppress(OSError):
                part.unlink()

    put("timeseries.csv", lambda p: write_series(res, p))
    if res.frame_log:
        put("frames.csv", lambda p: _write_frames(res, p))
    if res.frame_times:
        put("camera_frames.csv", lambda p: _write_camera_frames(res, p))
    if not (same and (out / "flight.tlog").resolve() == res.tlog.path.resolve()):
        put("flight.tlog", res.tlog.write)
    if plots and res.ticks > 1:
        from cosim.outputs.plots import plot_run

        try:
            plot_run(res, res.scenario.world, out)
        except OSError as exc:
            errors.append(f"plots: {exc.strerror or exc}")
    if not same:
        for src in (res.video, res.mcap):
            if src is not None:
                put(src.name, lambda p, src=src: shutil.copyfile(src, p))
        if res.png_count:
            try:
                shutil.copytree(res.run_dir / "frames", out / "frames", dirs_exist_ok=True)
            except OSError as exc:
                errors.append(f"frames: {exc.strerror or exc}")
    tlog_error = res.tlog.error
    if tlog_error is not None:       # the streamed log stopped: it holds whole records only
        errors.append(f"flight.tlog: {tlog_error.strerror or tlog_error} (cut at its last "
                      "whole record)")
    if errors:
        summary["output_errors"] = errors
        summary["passed"] = False
    text = strict_dumps(summary, indent=2)       # strict JSON: null for NaN, real booleans
    try:
        part = out / "summary.json.part"
        part.write_text(text)
        os.replace(part, out / "summary.json")
    except OSError as exc:
        with contextlib.suppress(OSError):
            part.unlink()
        raise output_error(exc, out / "summary.json", "the other outputs that fit are written"
                           + (f" ({'; '.join(errors)})" if errors else "")) from None
    return summary


def _write_frames(res: RunResult, path: Path) -> None:
    with open(path, "w") as f:
        f.write(",".join(res.frame_columns or LINE_FRAME_COLUMNS) + "\n")
        for r in res.frame_log:
            f.write(",".join(repr(float(v)) for v in r) + "\n")


def _write_camera_frames(res: RunResult, path: Path) -> None:
    """Every frame the app was handed: its capture and delivery times (cosim/sensors/stream.py)."""
    from cosim.sensors.stream import frame_rows

    with open(path, "w") as f:
        f.write("frame,t_capture_s,t_delivery_s,delay_s,blur_px\n")
        for i, tc, td, d, b in frame_rows(res.frame_times, res.scenario.timing.tick_s):
            f.write(f"{i},{tc!r},{td!r},{d!r},{b!r}\n")


def write_series(res: RunResult, path: Path) -> None:
    phase_names = np.array(res.phases + ["?"], dtype=object)
    est = res.estimate                  # sensor-fed: the rest of the estimate (est_x/y/z are
    extra = () if est is None else ESTIMATE_COLUMNS[3:]   # in the series already)
    with open(path, "w") as f:
        f.write(",".join(SERIES_COLUMNS) + ",phase_name" + "".join("," + c for c in extra)
                + "\n")
        pcol = COL["phase"]
        k = 0
        for block in res.recorded.blocks():
            for row in block:
                f.write(",".join(repr(float(v)) for v in row))
                f.write("," + phase_names[int(row[pcol])])
                if extra:
                    e = est[k] if k < len(est) else (math.nan,) * len(ESTIMATE_COLUMNS)
                    f.write("".join("," + repr(float(v)) for v in e[3:]))
                k += 1
                f.write("\n")


def _rtf(x: float) -> str:
    """x real time, to the digits that mean something: 2.65x, 11.3x, 412x."""
    return f"{x:.2f}x" if x < 10 else f"{x:.1f}x" if x < 100 else f"{x:.0f}x"


def one_screen(summary: dict[str, Any], out: Path | None = None) -> str:
    m = summary["metrics"]
    lines = [
        f"scenario  {summary['scenario']}  ({summary['vehicle']}, app {summary['app']}, "
        f"{summary['mode'].upper()}, seed {summary['seed']})",
        f"exit      {summary['exit_reason']}: {summary['message']}",
        f"sensors   {summary['sensors']}; estimator {summary['estimator']}",
        *([f"app       {summary['metrics']['outcome']}"]
          if isinstance(summary["metrics"].get("outcome"), str) else []),
        f"sim time  {summary['sim_time_s']:.2f} s in {summary['wall_time_s']:.2f} s wall "
        f"({_rtf(summary['real_time_factor'])} real time)",
    ]
    st = summary.get("camera_stream")
    if st:       # how the frames were made: the render worker or not, the frames not needed
        how = {"process": "rendered in a worker process", "thread": "rendered in a worker "
               "thread"}.get(st.get("worker", ""), "rendered in the loop")
        lines.append(f"camera    {st['frames']} frames ({st.get('skipped', 0)} not needed, "
                     f"not rendered), {how}")
    fmt = {
        "mission_time_s": ("mission time", "{:.2f} s"),
        "track_coverage": ("track coverage", "{:.1%}"),
        "path_error_rms_m": ("path error RMS", "{:.3f} m"),
        "path_error_max_m": ("path error max", "{:.3f} m"),
        "landing_error_m": ("landing error", "{:.3f} m"),
        "line_in_view_s": ("line in view", "{:.1f} s"),
        "speed_mean_mps": ("speed mean", "{:.2f} m/s"),
        "speed_max_mps": ("speed max", "{:.2f} m/s"),
        "position_error_max_m": ("waypoint error max", "{:.3f} m"),
        "min_clearance_m": ("min clearance", "{:.3f} m"),
        "keys_reached": ("keys reached", "{:d}"),
        "goal_time_s": ("last key at", "{:.2f} s"),
        "final_pose_error_m": ("final pose error", "{:.3f} m"),
        "final_yaw_error_deg": ("final yaw error", "{:.2f} deg"),
        "taught_path_speed_mps": ("taught path speed", "{:.3f} m/s"),
        "estimation_error_pos_rms_m": ("estimate pos RMS", "{:.3f} m"),
        "estimation_error_pos_max_m": ("estimate pos max", "{:.3f} m"),
        "estimation_error_att_rms_deg": ("estimate att RMS", "{:.2f} deg"),
        "estimation_error_vel_rms_mps": ("estimate vel RMS", "{:.3f} m/s"),
    }
    for key, (label, f) in fmt.items():
        if key in m and m[key] is not None:
            lines.append(f"  {label:<20s}{f.format(m[key])}"
                         + (f"  to the {m['min_clearance_to']} at t = "
                            f"{m['min_clearance_t_s']:.2f} s" if key == "min_clearance_m" else ""))
    for name, c in summary["criteria"].items():
        v = c["value"]
        vs = f"{v:.3f}" if isinstance(v, float) else str(v)
        lines.append(f"  [{'PASS' if c['passed'] else 'FAIL'}] {name}: {vs} (limit {c['limit']})")
    for e in summary.get("output_errors", ()):
        lines.append(f"  [FAIL] output not written: {e}")
    lines.append(f"result    {'PASSED' if summary['passed'] else 'FAILED'}"
                 + (f"   outputs in {out}" if out else ""))
    return "\n".join(lines)


def estimator_name(sc) -> str:
    """The estimator the vehicle flies on, as the summary names it."""
    if sc.sensors is None or not sc.sensors.hil:
        return "none (truth ODOMETRY)"
    kind = dict(sc.onboard_params).get("TPL_EST_TYPE")
    return ("paper 1's release (TPL_EST_TYPE 2)" if kind == EST_RELEASE
            else "template with ours (TPL_EST_TYPE 1)")
