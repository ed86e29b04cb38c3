"""`cosim bench`'s paper-2 figures: the front-camera missions in x real time, and where a
front-camera tick goes (issue 29).

- "paper 2 E2 mission (x real time)": simulated time over the wall time of `run_scenario`
  (set-up, teach and flight; not the CSV and plots `cosim run` writes afterwards), MIL, one
  process. The first run in a process makes the world's textures, tiles and taught keys
  ("cold", what `cosim run` pays); the repeats find them made ("warm", what every run after the
  first in a study worker pays). OpenCV on every core (a single run) and on one thread (a
  study worker) from the same run.
- E3 and E4 (the 30-key oval) likewise, warm, without --quick.
- The breakdown of E2's front-camera tick, ms per camera frame: render, column detection,
  tracking (LK + the epipolar outlier test), matching at a key change (features + match),
  homography and law (homography, gain and law, hierarchy), the rest of the app's frame,
  and beside it the other ticks of a camera period (plant, flight stack, app ticks, master).

`python -m cosim.studies.bench_paper2 [--quick]` prints these alone; `--against DIR` flies
E2 in fresh processes alternately with the code in DIR (e.g. a copy of the tree before a
change) and with this tree, and prints the ratio from that one sitting.
"""

from __future__ import annotations

import contextlib
import importlib
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from cosim.studies.bench_common import ROOT, _stat

MISSIONS = {"E2": ("bebop2_vs_e2.toml", 15.0), "E3": ("bebop2_vs_oval.toml", 12.0),
            "E4": ("bebop2_vs_oval_ff.toml", 12.0)}       # scenario, target (x real time)
# (module, attribute owner or None for a module function, attribute, part)
PARTS = (
    ("cosim.sensors.front", "FrontCamera", "render", "render"),
    ("cosim.apps.visual_servo", None, "find_obstacle", "detection (column)"),
    ("cosim.apps.vs.features", "Tracker", "track", "tracking (LK, outlier test)"),
    ("cosim.apps.visual_servo", None, "robust_inliers", "tracking (LK, outlier test)"),
    ("cosim.apps.vs.features", "Detector", "detect", "matching at key changes"),
    ("cosim.apps.visual_servo", None, "match", "matching at key changes"),
    ("cosim.apps.visual_servo", None, "homography", "homography / law"),
    ("cosim.apps.visual_servo", "VisualServoApp", "_law", "homography / law"),
    ("cosim.apps.vs.geometry", None, "hierarchy", "homography / law"),
    ("cosim.apps.visual_servo", "VisualServoApp", "on_frame", "_on_frame"),
)


def _fly(path: Path) -> tuple[float, float, str]:
    """(simulated s, wall s, exit reason) of one MIL run in this process; its CPU time goes
    to `_CPU` (on a host busy with other work, closer to what the run costs than its wall)."""
    from cosim.scenario.parse import load_scenario
    from cosim.sim.master import RunOptions, run_scenario

    sc = load_scenario(path)
    with tempfile.TemporaryDirectory(prefix="cosim-bench-") as tmp:
        t0, c0 = time.perf_counter(), time.process_time()
        res = run_scenario(sc, RunOptions(mode="mil", out_dir=Path(tmp)))
        wall = time.perf_counter() - t0
        _CPU.append(time.process_time() - c0)
    return res.t_end_s, wall, res.exit_reason.value


_CPU: list[float] = []


@contextlib.contextmanager
def _threads(n: int | None) -> Iterator[None]:
    from cosim import cvthreads

    saved = cvthreads._run_threads
    cvthreads.set_run_threads(n)
    try:
        yield
    finally:
        cvthreads.set_run_threads(saved)


def mission(name: str, repeats: int, threads: int | None = None) -> dict[str, Any]:
    """x real time of `repeats` runs of a paper-2 mission (the first one cold if the world
    was not flown yet in this process)."""
    file, target = MISSIONS[name]
    with _threads(threads):
        runs = [_fly(ROOT / "scenarios" / file) for _ in range(repeats)]
    rtf = [s / w for s, w, _ in runs]
    d = _stat(rtf, "x real time", target, higher_is_better=True)
    d.update(sim_time_s=runs[0][0], exit_reason=runs[0][2], wall_s=[w for _, w, _ in runs],
             cpu_s=_CPU[-repeats:])
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


