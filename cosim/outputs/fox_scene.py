"""What a 3D viewer (Foxglove, Lichtblick) draws of a run, as Foxglove messages: the frames,
the world and the vehicle.

Frames (the 3D panel's convention is z up):

- ``map``: z up (x east, y north, z up: ENU), its origin on the floor at the centre of the
  world's arena, so the view opens on the scene whatever the world's coordinates (the seed
  world lies at N 51.5-58, E 91.5-96.5 m);
- ``world``: the simulator's world NED (x north, y east, z down), a static child of ``map``
  (``map_to_world``: a rotation of 180 deg about the (1, 1, 0) axis and the arena centre);
- ``body``: the vehicle's body FRD, a child of ``world`` at the pose of each tick;
- ``body_flu``: the same body with z up (x forward, y left, z up, ROS's base_link), a static
  child of ``body``: the display frame to follow the vehicle with the view right way up;
- ``camera``: the camera's optical frame (x image right, y image down, z along the optical
  axis, the convention of ``foxglove.CameraCalibration``), a child of ``body`` at the camera's
  mount (a stabilized camera turns against the body's roll and pitch, so its transform is
  sent with each frame).

The world (``world_scene``) is drawn in ``world``: the floor (a thin slab under z = 0), the
floor track, end marker, distractors and arena outline of a flat world, and the surfaces the
front camera renders of a 3D world (``cosim/world/surfaces.py``: walls, boxes, columns,
posters and their frames; not the ceiling, which would hide the room from above), each in
the mean colour of its texture, walls see-through. The vehicle (``vehicle_model``) is drawn
in ``body``: two arms, four rotors and a nose arrow, frame-locked so it follows the pose.
"""

from __future__ import annotations

import math

import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

from mav.rotations import quat_from_euler, quat_from_R

MAP, WORLD, BODY, CAMERA = "map", "world", "body", "camera"
FLU = "_flu"                                # + body: the body frame z up (x fwd, y left)
R_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
VEHICLE_RGBA = (1.0, 0.45, 0.0, 1.0)        # orange: the vehicle, easy to find in a view
FLOOR_SLAB_M = 0.02                         # the floor's thickness, under z = 0
WALL_ALPHA = 0.3                            # walls see-through: the room seen from outside
T0 = Timestamp(0, 0)


def ts(t_ns: int) -> Timestamp:
    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


