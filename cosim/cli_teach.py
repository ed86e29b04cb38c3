"""`cosim teach SCENARIO`: the teach phase of teach-and-repeat, as its own command.

The scenario is a repeat scenario (`app.name = "visual_servo"`) whose `app.params.keys` lists
the poses to teach at. Two ways, both writing the folder format of visual_path.py:
- render (default): the scenario's front camera at each pose, level (fast, deterministic);
- `--fly`: the vehicle flies the poses as scripted position setpoints with the heading, hovers
  `--hover-s` at each, and the frame taken at the end of the hover is the key image (what
  the paper did); the stored pose is the true pose at that frame (for metrics only).
A repeat scenario then names the folder: `--set app.params.visual_path=FOLDER`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cosim.apps.scripted import ScriptedApp
from cosim.apps.vs import visual_path as VP
from cosim.errors import ScenarioError


class _TeachFlight(ScriptedApp):
    """The scripted app, keeping the last frame of each hover at a key as its image."""

    def __init__(self, params: dict, hover_s: float, is_key: list[bool]) -> None:
        super().__init__(params)
        self.hover_s = hover_s
        self.is_key = is_key
        self.captured: list[tuple[float, np.ndarray]] = []
        self._taken = -1

    def on_frame(self, t: float, image: np.ndarray) -> None:
        i = self._i
        if (self.phase == "waypoints" and self.is_key[i] and i != self._taken
                and not math.isnan(self._t_in) and t - self._t_in >= 0.8 * self.hover_s):
            self.captured.append((self.ctx.frame_time, image.copy()))   # its capture time
            self._taken = i


def parse_via(items: list[str], n_keys: int) -> dict[int, list[list[float]]]:
    """`K:N,E,D` (repeatable): fly through (N, E, D) before key K (1-based), not taught."""
    out: dict[int, list[list[float]]] = {}
    for item in items:
        k, _, pos = item.partition(":")
        try:
            ki = int(k)
            n, e, d = (float(v) for v in pos.split(","))
        except ValueError:
            raise ScenarioError("--via", item, "K:N,E,D (a key number and a position)") from None
        if not 1 <= ki <= n_keys or not all(math.isfinite(v) for v in (n, e, d)):
            raise ScenarioError("--via", item, f"a key number 1..{n_keys} and finite N,E,D")
        out.setdefault(ki - 1, []).append([n, e, d])
    return out


def _pose_at(res, t: float) -> tuple[float, float, float, float]:
    from cosim.sensors.pinhole import yaw_of

    ts, x, y, z, qw, qx, qy, qz = res.recorded.columns("t", "x", "y", "z", "qw", "qx", "qy",
                                                       "qz")
    i = min(int(np.searchsorted(ts, t)), len(ts) - 1)
    yaw = math.degrees(yaw_of((qw[i], qx[i], qy[i], qz[i])))
    return float(x[i]), float(y[i]), float(z[i]), yaw


def teach_command(args) -> int:
    from cosim.apps.vs.presets import resolve
    from cosim.load import load_scenario, with_set
    from cosim.scenario.sets import one_each

    sc = load_scenario(args.scenario)
    if args.set:
        sc = with_set(sc, one_each(args.set))
    if sc.app.name != "visual_servo":
        raise ScenarioError("app.name", sc.app.name, "visual_servo (a repeat scenario)")
    params = resolve(sc.app.params)        # checked when the scenario was loaded
    keys = params["keys"]
    if not keys:
        raise ScenarioError("app.params.keys", keys, "the [n, e, d, yaw_deg] poses to teach")
    detector, n_features = params["detector"], params["n_features"]
    out = Path(args.out or f"runs/visual-paths/{sc.name}")
    if out.exists() and not out.is_dir():
        raise ScenarioError("--out", str(out), "a folder for the visual path (this is a file)")
    poses = [tuple(float(v) for v in k) for k in keys]
    if not args.fly:
        VP.teach_by_render(sc, poses, out, detector, n_features)
        print(f"{out}: {len(poses)} key images rendered ({detector} features)")
        return 0
    from cosim.sim.master import RunOptions, run_scenario

    hover = float(args.hover_s)
    if not 0.2 <= hover <= 60.0:
        raise ScenarioError("--hover-s", hover, "a hover time of 0.2 to 60 s")
    via = parse_via(args.via, len(poses))
    route, is_key = [], []
    for i, (n, e, d, yaw) in enumerate(poses):
        for vn, ve, vd in via.get(i, []):
            route.append([vn, ve, vd, 0.0, yaw])
            is_key.append(False)
        route.append([n, e, d, hover, yaw])
        is_key.append(True)
    app = _TeachFlight({"takeoff_alt_m": float(params["takeoff_alt_m"]),
                        "waypoints": route, "tolerance_m": 0.05, "setpoint_every": 4},
                       hover, is_key)
    res = run_scenario(sc, RunOptions(app_override=app))
    if len(app.captured) < len(poses):
        print(f"cosim teach: the flight ended ({res.exit_reason.value}: {res.message}) after "
              f"{len(app.captured)} of {len(poses)} key images; nothing written")
        return 1
    flown = [_pose_at(res, t) for t, _ in app.captured]
    VP.write(out, [img for _, img in app.captured], flown, VP.camera_dict(sc.camera),
             detector, n_features, taught_by="flight", scenario=sc.name, world=sc.world.name)
    worst = max(math.dist(a[:3], b[:3]) for a, b in zip(flown, poses, strict=True))
    print(f"{out}: {len(poses)} key images taken in hover (largest offset from the listed "
          f"pose {worst:.3f} m; the true poses are stored)")
    return 0