def tick_breakdown(name: str = "E2", warm: bool = False) -> dict[str, Any]:
    """ms per camera frame of each part of a warm run of the mission (``warm``: it was
    flown in this process already)."""
    file = MISSIONS[name][0]
    if not warm:
        _fly(ROOT / "scenarios" / file)      # textures, tiles and keys made
    acc: dict[str, float] = {}
    calls: dict[str, int] = {}
    with _timing(acc, calls):
        sim, wall, _ = _fly(ROOT / "scenarios" / file)
    frames = calls["render"]
    parts = {p: 1e3 * acc.get(p, 0.0) / frames for p in dict.fromkeys(p[3] for p in PARTS)}
    on_frame = parts.pop("_on_frame")
    inside = sum(v for k, v in parts.items() if k != "render")
    parts["rest of the app's frame"] = on_frame - inside
    camera_tick = parts["render"] + on_frame
    period = 1e3 * wall / frames
    return {"mission": name, "frames": frames, "sim_time_s": sim, "wall_s": wall,
            "ms_per_frame": parts, "camera_tick_ms": camera_tick,
            "other_ticks_ms": period - camera_tick, "camera_period_ms": period}


def bench_paper2(quick: bool = False) -> dict[str, Any]:
    res: dict[str, Any] = {}
    res["E2"] = mission("E2", 1 if quick else 4)
    if not quick:                            # --quick: E2 once, then its breakdown
        res["E2_one_thread"] = mission("E2", 3, threads=1)
        res["E3"] = mission("E3", 2)
        res["E4"] = mission("E4", 2)
    res["breakdown"] = tick_breakdown("E2", warm=True)
    return res


def format_paper2(res: dict[str, Any]) -> list[str]:
    def row(label: str, d: dict[str, Any]) -> str:
        ok = "ok" if d["meets_target"] else "MISSED"
        return (f"{label:<34s}{d['median']:>10.2f}{d['min']:>10.2f}{d['max']:>10.2f}  "
                f"{d['unit']:<12s} >= {d['target']:g}  {ok}")

    e2 = res["E2"]
    cold = e2["sim_time_s"] / e2["wall_s"][0]
    per_cpu = ", ".join(f"{e2['sim_time_s'] / c:.1f}" for c in e2["cpu_s"])
    lines = [row("paper 2 E2 mission (x real time)", e2),
             f"  E2 first run in the process (cold: textures, tiles, keys made): {cold:.2f}x",
             f"  E2 simulated s per CPU s of the process, each run: {per_cpu}"]
    if "E2_one_thread" in res:
        lines.append(row("  E2, OpenCV on one thread", res["E2_one_thread"]))
    for k in ("E3", "E4"):
        if k in res:
            lines.append(row(f"paper 2 {k} mission (x real time)", res[k]))
    b = res["breakdown"]
    lines.append(f"front-camera tick of {b['mission']} ({b['frames']} frames, "
                 f"{b['sim_time_s']:.1f} s simulated in {b['wall_s']:.2f} s), ms per frame:")
    for k, v in b["ms_per_frame"].items():
        lines.append(f"  {k:<48s}{v:>8.3f}")
    lines.append(f"  {'= the camera tick (render + app frame)':<48s}{b['camera_tick_ms']:>8.3f}")
    lines.append(f"  {'the other ticks of a camera period':<48s}{b['other_ticks_ms']:>8.3f}")
    return lines


_FLY_ONE = ("import sys, time; from pathlib import Path; import tempfile\n"
            "from cosim.scenario.parse import load_scenario\n"
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

    path = ROOT / "scenarios" / MISSIONS[name][0]
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
    args = argv if argv is not None else sys.argv[1:]
    if "--against" in args:          # python -m cosim.studies.bench_paper2 --against DIR
        res = against(Path(args[args.index("--against") + 1]))
        for k in ("before", "now", "before_cpu", "now_cpu"):
            d = res[k]
            print(f"E2 cold, {k:<11s}{d['median']:>8.2f} {d['unit']} (min {d['min']:.2f}, "
                  f"max {d['max']:.2f}, {d['n']} runs)")
        print(f"now / before: {res['ratio']:.2f} (wall), {res['ratio_cpu']:.2f} (CPU)")
        return 0
    quick = "--quick" in args
    res = bench_paper2(quick)
    print("\n".join(format_paper2(res)))
    print(f"(E2 wall times: {', '.join(f'{w:.2f}' for w in res['E2']['wall_s'])} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
