"""`cosim bench`'s paper-2 figures: the front-camera missions in x real time, and where a
front-camera tick goes (issue 29).

- "paper 2 E2 mission (x real time)": simulated time over the wall time of `run_scenario`
  (set-up, teach and flight; not the CSV and plots `cosim run` writes afterwards), MIL, one
  process. The first run in a process makes the world's textures, tiles and taught keys
  ("cold", what `cosim run` pays); the repeats find them made ("warm", what every run after the
  first in a study worker pays). Flown as a single run on a free 2-core machine is: with a
  camera latency (E1, E2) pipelined (cosim/sensors/stream.py: render, grey conversion and
  column detection in the stream's worker, a render process: cosim/sensors/render_proc.py),
  else OpenCV on both cores; "E2, OpenCV on one thread" is the sequential run a study worker
  makes.
- "E2 at 428x240": the same mission at half the Bebop 2 stream's resolution, the documented
  resolution choice of docs/performance-paper2.md (every pixel threshold scales with the
  width: cosim/apps/vs/features.py px_scale).
- E3 and E4 (the 30-key oval, at both sizes) likewise, without --quick.
- "CPU s per run": the run's own CPU time and its render worker's (a child process joined
  when the run ends), i.e. what one run of a study costs its worker, whatever the load; and
  each of the two apart (the process, all its threads: the main thread mostly; its children:
  the render worker when it is a process, with render, grey and columns), to see which side
  a pipelined run waits on.
- The breakdown of E2's front-camera tick at 428 x 240, ms per camera frame, from a
  sequential run on one thread (each part timed where it runs): render, grey conversion,
  column detection, tracking (LK + the epipolar outlier test), matching at a key change
  (features + match), homography and law (homographies, gain and law, hierarchy), the rest of
  the app's frame, and beside it the other ticks of a camera period (plant, flight stack, app
  ticks, master); then the same run pipelined, with the CPU time of the stream's worker (the
  render process, or thread where a fork is not safe) and of the main thread.

`python -m cosim.bench.paper2 [--quick]` prints these alone; `--against DIR` flies
E2 in fresh processes alternately with the code in DIR (e.g. a copy of the tree before a
change) and with this tree, and prints the ratio from that one sitting.
"""

from __future__ import annotations

import contextlib
import importlib
import resource
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cosim.bench.common import ROOT, _stat

HALF = {"camera.width": 428, "camera.height": 240}
# label: (scenario, target x real time, --set overrides); the targets are issue 41's (E2 at
# 856 x 480 10x, at 428 x 240 20x, E3/E4 6x; none given for E3/E4 at 428 x 240: 6x)
MISSIONS: dict[str, tuple[str, float, dict[str, Any]]] = {
    "E2": ("bebop2_vs_e2.toml", 10.0, {}),
    "E2 at 428x240": ("bebop2_vs_e2.toml", 20.0, HALF),
    "E3": ("bebop2_vs_oval.toml", 6.0, {}),
    "E4": ("bebop2_vs_oval_ff.toml", 6.0, {}),
    "E3 at 428x240": ("bebop2_vs_oval.toml", 6.0, HALF),
    "E4 at 428x240": ("bebop2_vs_oval_ff.toml", 6.0, HALF),
}
# (module, attribute owner or None for a module function, attribute, part)
PARTS = (
    ("cosim.sensors.front", "FrontCamera", "render", "render"),
    ("cosim.apps.vs.tasks", None, "gray_of", "grey conversion"),
    ("cosim.apps.vs.tasks", None, "find_obstacle", "detection (column)"),
    ("cosim.apps.vs.features", "Tracker", "track", "tracking (LK, outlier test)"),
    ("cosim.apps.visual_servo", None, "robust_inliers", "tracking (LK, outlier test)"),
    ("cosim.apps.vs.features", "Detector", "detect", "matching at key changes"),
    ("cosim.apps.visual_servo", None, "match", "matching at key changes"),
    ("cosim.apps.visual_servo", None, "homographies", "homography / law"),
    ("cosim.apps.visual_servo", "VisualServoApp", "_law", "homography / law"),
    ("cosim.apps.vs.geometry", None, "hierarchy", "homography / law"),
    ("cosim.apps.visual_servo", "VisualServoApp", "on_frame", "_on_frame"),
)
# what the stream's worker computes in a pipelined run
WORKER_PARTS = ("render", "grey conversion", "detection (column)")


