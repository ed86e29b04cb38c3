"""The cascade both onboard low-level controllers share (mav/control.py builds them).

Contract (used by the onboard MAVLink vehicle; see mav/README.md, "Controllers"):

    ctrl = make_controller(vehicle, dt=0.005)      # MamboController or Bebop2Controller
    ctrl.update(state, setpoint, out)              # 200 Hz; writes u1..u4 in [0, 1] to out[0:4]

Motor order and spin (PX4 quad-X, viewed from above): 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW. Body FRD, world NED. Rotor i sits at (+-a, +-a) with
a = arm_length*sqrt(2)/2 and pushes k_thrust*w^2 along -z_body; a CCW rotor's reaction torque
is +yaw (about +z down). So roll right (+L) = more thrust on 2, 3; pitch up (+M) = more thrust
on 1, 3; yaw right (+N) = faster 1, 2. Motor command u = w_cmd/omega_max.

Both controllers share one hot path (`QuadCascade.update`), a cascade that is, in its
linear range, identical to the template's PID structure:

- horizontal: v_cmd = K_xy*e_pos (error in the body-yaw frame, each axis saturated) + v_ff,
  limited to a horizontal speed; tilt = K_vxy*(v_cmd - v) + C_drag*v_ff, limited to a tilt.
  With K_xy = P/D and K_vxy = D this is the template's pitch_ref = -P*e_x + D*vx exactly.
- vertical: vz_cmd = K_z*e_z + vz_ff, limited to a climb rate; thrust = m*g + K_vz*(vz - vz_cmd)
  - integrator, divided by the tilt cosine, saturated. With K_z = P/D and
  K_vz = D this is the template's P/I/D altitude law exactly.
- attitude: torque = K_p*(angle_ref - angle) + integrator - K_d*rate (the template's PID
  with D on the measured body rate).
- yaw: r_cmd = K_psi*wrap(yaw_ref - yaw) + r_ff, limited; torque = K_r*(r_cmd - r)
  (= template P*e - D*r with K_psi = P/D, K_r = D).
- mixer: the inverse of [T; N; M; L] = A [T1..T4], thrusts clipped to [0, T_max], yaw given
  only the headroom the other axes leave, then u = sqrt(T/k_thrust)/omega_max.

The hot path is plain-float Python: gains live in one record (`Gains`) rebuilt by `set_param`,
so a tick does no dict look-ups and allocates nothing but floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import cython
from cython.cimports.libc.math import cos as _cos
from cython.cimports.libc.math import sin as _sin
from cython.cimports.libc.math import sqrt as _sqrt

from mav.airframe import Airframe
from mav.mixer import inverse4, mixer_matrix
from mav.rotations import euler_from_quat, tilt_cos
from mav.types import Setpoint, VehicleState

# (compiled: C doubles and C's libm, the functions Python's math module calls; the types of
# the class's fields and of the records it reads are in cascade.pxd and types.pxd)
f64 = cython.typedef(cython.double)       # the controller's arithmetic: C doubles
_PI = cython.declare(cython.double, math.pi)
_TWO_PI = cython.declare(cython.double, 2.0 * math.pi)

@dataclass(frozen=True)
class ParamSpec:
    """One parameter, MAVLink style (PARAM_VALUE carries it as a float): the controllers' gains
    (mav/control.py) and the onboard stack's own (mav/params.py ONBOARD_PARAMS) alike."""

    name: str       # <= 16 characters, MAVLink param id style ("MPC_XY_P")
    default: float  # in `unit`
    min: float      # in `unit`, inclusive
    max: float      # in `unit`, inclusive
    unit: str       # e.g. "rad/m", "deg", "m/s"
    doc: str        # one line
    # a flight gain: while armed it stays within a factor of its default (mav/params.py
    # flight_envelope), so a vehicle in the air is never handed a gain that cannot fly
    flight_gain: bool = False
    # MAVLink param_type of PARAM_VALUE: "REAL32", or "INT32" where PX4's metadata types the
    # parameter int32 (sent byte-wise, PX4's encoding; mav/onboard/parameters.py)
    ptype: str = "REAL32"
    # a PX4-named parameter whose default is not PX4's: why (the airframe's or the room's own
    # value, as PX4's airframe files set theirs); "" = PX4's default (tests/test_px4_params.py)
    own_default: str = ""


