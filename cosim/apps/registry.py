"""The offboard apps a scenario can name: built-in names, or a user's `package.module:Class`.

A scenario that names a plugin app runs that plugin's code: its module is imported when the
scenario is loaded, and the class is constructed when the scenario runs. What is checked
before anything of the plugin is called (`plugin_class`): the name is `module:Class` with
identifiers only, the module is not part of Python's standard library (no app lives there,
and importing some of its modules has side effects), and the attribute is a class with the
app contract's methods (`on_start`, `on_frame`, `on_tick`). A callable that is not such a
class (`subprocess:Popen`, `os:system`) is refused with a ScenarioError naming `app.name`,
never called.

`make_app(spec)` builds the app (apps check their parameters in their constructor and raise
ValueError naming `app.params.NAME`). `check_app(spec)` runs at load time: a built-in app is
built once (our code) so a bad parameter fails early; a plugin is only checked as above, not
constructed.
"""

from __future__ import annotations

import importlib
import inspect
import math
import sys
from pathlib import Path

import numpy as np

from cosim.errors import ComponentError, ScenarioError
from cosim.scenario.records import AppSpec

BUILTIN_APPS = ("line_follower", "scripted", "visual_servo", "none")
CONTRACT_METHODS = ("on_start", "on_frame", "on_tick")


def plugin_class(name: str) -> type:
    """The class a `package.module:Class` name designates, checked against the app contract
    before anything of it is called. ScenarioError (field `app.name`) when it is not one."""
    mod, sep, cls_name = name.partition(":")
    if (not sep or not cls_name.isidentifier()
            or not all(part.isidentifier() for part in mod.split("."))):
        raise ScenarioError("app.name", name, "one of " + ", ".join(BUILTIN_APPS)
                            + " or 'package.module:Class' (identifiers only)")
    if mod.split(".")[0] in sys.stdlib_module_names:
        raise ScenarioError("app.name", name, "an app class in your own package (standard "
                            "library modules are not apps and are not imported)")
    try:
        module = importlib.import_module(mod)
    except Exception as exc:
        raise ScenarioError("app.name", name, f"an importable module ({type(exc).__name__}: "
                            f"{exc})") from None
    obj = inspect.getattr_static(module, cls_name, None)
    missing = [m for m in CONTRACT_METHODS
               if not callable(inspect.getattr_static(obj, m, None))] if inspect.isclass(obj) \
        else list(CONTRACT_METHODS)
    if not inspect.isclass(obj) or missing:
        raise ScenarioError("app.name", name, "a class with the app contract of "
                            "cosim/apps/base.py (missing: " + ", ".join(missing) + ")")
    return obj


def make_app(spec: AppSpec):
    """The app object for `spec`, or None for the app 'none'."""
    name = spec.name
    if name == "none":
        return None
    if name == "scripted":
        from cosim.apps.scripted import ScriptedApp

        return ScriptedApp(spec.params)
    if name == "line_follower":
        from cosim.apps.line_follower import LineFollowerApp

        return LineFollowerApp(spec.params)
    if name == "visual_servo":
        from cosim.apps.visual_servo import VisualServoApp

        return VisualServoApp(spec.params)
    try:
        cls = plugin_class(name)
    except ScenarioError as exc:
        raise ComponentError("app", str(exc)) from None
    return cls(spec.params)


def app_inputs(spec: AppSpec, source: str | None) -> dict[str, Path]:
    """The files and folders the app reads (field -> path), so that a run never clears one."""
    if spec.name == "visual_servo" and isinstance(spec.params.get("visual_path"), str) \
            and spec.params["visual_path"]:
        from cosim.apps.vs.visual_path import folder_of

        return {"app.params.visual_path": folder_of(spec.params["visual_path"], source)}
    return {}


def check_app(spec: AppSpec) -> None:
    """At load time: a built-in app is built once, so a bad parameter fails here; a plugin is
    checked against the contract without being constructed. Errors are ScenarioErrors."""
    if spec.name not in BUILTIN_APPS:
        plugin_class(spec.name)
        return
    try:
        make_app(spec)
    except ValueError as exc:
        msg = str(exc)
        head, _, rest = msg.partition(":")
        if not head.startswith("app.params"):
            head, rest = "app.params", msg
        rest = rest.strip()
        if rest.startswith("got ") and ";" in rest:  # "got X; expected Y" -> "Y"
            rest = rest.split(";", 1)[1].strip()
        for lead in ("expected ", "allowed: "):
            rest = rest.removeprefix(lead)
        raise ScenarioError(head, _param_value(spec, head), rest) from None