def _scenario(name: str):
    from cosim.load import load_scenario, with_set

    file, _, sets = MISSIONS[name]
    sc = load_scenario(ROOT / "scenarios" / file)
    return with_set(sc, sets) if sets else sc


def _fly(name: str, pipeline: bool | None = None) -> tuple[float, float, str]:
    """(simulated s, wall s, exit reason) of one MIL run in this process; its CPU time goes
    to `_CPU` (on a host busy with other work, closer to what the run costs than its wall)."""
    from cosim.sim.master import RunOptions, run_scenario

    sc = _scenario(name)
    with tempfile.TemporaryDirectory(prefix="cosim-bench-") as tmp:
        t0, c0, k0 = time.perf_counter(), time.process_time(), _children_cpu()
        res = run_scenario(sc, RunOptions(mode="mil", out_dir=Path(tmp), pipeline=pipeline))
        wall = time.perf_counter() - t0
        _CPU.append(time.process_time() - c0)
        # the run's render worker (a child process, joined when the run ends) too: what one
        # run costs a study worker
        _RUN_CPU.append(_CPU[-1] + _children_cpu() - k0)
    _STREAM[:] = [res.camera_stream or {}]
    return res.t_end_s, wall, res.exit_reason.value


_CPU: list[float] = []
_RUN_CPU: list[float] = []


def _children_cpu() -> float:
    """CPU s of this process's children that have ended (user + system)."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime
_STREAM: list[dict[str, Any]] = [{}]     # the last run's camera_stream summary


@contextlib.contextmanager
def _threads(n: int | None) -> Iterator[None]:
    from cosim import cvthreads

    saved = cvthreads._run_threads
    cvthreads.set_run_threads(n)
    try:
        yield
    finally:
        cvthreads.set_run_threads(saved)


def mission(name: str, repeats: int, threads: int = 2) -> dict[str, Any]:
    """x real time of `repeats` runs of a paper-2 mission (the first one cold if the world
    was not flown yet in this process), as a single run on a free 2-core machine goes
    (`threads` 2: pipelined where the stream has a latency, else OpenCV on both cores), or
    sequential on one thread (`threads` 1). Set, not left to the load rule of
    cosim/cvthreads.py: the bench's own runs raise the load average it reads."""
    target = MISSIONS[name][1]
    with _threads(threads):
        runs = [_fly(name) for _ in range(repeats)]
    for _, _, why in runs:
        _check(name, why)
    rtf = [s / w for s, w, _ in runs]
    d = _stat(rtf, "x real time", target, higher_is_better=True)
    d.update(sim_time_s=runs[0][0], exit_reason=runs[0][2], wall_s=[w for _, w, _ in runs],
             cpu_s=_CPU[-repeats:], run_cpu_s=_RUN_CPU[-repeats:])
    return d