class Controller(Protocol):
    dt: float  # s, control period

    def param_table(self) -> list[ParamSpec]: ...

    def get_param(self, name: str) -> float: ...

    def set_param(self, name: str, value: float) -> None: ...

    def reset(self) -> None: ...

    def update(self, s: VehicleState, sp: Setpoint, out: list[float]) -> None: ...


class Gains:
    """The hot path's gains and constants, absolute units, each by its name: built from
    keywords (a missing or unknown name raises), read by `update` as `g.<name>` (compiled:
    C fields, cascade.pxd). Rebuilt by `set_param`."""

    __slots__ = (
        "pitch_kp",            # N m/rad
        "pitch_ki",            # N m/(rad s)
        "pitch_kd",            # N m s/rad
        "roll_kp",             # N m/rad
        "roll_ki",             # N m/(rad s)
        "roll_kd",             # N m s/rad
        "att_i_lim",           # N m, roll/pitch integrator limit
        "att_kb",              # 1, back-calculation gain per tick
        "k_psi",               # 1/s, heading -> yaw rate
        "k_r",                 # N m s/rad, yaw rate -> torque
        "yawrate_max",         # rad/s
        "k_z",                 # 1/s, altitude -> climb rate
        "k_vz",                # N s/m, climb rate -> thrust
        "ki_z_pos",            # N/(m s), altitude-error integral (position mode)
        "ki_z_vpos",           # N/m, velocity-error integral (position mode)
        "ki_z_vel",            # N/m, velocity-error integral (velocity mode)
        "z_i_lim",             # N, altitude integrator limit
        "vz_max",              # m/s, climb/descent rate limit
        "thrust_max_total",    # N
        "k_xy",                # 1/s, position -> horizontal velocity
        "k_vxy",               # rad s/m, velocity error -> tilt
        "c_drag",              # rad s/m, drag feed-forward tilt per m/s
        "ki_vxy",              # rad/m, horizontal velocity-error integral -> tilt (wind; as PX4's
                               # MPC_XY_VEL_I_ACC), integrated in the world frame
        "xy_i_lim",            # rad, tilt the horizontal integrator may hold
        "xy_err_max",          # m, per-axis position error saturation
        "vxy_max",             # m/s, horizontal speed limit
        "tilt_max",            # rad
        "weight",              # N
        "inv_g",               # s^2/m, 1 / g (acceleration feed-forward -> tilt)
        "m0t",                 # inverse mixer A^-1: rotor 1 from thrust, pitch, roll (1/m)
        "m0m",
        "m0l",
        "m1t",                 # rotor 2
        "m1m",
        "m1l",
        "m2t",                 # rotor 3
        "m2m",
        "m2l",
        "m3t",                 # rotor 4
        "m3m",
        "m3l",
        "my",                  # rotor 1 from yaw torque, 1/m (rotors 1, 2: +; 3, 4: -)
        "t_max",               # N, one rotor at omega_max
        "c_u",                 # 1/N, u^2 per newton: 1/(k_thrust omega_max^2)
        "arm_a",               # m, rotor offset along x and y (pitch/roll torque per N)
        "dt",                  # s, control period
        "integ",               # a yaw-rate setpoint integrates a heading reference
    )

    def __init__(self, **values) -> None:
        names = Gains.__slots__
        missing = [n for n in names if n not in values]
        unknown = [n for n in values if n not in names]
        if missing or unknown:
            raise TypeError(f"Gains: missing {missing}, unknown {unknown}")
        for n in names:
            setattr(self, n, values[n])