def quaternion(q_wxyz) -> Quaternion:
    w, x, y, z = (float(c) for c in q_wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


def map_origin(world) -> tuple[float, float]:
    """(N, E) m in world NED of the map frame's origin: the arena's centre."""
    a = world.arena
    return 0.5 * (a[0] + a[1]), 0.5 * (a[2] + a[3])


def map_to_world(world) -> FrameTransform:
    """The static transform: the world NED frame's pose in the z-up map frame."""
    cn, ce = map_origin(world)
    return FrameTransform(timestamp=T0, parent_frame_id=MAP, child_frame_id=WORLD,
                          translation=Vector3(x=-ce, y=-cn, z=0.0),
                          rotation=quaternion(quat_from_R(R_ENU_NED)))


def flu_in_body(body: str = BODY) -> FrameTransform:
    """The static transform of the z-up body frame: 180 deg about the body's x axis."""
    return FrameTransform(timestamp=T0, parent_frame_id=body, child_frame_id=body + FLU,
                          translation=Vector3(), rotation=Quaternion(x=1.0, y=0.0, z=0.0,
                                                                     w=0.0))


def body_in_world(t_ns: int, x: float, y: float, z: float, q_wxyz, child: str = BODY
                  ) -> FrameTransform:
    return FrameTransform(timestamp=ts(t_ns), parent_frame_id=WORLD, child_frame_id=child,
                          translation=Vector3(x=x, y=y, z=z), rotation=quaternion(q_wxyz))


def camera_in_body(t_ns: int, mount_B, R_BC: np.ndarray, parent: str = BODY,
                   child: str = CAMERA) -> FrameTransform:
    m = [float(c) for c in mount_B]
    return FrameTransform(timestamp=ts(t_ns), parent_frame_id=parent, child_frame_id=child,
                          translation=Vector3(x=m[0], y=m[1], z=m[2]),
                          rotation=quaternion(quat_from_R(R_BC)))


def _color(rgb, a: float = 1.0) -> Color:
    return Color(r=rgb[0] / 255.0, g=rgb[1] / 255.0, b=rgb[2] / 255.0, a=a)


def _cube(cn: float, ce: float, d: float, size, yaw: float, color: Color) -> CubePrimitive:
    return CubePrimitive(pose=Pose(position=Vector3(x=cn, y=ce, z=d),
                                   orientation=quaternion(quat_from_euler(0.0, 0.0, yaw))),
                         size=Vector3(x=size[0], y=size[1], z=size[2]), color=color)


def _floor(world) -> CubePrimitive:
    a = world.arena
    room = world.scene.room
    rgb = room.floor.rgb if room is not None else world.floor_rgb
    return _cube(0.5 * (a[0] + a[1]), 0.5 * (a[2] + a[3]), 0.5 * FLOOR_SLAB_M,
                 (a[1] - a[0], a[3] - a[2], FLOOR_SLAB_M), 0.0, _color(rgb))


def _flat(world) -> tuple[list[LinePrimitive], list[CylinderPrimitive], list[CubePrimitive]]:
    """The floor drawing of a flat world: track, arena outline, marker, distractors (1 mm
    above the floor)."""
    lift = -0.001
    lines = [LinePrimitive(type=LinePrimitiveLineType.LineStrip, thickness=float(part.width),
                           scale_invariant=False, color=_color(part.rgb),
                           points=[Point3(x=float(p[0]), y=float(p[1]), z=lift) for p in line])
             for part, line in zip(world.track, world.centreline(), strict=True)]
    a = world.arena
    lines.append(LinePrimitive(
        type=LinePrimitiveLineType.LineLoop, thickness=0.02, color=_color((128, 128, 128)),
        points=[Point3(x=a[0], y=a[2], z=lift), Point3(x=a[1], y=a[2], z=lift),
                Point3(x=a[1], y=a[3], z=lift), Point3(x=a[0], y=a[3], z=lift)]))
    discs, squares = [], []
    marker = world.marker
    shapes = [(marker.center, 2.0 * marker.radius, "disc", 0.0, marker.rgb)] if marker else []
    shapes += [(s.center, s.size, s.shape, s.heading, s.rgb) for s in world.distractors]
    for (cn, ce), size, shape, heading, rgb in shapes:
        if shape == "disc":
            discs.append(CylinderPrimitive(
                pose=Pose(position=Vector3(x=cn, y=ce, z=2 * lift),
                          orientation=Quaternion(w=1.0)),
                size=Vector3(x=size, y=size, z=0.002), bottom_scale=1.0, top_scale=1.0,
                color=_color(rgb)))
        else:
            squares.append(_cube(cn, ce, 2 * lift, (size, size, 0.002), heading, _color(rgb)))
    return lines, discs, squares


def _surfaces(world) -> list[TriangleListPrimitive]:
    """The 3D world's surfaces as the front camera sees them, one flat colour each."""
    from cosim.world.surfaces import scene_surfaces

    scene = world.scene
    surfaces = world._cache.get("surfaces") or scene_surfaces(scene)   # the camera's, if built
    out = []
    for s in surfaces:
        if s.name in ("floor", "ceiling"):
            continue
        rgb = s.image.reshape(-1, 3).mean(axis=0)
        wall = s.group == 0
        c = s.corners_W()
        pts = [Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))   # a fan from corner 0
               for k in range(1, len(c) - 1) for p in (c[0], c[k], c[k + 1])]
        out.append(TriangleListPrimitive(pose=Pose(position=Vector3(), orientation=Quaternion(
            w=1.0)), points=pts, color=_color(rgb, WALL_ALPHA if wall else 1.0)))
    return out


def world_scene(world) -> SceneUpdate:
    """The world as one entity in the ``world`` frame (see the module docstring)."""
    lines, discs, cubes = ([], [], []) if world.scene.room is not None else _flat(world)
    tris = _surfaces(world) if not world.scene.empty else []
    return SceneUpdate(entities=[SceneEntity(
        timestamp=T0, frame_id=WORLD, id="world", frame_locked=True, lines=lines,
        cylinders=discs, cubes=[_floor(world), *cubes], triangles=tris)])


def vehicle_model(vehicle, frame: str = BODY) -> SceneUpdate:
    """The vehicle in its body frame (FRD: x forward, z down): X arms, rotors, nose arrow."""
    arm = float(vehicle.arm_length)
    c = Color(r=VEHICLE_RGBA[0], g=VEHICLE_RGBA[1], b=VEHICLE_RGBA[2], a=VEHICLE_RGBA[3])
    w = max(0.15 * arm, 0.01)
    arms = [CubePrimitive(pose=Pose(position=Vector3(), orientation=quaternion(
        quat_from_euler(0.0, 0.0, yaw))), size=Vector3(x=2.0 * arm, y=w, z=w), color=c)
        for yaw in (math.pi / 4, -math.pi / 4)]
    r = 0.6 * arm
    rotors = [CylinderPrimitive(pose=Pose(position=Vector3(
        x=arm * math.cos(a), y=arm * math.sin(a), z=-w), orientation=Quaternion(w=1.0)),
        size=Vector3(x=r, y=r, z=0.2 * w), bottom_scale=1.0, top_scale=1.0, color=c)
        for a in (math.pi / 4, 3 * math.pi / 4, -3 * math.pi / 4, -math.pi / 4)]
    nose = ArrowPrimitive(pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
                          shaft_length=1.2 * arm, shaft_diameter=0.5 * w, head_length=0.4 * arm,
                          head_diameter=1.5 * w, color=c)
    return SceneUpdate(entities=[SceneEntity(timestamp=T0, frame_id=frame, id="vehicle",
                                             frame_locked=True, cubes=arms, cylinders=rotors,
                                             arrows=[nose])])