def check_inputs(spec: AppSpec, camera, source: str | None, arena=None, scene=None,
                 body_radius: float = 0.0) -> None:
    """At load time: what the app reads (app_inputs) exists and fits the scenario (a visual
    path is a readable taught folder for the scenario's camera, with one `sigma` per key when
    a list), and every point it flies to is inside the arena and above the floor.
    A pose the visual servo is to be taught at (`app.params.keys`, issue 28) must also be a
    pose the vehicle can hold in the world (`scene`, a 3D world): its body sphere
    (`body_radius`) clear of every wall, the ceiling, box and column (the collision query
    `Scene.clearance`) and of the floor. (A taught folder's poses are the ones it was taught
    at, for metrics only: checked against the arena alone.) With feed-forward the taught
    path, poses and legs, must keep `ff_clearance_m` from the room (`_check_feedforward_clear`;
    a taught folder's poses too).
    ScenarioError naming the field, with the file and field at fault."""
    points: list[tuple[str, tuple[float, ...]]] = []
    poses: list[tuple[str, tuple[float, ...]]] = []      # taught poses: held in the world
    if spec.name == "scripted":
        wps = spec.params.get("waypoints", [])
        points += [(f"app.params.waypoints[{i}]", tuple(r[:3])) for i, r in enumerate(wps)]
    if spec.name == "visual_servo":
        from cosim.apps.vs.presets import resolve

        p = resolve(spec.params)
        poses += [(f"app.params.keys[{i}]", tuple(r[:3])) for i, r in enumerate(p["keys"])]
        n_keys = len(p["keys"])
        for name, path in app_inputs(spec, source).items():
            from cosim.apps.vs import visual_path as VP

            try:
                meta = VP.check(path, camera)
            except ValueError as exc:
                raise ScenarioError(name, spec.params["visual_path"], "a taught folder for "
                                    f"the scenario's camera ({exc})") from None
            n_keys = len(meta["_poses"])
            points += [(f"{name} (path.json keys[{i}].pose)", pose[:3])
                       for i, pose in enumerate(meta["_poses"])]
        sigma = p["sigma"]
        if isinstance(sigma, list) and len(sigma) > 1 and len(sigma) != n_keys:
            raise ScenarioError("app.params.sigma", sigma, f"one number, or one per key "
                                f"({n_keys} keys)")
    if arena is not None:
        for name, (n, e, d) in points + poses:
            if not (arena.n_min <= n <= arena.n_max and arena.e_min <= e <= arena.e_max
                    and d <= 0.0):
                raise ScenarioError(name, [n, e, d], f"a point inside the arena (N "
                                    f"{arena.n_min:g} to {arena.n_max:g}, E {arena.e_min:g} to "
                                    f"{arena.e_max:g}) and above the floor (d <= 0)")
    if scene is not None and not scene.empty:
        for name, (n, e, d) in poses:
            _check_pose_clear(name, (n, e, d), scene, body_radius)
        if spec.name == "visual_servo" and p["feedforward"]:
            _check_feedforward_clear(poses or points, scene, body_radius,
                                     float(p["ff_clearance_m"]))


def _check_pose_clear(name: str, ned: tuple[float, ...], scene, radius: float) -> None:
    """A taught pose where the body sphere overlaps the floor, a wall, the ceiling, a box or
    a column is refused, naming what it overlaps and by how much."""
    n, e, d = ned
    if -d < radius:
        raise ScenarioError(name, [n, e, d], f"a pose the vehicle can hold: {-d:.2f} m above "
                            f"the floor is under the body radius {radius:g} m (d <= "
                            f"{-radius:g})")
    gap, what = scene.clearance(n, e, d, radius)
    if gap < 0.0:
        where = "inside" if gap < -radius else "closer than the body radius to"
        raise ScenarioError(name, [n, e, d], f"a pose the vehicle can hold: it is {where} "
                            f"the {what.removeprefix('the ')} (clearance {gap:.2f} m with "
                            f"the body radius {radius:g} m)")


FF_STEP_M = 0.05     # m, spacing of the points checked along a taught path's legs


def _check_feedforward_clear(poses: list[tuple[str, tuple[float, ...]]], scene,
                             radius: float, clearance: float) -> None:
    """Feed-forward (paper 2, Eqs. 31-32) pushes the vehicle along the taught path's legs
    whatever it sees; the paper's Alg. 2 has it without avoidance, its paths having no
    obstacles (reference/paper2-visual-servoing.md, item 13). It is refused (a
    ScenarioError naming `app.params.feedforward`) when the body sphere at a taught pose, or
    anywhere on the straight leg between consecutive poses, comes closer than `clearance`
    (`app.params.ff_clearance_m`) to a wall, the ceiling, a box or a column: the corridor
    avoidance task sees columns only, never a wall or a box."""
    pts = [np.asarray(ned[:3], float) for _, ned in poses]
    worst = (math.inf, "", "")
    for i, a in enumerate(pts):
        b = pts[i + 1] if i + 1 < len(pts) else a
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / FF_STEP_M))
        for s in np.linspace(0.0, 1.0, n + 1):
            q = a + s * (b - a)
            gap, what = scene.clearance(float(q[0]), float(q[1]), float(q[2]), radius)
            if gap < worst[0]:
                where = poses[i][0] if s == 0.0 or b is a else \
                    f"the leg {poses[i][0]} -> {poses[i + 1][0]}"
                worst = (gap, what, where)
    gap, what, where = worst
    if gap < clearance:
        raise ScenarioError("app.params.feedforward", True, f"false on this path, or a "
                            f"taught path clear of the room by app.params.ff_clearance_m = "
                            f"{clearance:g} m: {where} passes {gap:.2f} m from the "
                            f"{what.removeprefix('the ')} (body radius {radius:g} m); "
                            "feed-forward flies the taught legs blind and the avoidance task "
                            "sees columns only")


def _param_value(spec: AppSpec, path: str) -> object:
    key = path.removeprefix("app.params.").split("[")[0]
    return spec.params.get(key, spec.params)