class QuadCascade:
    """Shared cascade and mixer. Subclasses supply the parameter table and `_gains()`."""

    PARAMS = ()         # tuple[ParamSpec, ...]: every parameter (a class attribute, not typed:
    PRESETS = {}        # dict[str, dict[str, float]]  Cython keeps no annotation on one)
    # True: a yaw-rate setpoint integrates a heading reference (no drift, PX4 style);
    # False: yaw-rate setpoints close a pure rate loop (Parrot PCMD style).
    YAW_RATE_INTEGRATES = True

    def __init__(self, vehicle: Airframe, dt: float = 0.005, preset: str = "default"):
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
        self.vehicle = vehicle
        self.dt = float(dt)
        self._specs = {p.name: p for p in self.PARAMS}
        self._p: dict[str, float] = {p.name: float(p.default) for p in self.PARAMS}
        A = mixer_matrix(vehicle)
        Ai = inverse4(A)
        self._A = A
        self._Ainv = Ai
        # The yaw column of the inverse must be (+y, +y, -y, -y): the mixer's yaw headroom
        # logic relies on it (true for any quad-X with the contract's motor order).
        y = Ai[0][1]
        if not (y > 0 and all(abs(Ai[i][1] - s * y) < 1e-9 * y
                              for i, s in enumerate((1, 1, -1, -1)))):
            raise ValueError("unexpected mixer structure (motor order must be PX4 quad-X)")
        self._i_p = 0.0   # pitch integrator, N m
        self._i_r = 0.0   # roll integrator, N m
        self._i_z = 0.0   # altitude integrator, N of upward thrust
        self._i_n = self._i_e = 0.0   # horizontal integrator, rad of tilt towards N / E
        self._yaw_ref = 0.0  # rad, heading reference
        self._n = 0       # armed ticks since arming (0: take the heading as reference)
        self._g: Gains | None = None
        if preset != "default":
            self.apply_preset(preset)
        self._refresh()

    # ---------------------------------------------------------------- parameters
    def param_table(self) -> list[ParamSpec]:
        """Every parameter with its default, range, unit and meaning."""
        return list(self.PARAMS)

    def get_param(self, name: str) -> float:
        try:
            return self._p[name]
        except KeyError:
            raise ValueError(f"unknown parameter {name!r} for {type(self).__name__}") from None

    def set_param(self, name: str, value: object) -> None:
        """Set one parameter; it takes effect on the next update. ValueError if the name is
        unknown, the value not a number, non-finite or outside [min, max] (`value` is an
        object, not float: compiled, a float annotation would raise TypeError first)."""
        spec = self._specs.get(name)
        if spec is None:
            raise ValueError(f"unknown parameter {name!r} for {type(self).__name__}")
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number, got {value!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite, got {v!r}")
        if not (spec.min <= v <= spec.max):
            raise ValueError(
                f"{name} = {f'{v:g} {spec.unit}'.rstrip()} is outside "
                f"[{spec.min:g}, {spec.max:g}]")
        self._p[name] = v
        self._refresh()

    def apply_preset(self, name: str) -> None:
        """Load a named gain set ('default' = the parameter defaults, or one of PRESETS)."""
        if name == "default":
            values = {p.name: p.default for p in self.PARAMS}
        elif name in self.PRESETS:
            values = self.PRESETS[name]
        else:
            choices = ", ".join(["default", *sorted(self.PRESETS)])
            raise ValueError(f"unknown preset {name!r}; choose one of {choices}")
        for k, v in values.items():
            self.set_param(k, v)

    def linear_gains(self) -> dict[str, float]:
        """The effective gains the hot path uses, in absolute units (for mav.tune).

        Keys: pitch/roll kp [N m/rad], ki [N m/(rad s)], kd [N m s/rad]; yaw k_psi [1/s],
        k_r [N m s/rad]; k_z [1/s], k_vz [N s/m], ki_z_pos [N/(m s)] (position-mode
        integrator on the altitude error), ki_z_vpos / ki_z_vel [N/m] (integrator gain on the
        vertical velocity error in position / velocity mode); k_xy [1/s], k_vxy [rad s/m],
        c_drag [rad s/m]; yaw_rate_integrates (1.0 or 0.0)."""
        g = self._gains()
        g["yaw_rate_integrates"] = 1.0 if self.YAW_RATE_INTEGRATES else 0.0
        return g

    def _gains(self) -> dict[str, float]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _refresh(self) -> None:
        """Rebuild the hot path's gains from the parameters (called by set_param)."""
        g = self._gains()
        v = self.vehicle
        t_max = v.thrust_max
        Ai = self._Ainv
        self._g = Gains(
            **g, weight=v.weight, inv_g=1.0 / v.g,
            m0t=Ai[0][0], m0m=Ai[0][2], m0l=Ai[0][3], m1t=Ai[1][0], m1m=Ai[1][2], m1l=Ai[1][3],
            m2t=Ai[2][0], m2m=Ai[2][2], m2l=Ai[2][3], m3t=Ai[3][0], m3m=Ai[3][2], m3l=Ai[3][3],
            my=Ai[0][1], t_max=t_max, c_u=1.0 / (v.k_thrust * v.omega_max * v.omega_max),
            arm_a=self._A[2][0], dt=self.dt, integ=self.YAW_RATE_INTEGRATES,
        )

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        """Clear the integrators and the heading reference."""
        self._i_p = self._i_r = self._i_z = 0.0
        self._i_n = self._i_e = 0.0
        self._yaw_ref = 0.0
        self._n = 0

    # ---------------------------------------------------------------- hot path
    @cython.locals(s=VehicleState, sp=Setpoint, out=list, g=Gains, qw=f64, qx=f64, qy=f64, qz=f64,
                   r33=f64, roll=f64, pitch=f64, yaw=f64, cy=f64, sy=f64, vx=f64, vy=f64, vxb=f64,
                   vyb=f64, fx=f64, fy=f64, fxb=f64, fyb=f64, v2=f64, f=f64, px=f64, py=f64,
                   ex=f64, ey=f64, exb=f64, eyb=f64, vcx=f64, vcy=f64, i_n=f64, i_e=f64, ixb=f64,
                   iyb=f64, pitch_ref=f64, roll_ref=f64, ax=f64, ay=f64, t2=f64, evx=f64, evy=f64,
                   i2=f64, vz=f64, fz=f64, zr=f64, ez=f64, vzc=f64, i_z=f64, thrust=f64, e_p=f64,
                   e_r=f64, i_p=f64, i_r=f64, tq_m=f64, tq_l=f64, yr=f64, rr=f64, yref=f64,
                   r_ff=f64, e_psi=f64, rc=f64, tq_n=f64, b1=f64, b2=f64, b3=f64, b4=f64, d=f64,
                   h=f64, di=f64, r_max=f64, i_lim=f64, tilt_sat=cython.bint,
                   pos_mode=cython.bint, limited=cython.bint, t_sat=cython.int, n=cython.long)
    def update(self, s: VehicleState, sp: Setpoint, out: list[float]) -> None:
        """One control tick: state estimate + setpoint -> motor commands u1..u4 in out[0:4].

        The state must be finite (the estimator's job); a NaN still never reaches the motors
        (the commands are clipped NaN-safe into [0, 1])."""
        if not sp.armed:
            out[0] = out[1] = out[2] = out[3] = 0.0
            if self._n:
                self.reset()
            return
        g = self._g

        # attitude (ZYX Euler) from the quaternion
        qw, qx, qy, qz = s.qw, s.qx, s.qy, s.qz
        roll, pitch, yaw = euler_from_quat(qw, qx, qy, qz)
        r33 = tilt_cos(qw, qx, qy, qz)
        cy = _cos(yaw)
        sy = _sin(yaw)

        n = self._n
        if n == 0:
            self._yaw_ref = yaw

        # ---- horizontal: position -> velocity -> tilt, in the body-yaw frame (F, R)
        vx, vy = s.vx, s.vy
        vxb = cy * vx + sy * vy
        vyb = cy * vy - sy * vx
        fx, fy = sp.vx, sp.vy
        if fx != fx:
            fx = 0.0
        if fy != fy:
            fy = 0.0
        fxb = cy * fx + sy * fy
        fyb = cy * fy - sy * fx
        v2 = fxb * fxb + fyb * fyb
        if v2 > g.vxy_max * g.vxy_max:  # the feed-forward alone may not exceed the speed limit
            f = g.vxy_max / _sqrt(v2)
            fxb *= f
            fyb *= f
        px, py = sp.x, sp.y
        if px == px and py == py:
            ex = px - s.x
            ey = py - s.y
            exb = cy * ex + sy * ey
            eyb = cy * ey - sy * ex
            if exb > g.xy_err_max:
                exb = g.xy_err_max
            elif exb < -g.xy_err_max:
                exb = -g.xy_err_max
            if eyb > g.xy_err_max:
                eyb = g.xy_err_max
            elif eyb < -g.xy_err_max:
                eyb = -g.xy_err_max
            vcx = g.k_xy * exb + fxb
            vcy = g.k_xy * eyb + fyb
        else:
            vcx = fxb
            vcy = fyb
        v2 = vcx * vcx + vcy * vcy
        if v2 > g.vxy_max * g.vxy_max:
            f = g.vxy_max / _sqrt(v2)
            vcx *= f
            vcy *= f
        # forward acceleration needs nose down (negative pitch); rightward needs roll right.
        # The integrator (world N/E, so a turn does not carry it off the wind) in body axes:
        i_n, i_e = self._i_n, self._i_e
        ixb = cy * i_n + sy * i_e
        iyb = cy * i_e - sy * i_n
        pitch_ref = -(g.k_vxy * (vcx - vxb) + g.c_drag * fxb + ixb)
        roll_ref = g.k_vxy * (vcy - vyb) + g.c_drag * fyb + iyb
        ax = sp.ax
        if ax == ax:            # acceleration feed-forward: the tilt it takes, a / g
            ay = sp.ay
            pitch_ref -= (cy * ax + sy * ay) * g.inv_g
            roll_ref += (cy * ay - sy * ax) * g.inv_g
        t2 = pitch_ref * pitch_ref + roll_ref * roll_ref
        tilt_sat = t2 > g.tilt_max * g.tilt_max
        if tilt_sat:
            f = g.tilt_max / _sqrt(t2)
            pitch_ref *= f
            roll_ref *= f
        if g.ki_vxy > 0.0 and not tilt_sat:   # anti-windup: frozen while the tilt saturates
            evx, evy = vcx - vxb, vcy - vyb
            i_n += g.ki_vxy * g.dt * (cy * evx - sy * evy)
            i_e += g.ki_vxy * g.dt * (sy * evx + cy * evy)
            i2 = i_n * i_n + i_e * i_e
            if i2 > g.xy_i_lim * g.xy_i_lim:
                f = g.xy_i_lim / _sqrt(i2)
                i_n *= f
                i_e *= f
            self._i_n, self._i_e = i_n, i_e

        # ---- vertical: altitude -> climb rate -> thrust (NED: up is -z)
        vz = s.vz
        fz = sp.vz
        if fz != fz:
            fz = 0.0
        zr = sp.z
        pos_mode = zr == zr
        if pos_mode:
            ez = zr - s.z
            vzc = g.k_z * ez + fz
        else:
            ez = 0.0
            vzc = fz
        limited = False
        if vzc > g.vz_max:
            vzc = g.vz_max
            limited = True
        elif vzc < -g.vz_max:
            vzc = -g.vz_max
            limited = True
        i_z = self._i_z
        thrust = g.weight + g.k_vz * (vz - vzc) + i_z
        if r33 > 0.5:  # tilt compensation (the template has none), capped at 60 deg
            thrust /= r33
        else:
            thrust *= 2.0
        t_sat = 0
        if thrust > g.thrust_max_total:
            thrust = g.thrust_max_total
            t_sat = 1
        elif thrust < 0.0:
            thrust = 0.0
            t_sat = -1

        # ---- attitude PID (D on body rates) -> pitch / roll torques
        e_p = pitch_ref - pitch
        e_r = roll_ref - roll
        i_p = self._i_p
        i_r = self._i_r
        tq_m = g.pitch_kp * e_p + i_p - g.pitch_kd * s.q
        tq_l = g.roll_kp * e_r + i_r - g.roll_kd * s.p

        # ---- heading
        yr = sp.yaw
        rr = sp.yaw_rate
        if yr == yr:
            yref = yr
            r_ff = 0.0
        elif rr == rr:
            # limited first, so the integrated heading reference cannot run away
            r_max = g.yawrate_max
            r_ff = r_max if rr > r_max else (-r_max if rr < -r_max else rr)
            if g.integ:
                yref = self._yaw_ref + r_ff * g.dt
                if yref > _PI or yref < -_PI:
                    yref = (yref + _PI) % _TWO_PI - _PI
            else:
                yref = yaw
        else:
            yref = self._yaw_ref
            r_ff = 0.0
        self._yaw_ref = yref
        e_psi = yref - yaw
        if e_psi > _PI or e_psi < -_PI:
            e_psi = (e_psi + _PI) % _TWO_PI - _PI
        rc = g.k_psi * e_psi + r_ff
        if rc > g.yawrate_max:
            rc = g.yawrate_max
        elif rc < -g.yawrate_max:
            rc = -g.yawrate_max
        tq_n = g.k_r * (rc - s.r)

        # ---- mixer: thrust, pitch, roll first; yaw gets the remaining headroom
        b1 = g.m0t * thrust + g.m0m * tq_m + g.m0l * tq_l
        b2 = g.m1t * thrust + g.m1m * tq_m + g.m1l * tq_l
        b3 = g.m2t * thrust + g.m2m * tq_m + g.m2l * tq_l
        b4 = g.m3t * thrust + g.m3m * tq_m + g.m3l * tq_l
        b1 = g.t_max if b1 > g.t_max else (b1 if b1 > 0.0 else 0.0)  # NaN -> 0
        b2 = g.t_max if b2 > g.t_max else (b2 if b2 > 0.0 else 0.0)  # NaN -> 0
        b3 = g.t_max if b3 > g.t_max else (b3 if b3 > 0.0 else 0.0)  # NaN -> 0
        b4 = g.t_max if b4 > g.t_max else (b4 if b4 > 0.0 else 0.0)  # NaN -> 0
        d = g.my * tq_n  # rotors 1, 2 get +d, rotors 3, 4 get -d
        if d > 0.0:
            h = min(g.t_max - b1, g.t_max - b2, b3, b4)
            if d > h:
                d = h
        elif d < 0.0:
            h = min(b1, b2, g.t_max - b3, g.t_max - b4)
            if -d > h:
                d = -h
        else:
            d = 0.0  # also for NaN
        b1 += d
        b2 += d
        b3 -= d
        b4 -= d
        out[0] = _sqrt(b1 * g.c_u)
        out[1] = _sqrt(b2 * g.c_u)
        out[2] = _sqrt(b3 * g.c_u)
        out[3] = _sqrt(b4 * g.c_u)

        # ---- integrators (forward Euler; back-calculation on the achieved torque)
        i_p += g.dt * g.pitch_ki * e_p + g.att_kb * (g.arm_a * (b1 - b2 + b3 - b4) - tq_m)
        i_r += g.dt * g.roll_ki * e_r + g.att_kb * (g.arm_a * (b2 + b3 - b1 - b4) - tq_l)
        i_lim = g.att_i_lim
        self._i_p = i_lim if i_p > i_lim else (-i_lim if i_p < -i_lim else i_p)
        self._i_r = i_lim if i_r > i_lim else (-i_lim if i_r < -i_lim else i_r)
        # altitude: upward-thrust integrator (grows while the vehicle is below its reference
        # or sinks faster than commanded). Anti-windup by conditional integration: the
        # position term is frozen while the climb rate is limited, and the whole update is
        # skipped while the thrust saturates in the direction it would push.
        if pos_mode:
            di = g.ki_z_vpos * (vz - vzc) if limited else g.ki_z_vpos * (vz - vzc) - g.ki_z_pos * ez
        else:
            di = g.ki_z_vel * (vz - vzc)
        di *= g.dt
        if not ((t_sat > 0 and di > 0.0) or (t_sat < 0 and di < 0.0)):
            i_z += di
            self._i_z = g.z_i_lim if i_z > g.z_i_lim else (-g.z_i_lim if i_z < -g.z_i_lim else i_z)
        self._n = n + 1
