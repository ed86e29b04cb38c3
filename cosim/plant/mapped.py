"""A plant FMU of any make behind the master's plant interface, through fmpy's own API.

`MappedPlant` loads an FMI 2.0 or 3.0 Co-Simulation FMU with fmpy (`FMU2Slave` /
`FMU3Slave`), sets its parameters and start pose, and on every tick converts between the
master's conventions (NED world, FRD body, quaternion body -> world, specific force in body
axes, SI, motor commands u1..u4 in PX4 quad-X order) and the FMU's, as the scenario's map says
(`cosim/plant/mapping.py`). Its `y` has the layout of `cosim.plant.fmu.OUTPUT_NAMES`, so the
loop, the sensors, the exits and the recorder do not know which plant they fly.

The default plant (the project's FMI 2.0 FMU, `cosim.plant.fmu.Plant`) never comes here: this
path costs a few fmpy calls and some Python arithmetic per tick, and only scenarios that name
`[vehicle] fmu` or `fmi = 3` pay it.

Example::

    from cosim.plant.mapped import MappedPlant
    from cosim.plant.mapping import PlantSpec
    from cosim.scenario.vehicles import MAMBO
    with MappedPlant(MAMBO, PlantSpec(fmu=None, fmi=3, map=None)) as plant:   # own FMI 3.0
        y = plant.step(*(4 * [MAMBO.u_hover]), 0.0, 0.0, 0.0)
"""

from __future__ import annotations

import collections
import math
import shutil

from cosim.errors import ComponentError
from cosim.plant import fmufile
from cosim.plant.fmu import OUTPUT_NAMES, Y_ON_GROUND, FmuPlant
from cosim.plant.mapping import RATE, PlantMap, PlantSpec, own_map, read_description
from mav.rotations import quat_from_euler, quat_mul, rotate_world_to_body

GROUND_EPS_M = 0.01      # m: without an on_ground output, "on the ground" is z_NED > -this
_S = math.sqrt(0.5)
_Q_ENU_TO_NED = (0.0, _S, _S, 0.0)   # rotation taking ENU coordinates to NED ones
_Q_FRD_TO_FLU = (0.0, 1.0, 0.0, 0.0)  # pi about x: FRD <-> FLU


# ------------------------------------------------------------------ frames (plain functions)
def world_swap(v, world: str) -> tuple[float, float, float]:
    """A world vector between ENU and NED coordinates (the map is its own inverse)."""
    return (v[0], v[1], v[2]) if world == "NED" else (v[1], v[0], -v[2])


def body_swap(v, body: str) -> tuple[float, float, float]:
    """A body vector between FLU and FRD axes (its own inverse)."""
    return (v[0], v[1], v[2]) if body == "FRD" else (v[0], -v[1], -v[2])


def attitude_to_ned_frd(q, world: str, body: str) -> tuple[float, float, float, float]:
    """The attitude of a body -> world quaternion given in (world, body) frames, in NED/FRD."""
    if world == "ENU":
        q = quat_mul(_Q_ENU_TO_NED, q)
    if body == "FLU":
        q = quat_mul(q, _Q_FRD_TO_FLU)
    return q