@contextlib.contextmanager
def _timing(acc: dict[str, float], calls: dict[str, int]) -> Iterator[None]:
    saved = []
    for mod_name, owner_name, attr, part in PARTS:
        mod = importlib.import_module(mod_name)
        owner = getattr(mod, owner_name) if owner_name else mod
        fn = owner.__dict__[attr] if owner_name else getattr(mod, attr)

        def timed(*a: Any, _fn: Any = fn, _part: str = part, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return _fn(*a, **kw)
            finally:
                acc[_part] = acc.get(_part, 0.0) + time.perf_counter() - t0
                calls[_part] = calls.get(_part, 0) + 1
        saved.append((owner, attr, fn))
        setattr(owner, attr, timed)
    try:
        yield
    finally:
        for owner, attr, fn in reversed(saved):
            setattr(owner, attr, fn)


@contextlib.contextmanager
def _thread_cpu(acc: dict[str, float]) -> Iterator[None]:
    """The CPU time of the stream's worker (its jobs, timed in the worker) and of the calling
    thread, over the block."""
    from cosim.sensors.stream import FrameStream

    render = FrameStream._render

    def timed(self: Any, *a: Any, **kw: Any) -> Any:
        c0 = time.thread_time()
        try:
            return render(self, *a, **kw)
        finally:
            acc["worker"] = acc.get("worker", 0.0) + time.thread_time() - c0
    FrameStream._render = timed            # type: ignore[method-assign]
    c0 = time.thread_time()
    try:
        yield
    finally:
        FrameStream._render = render       # type: ignore[method-assign]
        acc["main"] = time.thread_time() - c0


def _check(name: str, why: str) -> None:
    if why != "mission_complete":
        raise RuntimeError(f"cosim bench: {name} ended {why!r}: its timings would mean nothing")


def tick_breakdown(name: str = "E2", warm: bool = False) -> dict[str, Any]:
    """ms per camera frame of each part of a warm run of the mission (``warm``: it was
    flown in this process already), flown sequentially on one OpenCV thread so that every
    part is timed on its own; then the same mission pipelined, with the CPU time of its two
    threads (the stream's worker: render, grey, columns; the main thread: the rest)."""
    if not warm:
        _fly(name)                           # textures, tiles and keys made
    acc: dict[str, float] = {}
    calls: dict[str, int] = {}
    with _threads(1), _timing(acc, calls):
        sim, wall, why = _fly(name, pipeline=False)
    _check(name, why)
    frames = _STREAM[0]["frames"]            # per camera period (some are not rendered)
    parts = {p: 1e3 * acc.get(p, 0.0) / frames for p in dict.fromkeys(p[3] for p in PARTS)}
    on_frame = parts.pop("_on_frame")
    inside = sum(v for k, v in parts.items() if k not in ("render", "grey conversion",
                                                          "detection (column)"))
    parts["rest of the app's frame"] = on_frame - inside - parts["grey conversion"] - parts[
        "detection (column)"]
    camera_tick = parts["render"] + on_frame
    period = 1e3 * wall / frames
    out: dict[str, Any] = {
        "mission": name, "frames": frames, "rendered": calls["render"], "sim_time_s": sim,
        "wall_s": wall,
        "ms_per_frame": parts, "camera_tick_ms": camera_tick,
        "other_ticks_ms": period - camera_tick, "camera_period_ms": period}
    cpu: dict[str, float] = {}
    with _threads(2), _thread_cpu(cpu):
        sim2, wall2, why = _fly(name, pipeline=True)
    _check(name, why)
    st = _STREAM[0]
    worker = st.get("worker", "")
    out["pipelined"] = {"wall_s": wall2, "x_real_time": sim2 / wall2, "worker": worker,
                        "worker_cpu_s": (st.get("worker_cpu_s") or 0.0) if worker == "process"
                        else cpu.get("worker", 0.0), "main_cpu_s": cpu["main"]}
    return out


def bench_paper2(quick: bool = False) -> dict[str, Any]:
    """The missions in x real time (--quick: E2 once, cold, and E2 at 428 x 240 twice, the
    first cold; else 4 times each, and E3/E4 at both sizes twice), then E2's breakdown at
    428 x 240."""
    res: dict[str, Any] = {}
    res["E2"] = mission("E2", 1 if quick else 4)
    res["E2 at 428x240"] = mission("E2 at 428x240", 2 if quick else 4)
    if not quick:
        res["E2_one_thread"] = mission("E2", 3, threads=1)
        for k in ("E3", "E4", "E3 at 428x240", "E4 at 428x240"):
            res[k] = mission(k, 2)
    res["breakdown"] = tick_breakdown("E2 at 428x240", warm=True)
    return res


def format_paper2(res: dict[str, Any]) -> list[str]:
    def row(label: str, d: dict[str, Any]) -> str:
        ok = "ok" if d["meets_target"] else "MISSED"
        return (f"{label:<46s}{d['median']:>8.2f}{d['min']:>8.2f}{d['max']:>8.2f}  "
                f"{d['unit']:<12s} >= {d['target']:g}  {ok}")

    lines = [f"{'paper 2 missions: E2, E3, E4 at 856x480 unless named':<46s}"
             f"{'median':>8s}{'min':>8s}{'max':>8s}  (over the runs)"]
    for k in ("E2", "E2 at 428x240"):
        d = res[k]
        cold = d["sim_time_s"] / d["wall_s"][0]
        per_cpu = ", ".join(f"{d['sim_time_s'] / c:.1f}" for c in d["cpu_s"])
        run_cpu = ", ".join(f"{c:.1f} ({p:.1f} + {c - p:.1f})"
                            for c, p in zip(d["run_cpu_s"], d["cpu_s"], strict=True))
        lines += [row(f"paper 2 {k} mission (x real time)", d),
                  f"  first run in the process (cold: textures, tiles, keys made): {cold:.2f}x",
                  f"  simulated s per CPU s of the process, each run: {per_cpu}",
                  f"  CPU s per run (a study run's cost) = (this process, all its threads "
                  f"+ its children: the render worker when it is a process): {run_cpu}"]
        if k == "E2" and "E2_one_thread" in res:
            lines.append(row("  E2, OpenCV on one thread", res["E2_one_thread"]))
    for k in ("E3", "E4", "E3 at 428x240", "E4 at 428x240"):
        if k in res:
            lines.append(row(f"paper 2 {k} mission (x real time)", res[k]))
    b = res["breakdown"]
    lines.append(f"front-camera tick of {b['mission']}, sequential, one thread "
                 f"({b['frames']} frames, {b['rendered']} rendered; {b['sim_time_s']:.1f} s "
                 f"simulated in {b['wall_s']:.2f} s), ms per camera frame:")
    for k, v in b["ms_per_frame"].items():
        lines.append(f"  {k:<48s}{v:>8.3f}")
    lines.append(f"  {'= the camera tick (render + app frame)':<48s}{b['camera_tick_ms']:>8.3f}")
    lines.append(f"  {'the other ticks of a camera period':<48s}{b['other_ticks_ms']:>8.3f}")
    pl = b["pipelined"]
    lines.append(f"  pipelined (render, grey, columns in the stream's worker {pl['worker']}): "
                 f"{pl['x_real_time']:.2f}x real time")
    lines.append(f"    CPU s: worker {pl['worker_cpu_s']:.2f}, main thread "
                 f"{pl['main_cpu_s']:.2f}; wall {pl['wall_s']:.2f}")
    return lines


_FLY_ONE = ("import sys, time; from pathlib import Path; import tempfile\n"
            "from cosim.load import load_scenario\n"
            "from cosim.sim.master import RunOptions, run_scenario\n"
            "sc = load_scenario(sys.argv[1])\n"
            "with tempfile.TemporaryDirectory() as d:\n"
            "    t0, c0 = time.perf_counter(), time.process_time()\n"
            "    r = run_scenario(sc, RunOptions(mode='mil', out_dir=Path(d)))\n"
            "    print(r.t_end_s, time.perf_counter() - t0, time.process_time() - c0)\n")


def against(before: Path, name: str = "E2", rounds: int = 3) -> dict[str, Any]:
    """The mission flown cold in a fresh process (as `cosim run` does, without its outputs),
    alternately with the code in `before` (a copy of the tree with its built parts, put first
    on the path) and with this tree, `rounds` times each: the ratio from one sitting."""
    import os
    import subprocess

    path = ROOT / "scenarios" / MISSIONS[name][0]    # (its overrides are not applied)
    out: dict[str, list[float]] = {"before": [], "now": [], "before_cpu": [], "now_cpu": []}
    for _ in range(rounds):
        for label, src in (("before", Path(before).resolve()), ("now", ROOT)):
            env = {**os.environ, "PYTHONPATH": str(src)}
            r = subprocess.run([sys.executable, "-c", _FLY_ONE, str(path)], env=env, cwd=src,
                               capture_output=True, text=True, check=True)
            sim, wall, cpu = (float(v) for v in r.stdout.split())
            out[label].append(sim / wall)
            out[f"{label}_cpu"].append(sim / cpu)
    res: dict[str, Any] = {k: _stat(v, "x real time" if "cpu" not in k else "sim s / CPU s")
                           for k, v in out.items()}
    res["ratio"] = res["now"]["median"] / res["before"]["median"]
    res["ratio_cpu"] = res["now_cpu"]["median"] / res["before_cpu"]["median"]
    return res


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m cosim.bench.paper2",
        description="cosim bench's paper-2 figures alone: E2-E4 in x real time at 856x480 "
                    "and 428x240, and where a front-camera tick goes (a few minutes).")
    ap.add_argument("--quick", action="store_true",
                    help="E2 only: once at 856x480, twice at 428x240 (about 40 s)")
    ap.add_argument("--against", metavar="DIR", type=Path,
                    help="fly E2 alternately with the code in DIR (a copy of the tree, "
                         "built) and with this tree; print the ratio from that one sitting")
    args = ap.parse_args(argv)
    if args.against is not None:
        res = against(args.against)
        for k in ("before", "now", "before_cpu", "now_cpu"):
            d = res[k]
            print(f"E2 cold, {k:<11s}{d['median']:>8.2f} {d['unit']} (min {d['min']:.2f}, "
                  f"max {d['max']:.2f}, {d['n']} runs)")
        print(f"now / before: {res['ratio']:.2f} (wall), {res['ratio_cpu']:.2f} (CPU)")
        return 0
    res = bench_paper2(args.quick)
    print("\n".join(format_paper2(res)))
    print(f"(E2 at 856x480, wall s of each run: "
          f"{', '.join(f'{w:.2f}' for w in res['E2']['wall_s'])})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