# ------------------------------------------------------------------ the plant
class MappedPlant(FmuPlant):
    """An FMU plant with the interface of `cosim.plant.fmu.Plant` (`y`, `step`, `k`, `t`,
    `reset`, `close`), converted by its map. `x0, y0, yaw0`: the start on the floor (NED m,
    rad); with a `start` map they are the FMU's parameters, without one the master places
    the FMU's origin there, its x axis (the heading it starts with) turned to yaw0.
    `unzipdir`: extract the FMU into this folder, which the caller owns and removes (default:
    a temporary one, removed by `close`)."""

    def __init__(self, vehicle, spec: PlantSpec, *, step_size: float = 0.005,
                 x0: float = 0.0, y0: float = 0.0, yaw0: float = 0.0,
                 unzipdir: str | None = None) -> None:
        self.vehicle = vehicle
        self.step_size = float(step_size)
        self.k = 0
        self._fmu = None
        self._unzipdir = None
        self._own_dir = unzipdir is None     # else the caller's folder: the caller removes it
        self._messages: collections.deque[str] = collections.deque(maxlen=32)
        if spec.fmu is None:
            from fmus.build import fmu_path

            self.fmu_path = fmu_path(fmi=spec.fmi)
        else:
            self.fmu_path = spec.fmu
        self._md = md = read_description(self.fmu_path, "vehicle.fmu", str(self.fmu_path))
        m: PlantMap = spec.map if spec.map is not None else own_map(md, vehicle)
        self.map = m
        self._fmi3 = md.fmiVersion.startswith("3")
        self._start = (x0, y0, yaw0)
        # the master places the FMU's origin unless the FMU takes the start as parameters: its
        # frame turned by psi about the vertical, so that its x axis (the heading it starts
        # with) points to yaw0 (ENU's x axis is east: 90 degrees in NED)
        psi = yaw0 - (0.0 if m.world == "NED" else math.pi / 2)
        self._offset = not m.start and (x0, y0, psi) != (0.0, 0.0, 0.0)
        self._q_yaw = (math.cos(0.5 * psi), 0.0, 0.0, math.sin(0.5 * psi))
        self._cy, self._sy = math.cos(psi), math.sin(psi)
        self._in_cmd = [m.inputs[k] for k in (("u1", "u2", "u3", "u4") if m.command == "rotors"
                                              else ("thrust", "tau_x", "tau_y", "tau_z"))]
        self._in_wind = [m.inputs[k] for k in ("wind_x", "wind_y", "wind_z") if k in m.inputs]
        self._in_vrs = [v.vr for v in self._in_cmd + self._in_wind]
        if m.command == "wrench":
            from mav.mixer import mixer_matrix

            self._mix = mixer_matrix(vehicle)
        att = ("qw", "qx", "qy", "qz") if m.attitude == "quaternion" else ("roll", "pitch", "yaw")
        self._out_keys = [k for k in ("x", "y", "z", "vx", "vy", "vz", *att, "p", "q", "r",
                                      "ax", "ay", "az", "omega1", "omega2", "omega3", "omega4")
                          if k in m.outputs]
        self._out = [m.outputs[k] for k in self._out_keys]
        self._out_vrs = [v.vr for v in self._out]
        self._og = m.outputs.get("on_ground")
        # unit conversions, only where a unit is not SI: (index, factor, offset)
        self._in_scaled = [(i, v.factor, v.offset)
                           for i, v in enumerate(self._in_cmd + self._in_wind) if not v.identity]
        self._out_scaled = [(i, v.factor, v.offset)
                            for i, v in enumerate(self._out) if not v.identity]
        # our own conventions, every output there: y is the FMU's outputs as they are
        self._identity = (m.world == "NED" and m.body == "FRD" and m.attitude == "quaternion"
                          and m.acceleration == "body" and not self._offset
                          and not self._out_scaled
                          and self._out_keys == list(OUTPUT_NAMES[:Y_ON_GROUND]))
        #: latest outputs in OUTPUT_NAMES order (updated in place by step())
        self.y: list[float] = [math.nan] * len(OUTPUT_NAMES)
        self._unzipdir = fmufile.extract(self.fmu_path, int(md.fmiVersion[0]),
                                         md.coSimulation.modelIdentifier, unzipdir)
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    # ---- life cycle ------------------------------------------------------------------------
    def _open(self) -> None:
        """Instantiate, set the parameters and the start, initialise, read y(0)."""
        from fmpy.fmi2 import FMU2Slave
        from fmpy.fmi3 import FMU3Slave

        md, m, v = self._md, self.map, self.vehicle
        kw = dict(guid=md.guid, unzipDirectory=self._unzipdir,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
        if self._fmi3:
            fmu = FMU3Slave(**kw)
            self._call("instantiate", lambda: fmu.instantiate(logMessage=self._log3))
            self._set_real, self._get_real = fmu.setFloat64, fmu.getFloat64
        else:
            fmu = FMU2Slave(**kw)
            self._call("instantiate", lambda: fmu.instantiate(callbacks=self._callbacks2()))
            self._set_real, self._get_real = fmu.setReal, fmu.getReal
        self._fmu = fmu
        self._get_bool, self._do_step = fmu.getBoolean, fmu.doStep
        types = {mv.name: mv.type for mv in md.modelVariables}
        by_type: dict[str, list] = {}          # "Real", "Boolean", "Int32", ... -> (vr, value)
        for name, vr, val in m.parameters:
            val = getattr(v, val) if isinstance(val, str) else val
            by_type.setdefault(types[name], []).append((vr, val))
        reals = by_type.pop("Float64" if self._fmi3 else "Real", [])
        if m.start:
            n, e, yaw = self._start
            x, y = (n, e) if m.world == "NED" else (e, n)
            yaw = yaw if m.world == "NED" else math.pi / 2 - yaw
            for key, val in (("x", x), ("y", y), ("yaw", yaw)):
                s = m.start[key]
                reals.append((s.vr, (val - s.offset) / s.factor))
        if reals:
            self._call("set parameters", lambda: self._set_real(*zip(*reals, strict=True)))
        for t, pairs in by_type.items():   # fmpy's setBoolean, setInteger, setInt32, ...
            if t == "Enumeration":
                t = "Int64" if self._fmi3 else "Integer"
            setter = getattr(fmu, f"set{t}")
            self._call("set parameters", lambda s=setter, p=pairs: s(*zip(*p, strict=True)))
        if self._fmi3:
            self._call("fmi3EnterInitializationMode", lambda: fmu.enterInitializationMode(
                startTime=0.0))
        else:
            self._call("fmi2SetupExperiment", lambda: fmu.setupExperiment(startTime=0.0))
            self._call("fmi2EnterInitializationMode", fmu.enterInitializationMode)
        self._call("ExitInitializationMode", fmu.exitInitializationMode)
        self._read()

    def reset(self) -> None:
        """Back to t = 0: a fresh instance of the FMU (any FMU can do that)."""
        self._free()
        self.k = 0
        self._open()

    def _free(self) -> None:
        fmu, self._fmu = self._fmu, None
        if fmu is not None:
            try:
                fmu.terminate()
            except Exception:
                pass
            fmu.freeInstance()

    def close(self) -> None:
        """Free the instance and the extracted files (idempotent)."""
        try:
            self._free()
        finally:
            if self._unzipdir is not None and self._own_dir:
                shutil.rmtree(self._unzipdir, ignore_errors=True)
            self._unzipdir = None

    # ---- the tick --------------------------------------------------------------------------
    def step(self, u1: float, u2: float, u3: float, u4: float, wind_n: float = 0.0,
             wind_e: float = 0.0, wind_d: float = 0.0) -> list[float]:
        """Hold the inputs over one tick, advance t_k -> t_k+1; returns :attr:`y`."""
        if self._fmu is None:     # closed: fmpy would call into a freed instance
            self._used_closed()
        m, v = self.map, self.vehicle
        if m.command == "rotors":
            si = [u1, u2, u3, u4]
            if self._in_cmd[0].dim == RATE:
                si = [u * v.omega_max for u in si]
        else:                     # the master's rotors: static thrust k w^2, PX4 quad-X
            kt, wm = v.k_thrust, v.omega_max
            t = [kt * (min(max(u, 0.0), 1.0) * wm) ** 2 for u in (u1, u2, u3, u4)]
            thrust, yaw, pitch, roll = (sum(a * b for a, b in zip(row, t, strict=True))
                                        for row in self._mix)
            si = [thrust, *body_swap((roll, pitch, yaw), m.body)]
        if self._in_wind:
            wn, we = wind_n, wind_e
            if self._offset:          # into the FMU's (unrotated) frame
                wn, we = self._cy * wind_n + self._sy * wind_e, -self._sy * wind_n + \
                    self._cy * wind_e
            si += world_swap((wn, we, wind_d), m.world)
        for i, factor, offset in self._in_scaled:
            si[i] = (si[i] - offset) / factor
        t = self.k * self.step_size
        self._call("set inputs", lambda: self._set_real(self._in_vrs, si))
        res = self._call("DoStep", lambda: self._do_step(t, self.step_size))
        if self._fmi3 and res[1]:
            raise ComponentError("plant", f"the FMU asked to terminate at t = "
                                          f"{t + self.step_size:.6g} s: {self._drain()}")
        self.k += 1
        return self._read()

    def _read(self) -> list[float]:
        raw = self._call("get outputs", lambda: self._get_real(self._out_vrs))
        for i, factor, offset in self._out_scaled:
            raw[i] = factor * raw[i] + offset
        y = self.y
        if self._identity:
            y[:Y_ON_GROUND] = raw
        else:
            self._convert(dict(zip(self._out_keys, raw, strict=True)), y, self.map)
        if self._og is not None:
            og = self._call("get on_ground", lambda: self._get_bool([self._og.vr]))[0]
            y[Y_ON_GROUND] = 1.0 if og else 0.0
        else:
            y[Y_ON_GROUND] = 1.0 if y[2] > -GROUND_EPS_M else 0.0
        return y

    def _convert(self, o: dict, y: list[float], m: PlantMap) -> None:
        """Outputs in the FMU's frames (SI) -> y in the master's."""
        p = world_swap((o["x"], o["y"], o["z"]), m.world)
        vel = world_swap((o["vx"], o["vy"], o["vz"]), m.world)
        if m.attitude == "quaternion":
            q = (o["qw"], o["qx"], o["qy"], o["qz"])
        else:
            q = quat_from_euler(o["roll"], o["pitch"], o["yaw"])
        q = attitude_to_ned_frd(q, m.world, m.body)
        rates = body_swap((o["p"], o["q"], o["r"]), m.body)
        if m.acceleration == "body":
            acc = body_swap((o["ax"], o["ay"], o["az"]), m.body)
        else:                 # kinematic, world -> specific force in body axes
            a = world_swap((o["ax"], o["ay"], o["az"]), m.world)
            acc = rotate_world_to_body(q, (a[0], a[1], a[2] - self.vehicle.g))
        if self._offset:      # the FMU's origin -> the start pose
            c, s = self._cy, self._sy
            n0, e0, _ = self._start
            p = (n0 + c * p[0] - s * p[1], e0 + s * p[0] + c * p[1], p[2])
            vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
            q = quat_mul(self._q_yaw, q)
        # q and -q are one attitude: keep the sign continuous (Euler angles wrapping at 180
        # degrees, the frame products), starting with qw >= 0, as the FMU integrates it
        qp = y[6:10]
        dot = q[0] * qp[0] + q[1] * qp[1] + q[2] * qp[2] + q[3] * qp[3]
        if dot < 0.0 or (dot != dot and q[0] < 0.0):
            q = (-q[0], -q[1], -q[2], -q[3])
        y[0:3] = p
        y[3:6] = vel
        y[6:10] = q
        y[10:13] = rates
        y[13:16] = acc
        for i in range(4):
            y[16 + i] = o.get(f"omega{i + 1}", math.nan)

    # ---- errors and logging ----------------------------------------------------------------
    def _call(self, what: str, f):
        try:
            return f()
        except ComponentError:
            raise
        except Exception as exc:
            raise ComponentError("plant", f"{what} failed at t = {self.t:.6g} s "
                                          f"({type(exc).__name__}: {exc}): {self._drain()}") \
                from exc

    def _callbacks2(self):
        from ctypes import byref

        from fmpy import calloc, free
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )
        from fmpy.logging import addLoggerProxy

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(self._log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        addLoggerProxy(byref(cb))
        self._cb = cb            # kept alive as long as the instance
        return cb

    def _log3(self, env, status, category, message) -> None:
        self._log(env, None, status, category, message)
