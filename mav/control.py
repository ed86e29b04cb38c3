"""Onboard low-level flight controllers: the Mambo template FCS and a Bebop 2 velocity controller.

Contract (used by the onboard MAVLink vehicle; see mav/README.md, "Controllers"):

    ctrl = make_controller(vehicle, dt=0.005)      # MamboController or Bebop2Controller
    ctrl.update(state, setpoint, out)              # 200 Hz; writes u1..u4 in [0, 1] to out[0:4]

Motor order and spin (PX4 quad-X, viewed from above): 1 front-right CCW, 2 rear-left CCW,
3 front-left CW, 4 rear-right CW. Body FRD, world NED. Rotor i sits at (+-a, +-a) with
a = arm_length*sqrt(2)/2 and pushes k_thrust*w^2 along -z_body; a CCW rotor's reaction torque
is +yaw (about +z down). So roll right (+L) = more thrust on 2, 3; pitch up (+M) = more thrust
on 1, 3; yaw right (+N) = faster 1, 2. Motor command u = w_cmd/omega_max.

Both controllers share one hot path (`_QuadController.update`), a cascade that is, in its
linear range, identical to the template's PID structure:

- horizontal: v_cmd = K_xy*e_pos (error in the body-yaw frame, each axis saturated) + v_ff,
  limited to a horizontal speed; tilt = K_vxy*(v_cmd - v) + C_drag*v_ff, limited to a tilt.
  With K_xy = P/D and K_vxy = D this is the template's pitch_ref = -P*e_x + D*vx exactly.
- vertical: vz_cmd = K_z*e_z + vz_ff, limited to a climb rate; thrust = m*g + K_vz*(vz - vz_cmd)
  - integrator (+ take-off boost), divided by the tilt cosine, saturated. With K_z = P/D and
  K_vz = D this is the template's P/I/D altitude law exactly.
- attitude: torque = K_p*(angle_ref - angle) + integrator - K_d*rate (the template's PID
  with D on the measured body rate).
- yaw: r_cmd = K_psi*wrap(yaw_ref - yaw) + r_ff, limited; torque = K_r*(r_cmd - r)
  (= template P*e - D*r with K_psi = P/D, K_r = D).
- mixer: the inverse of [T; N; M; L] = A [T1..T4], thrusts clipped to [0, T_max], yaw given
  only the headroom the other axes leave, then u = sqrt(T/k_thrust)/omega_max.

The hot path is plain-float Python: gains live in one tuple rebuilt by `set_param`, so a tick
does no dict look-ups and allocates nothing but floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from mav.airframe import Airframe
from mav.types import Setpoint, VehicleState

_sqrt, _atan2, _asin, _cos, _sin = math.sqrt, math.atan2, math.asin, math.cos, math.sin

__all__ = [
    "Bebop2Controller",
    "Controller",
    "MamboController",
    "ParamSpec",
    "make_controller",
    "mixer_matrix",
]

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_D2R = math.pi / 180.0


@dataclass(frozen=True)
class ParamSpec:
    """One tunable parameter, MAVLink style (PARAM_VALUE carries it as a float)."""

    name: str       # <= 16 characters, MAVLink param id style ("MC_XY_P")
    default: float  # in `unit`
    min: float      # in `unit`, inclusive
    max: float      # in `unit`, inclusive
    unit: str       # e.g. "rad/m", "deg", "m/s"
    doc: str        # one line


class Controller(Protocol):
    dt: float  # s, control period

    def param_table(self) -> list[ParamSpec]: ...

    def get_param(self, name: str) -> float: ...

    def set_param(self, name: str, value: float) -> None: ...

    def reset(self) -> None: ...

    def update(self, s: VehicleState, sp: Setpoint, out: list[float]) -> None: ...


def mixer_matrix(v: Airframe) -> list[list[float]]:
    """A (4x4): [T; N; M; L] = A @ [T1, T2, T3, T4] for PX4 quad-X order (rows: total thrust N,
    yaw torque N m, pitch torque N m, roll torque N m; columns: rotor thrusts N)."""
    a = v.arm_length * _sqrt(2.0) / 2.0  # m, rotor offset along body x and y
    c = v.k_torque / v.k_thrust               # m, reaction torque per unit thrust
    # rotor positions (x forward, y right): 1 (+a,+a), 2 (-a,-a), 3 (+a,-a), 4 (-a,+a)
    # torque of a thrust T along -z at (x, y): roll = -y*T, pitch = +x*T
    return [
        [1.0, 1.0, 1.0, 1.0],
        [c, c, -c, -c],      # 1, 2 CCW -> +yaw; 3, 4 CW -> -yaw
        [a, -a, a, -a],      # front rotors (1, 3) pitch up
        [-a, a, a, -a],      # left rotors (2, 3) roll right
    ]


def _inverse4(m: list[list[float]]) -> list[list[float]]:
    """Inverse of a 4x4 matrix by Gauss-Jordan with partial pivoting (set-up time only)."""
    n = 4
    aug = [list(map(float, row)) + [1.0 if i == j else 0.0 for j in range(n)]
           for i, row in enumerate(m)]
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(aug[r][col]))
        if abs(aug[piv][col]) < 1e-15:
            raise ValueError("mixer matrix is singular (check arm_length, k_torque, k_thrust)")
        aug[col], aug[piv] = aug[piv], aug[col]
        pv = aug[col][col]
        aug[col] = [x / pv for x in aug[col]]
        for r in range(n):
            if r != col:
                f = aug[r][col]
                aug[r] = [x - f * y for x, y in zip(aug[r], aug[col], strict=True)]
    return [row[n:] for row in aug]


class _QuadController:
    """Shared cascade and mixer. Subclasses supply the parameter table and `_gains()`."""

    PARAMS: tuple[ParamSpec, ...] = ()
    PRESETS: dict[str, dict[str, float]] = {}
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
        Ai = _inverse4(A)
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
        self._yaw_ref = 0.0  # rad, heading reference
        self._n = 0       # armed ticks since arming (take-off boost counter)
        self._g: tuple = ()
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

    def set_param(self, name: str, value: float) -> None:
        """Set one parameter; it takes effect on the next update. ValueError if the name is
        unknown or the value is non-finite or outside [min, max]."""
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
                f"{name} = {v:g} {spec.unit} is outside [{spec.min:g}, {spec.max:g}]")
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
        """Rebuild the hot path's gain tuple from the parameters (called by set_param)."""
        g = self._gains()
        v = self.vehicle
        t_max = v.thrust_max
        Ai = self._Ainv
        self._g = (
            g["pitch_kp"], g["pitch_ki"], g["pitch_kd"],
            g["roll_kp"], g["roll_ki"], g["roll_kd"],
            g["att_i_lim"], g["att_kb"],
            g["k_psi"], g["k_r"], g["yawrate_max"],
            g["k_z"], g["k_vz"], g["ki_z_pos"], g["ki_z_vpos"], g["ki_z_vel"], g["z_i_lim"],
            g["vz_max"], g["thrust_max_total"], g["boost"], int(round(g["boost_ticks"])),
            g["k_xy"], g["k_vxy"], g["c_drag"], g["xy_err_max"], g["vxy_max"], g["tilt_max"],
            v.weight,
            Ai[0][0], Ai[0][2], Ai[0][3], Ai[1][0], Ai[1][2], Ai[1][3],
            Ai[2][0], Ai[2][2], Ai[2][3], Ai[3][0], Ai[3][2], Ai[3][3],
            Ai[0][1],
            t_max, 1.0 / (v.k_thrust * v.omega_max * v.omega_max),
            self._A[2][0], self.dt, self.YAW_RATE_INTEGRATES,
        )

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        """Clear integrators, the heading reference and the take-off boost counter."""
        self._i_p = self._i_r = self._i_z = 0.0
        self._yaw_ref = 0.0
        self._n = 0

    # ---------------------------------------------------------------- hot path
    def update(self, s: VehicleState, sp: Setpoint, out: list[float]) -> None:
        """One control tick: state estimate + setpoint -> motor commands u1..u4 in out[0:4].

        The state must be finite (the estimator's job); a NaN still never reaches the motors
        (the commands are clipped NaN-safe into [0, 1])."""
        if not sp.armed:
            out[0] = out[1] = out[2] = out[3] = 0.0
            if self._n:
                self.reset()
            return
        (kp_p, ki_p, kd_p, kp_r, ki_r, kd_r, i_lim, kb,
         k_psi, k_r, r_max,
         k_z, k_vz, ki_zp, ki_zvp, ki_zv, zi_lim, vz_max, t_tot_max, boost, boost_n,
         k_xy, k_vxy, c_drag, e_max, v_max, tilt_max,
         weight,
         m0t, m0m, m0l, m1t, m1m, m1l, m2t, m2m, m2l, m3t, m3m, m3l, my,
         t_max, c_u, arm_a, dt, integ) = self._g

        # attitude (ZYX Euler) from the quaternion
        qw, qx, qy, qz = s.qw, s.qx, s.qy, s.qz
        r33 = 1.0 - 2.0 * (qx * qx + qy * qy)
        roll = _atan2(2.0 * (qw * qx + qy * qz), r33)
        sp_ = 2.0 * (qw * qy - qz * qx)
        pitch = _asin(1.0 if sp_ > 1.0 else (-1.0 if sp_ < -1.0 else sp_))
        yaw = _atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
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
        if v2 > v_max * v_max:  # the feed-forward alone may not exceed the speed limit
            f = v_max / _sqrt(v2)
            fxb *= f
            fyb *= f
        px, py = sp.x, sp.y
        if px == px and py == py:
            ex = px - s.x
            ey = py - s.y
            exb = cy * ex + sy * ey
            eyb = cy * ey - sy * ex
            if exb > e_max:
                exb = e_max
            elif exb < -e_max:
                exb = -e_max
            if eyb > e_max:
                eyb = e_max
            elif eyb < -e_max:
                eyb = -e_max
            vcx = k_xy * exb + fxb
            vcy = k_xy * eyb + fyb
        else:
            vcx = fxb
            vcy = fyb
        v2 = vcx * vcx + vcy * vcy
        if v2 > v_max * v_max:
            f = v_max / _sqrt(v2)
            vcx *= f
            vcy *= f
        # forward acceleration needs nose down (negative pitch); rightward needs roll right
        pitch_ref = -(k_vxy * (vcx - vxb) + c_drag * fxb)
        roll_ref = k_vxy * (vcy - vyb) + c_drag * fyb
        t2 = pitch_ref * pitch_ref + roll_ref * roll_ref
        if t2 > tilt_max * tilt_max:
            f = tilt_max / _sqrt(t2)
            pitch_ref *= f
            roll_ref *= f

        # ---- vertical: altitude -> climb rate -> thrust (NED: up is -z)
        vz = s.vz
        fz = sp.vz
        if fz != fz:
            fz = 0.0
        zr = sp.z
        pos_mode = zr == zr
        if pos_mode:
            ez = zr - s.z
            vzc = k_z * ez + fz
        else:
            ez = 0.0
            vzc = fz
        limited = False
        if vzc > vz_max:
            vzc = vz_max
            limited = True
        elif vzc < -vz_max:
            vzc = -vz_max
            limited = True
        i_z = self._i_z
        thrust = weight + k_vz * (vz - vzc) + i_z
        if boost_n and n < boost_n and sp.takeoff_boost:
            thrust += boost
        if r33 > 0.5:  # tilt compensation (the template has none), capped at 60 deg
            thrust /= r33
        else:
            thrust *= 2.0
        t_sat = 0
        if thrust > t_tot_max:
            thrust = t_tot_max
            t_sat = 1
        elif thrust < 0.0:
            thrust = 0.0
            t_sat = -1

        # ---- attitude PID (D on body rates) -> pitch / roll torques
        e_p = pitch_ref - pitch
        e_r = roll_ref - roll
        i_p = self._i_p
        i_r = self._i_r
        tq_m = kp_p * e_p + i_p - kd_p * s.q
        tq_l = kp_r * e_r + i_r - kd_r * s.p

        # ---- heading
        yr = sp.yaw
        rr = sp.yaw_rate
        if yr == yr:
            yref = yr
            r_ff = 0.0
        elif rr == rr:
            # limited first, so the integrated heading reference cannot run away
            r_ff = r_max if rr > r_max else (-r_max if rr < -r_max else rr)
            if integ:
                yref = self._yaw_ref + r_ff * dt
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
        rc = k_psi * e_psi + r_ff
        if rc > r_max:
            rc = r_max
        elif rc < -r_max:
            rc = -r_max
        tq_n = k_r * (rc - s.r)

        # ---- mixer: thrust, pitch, roll first; yaw gets the remaining headroom
        b1 = m0t * thrust + m0m * tq_m + m0l * tq_l
        b2 = m1t * thrust + m1m * tq_m + m1l * tq_l
        b3 = m2t * thrust + m2m * tq_m + m2l * tq_l
        b4 = m3t * thrust + m3m * tq_m + m3l * tq_l
        b1 = t_max if b1 > t_max else (b1 if b1 > 0.0 else 0.0)  # NaN -> 0
        b2 = t_max if b2 > t_max else (b2 if b2 > 0.0 else 0.0)  # NaN -> 0
        b3 = t_max if b3 > t_max else (b3 if b3 > 0.0 else 0.0)  # NaN -> 0
        b4 = t_max if b4 > t_max else (b4 if b4 > 0.0 else 0.0)  # NaN -> 0
        d = my * tq_n  # rotors 1, 2 get +d, rotors 3, 4 get -d
        if d > 0.0:
            h = min(t_max - b1, t_max - b2, b3, b4)
            if d > h:
                d = h
        elif d < 0.0:
            h = min(b1, b2, t_max - b3, t_max - b4)
            if -d > h:
                d = -h
        else:
            d = 0.0  # also for NaN
        b1 += d
        b2 += d
        b3 -= d
        b4 -= d
        out[0] = _sqrt(b1 * c_u)
        out[1] = _sqrt(b2 * c_u)
        out[2] = _sqrt(b3 * c_u)
        out[3] = _sqrt(b4 * c_u)

        # ---- integrators (forward Euler; back-calculation on the achieved torque)
        i_p += dt * ki_p * e_p + kb * (arm_a * (b1 - b2 + b3 - b4) - tq_m)
        i_r += dt * ki_r * e_r + kb * (arm_a * (b2 + b3 - b1 - b4) - tq_l)
        self._i_p = i_lim if i_p > i_lim else (-i_lim if i_p < -i_lim else i_p)
        self._i_r = i_lim if i_r > i_lim else (-i_lim if i_r < -i_lim else i_r)
        # altitude: upward-thrust integrator (grows while the vehicle is below its reference
        # or sinks faster than commanded). Anti-windup by conditional integration: the
        # position term is frozen while the climb rate is limited, and the whole update is
        # skipped while the thrust saturates in the direction it would push.
        if pos_mode:
            di = ki_zvp * (vz - vzc) if limited else ki_zvp * (vz - vzc) - ki_zp * ez
        else:
            di = ki_zv * (vz - vzc)
        di *= dt
        if not ((t_sat > 0 and di > 0.0) or (t_sat < 0 and di < 0.0)):
            i_z += di
            self._i_z = zi_lim if i_z > zi_lim else (-zi_lim if i_z < -zi_lim else i_z)
        self._n = n + 1


# ===================================================================== Mambo
def _p(name, default, lo, hi, unit, doc) -> ParamSpec:
    return ParamSpec(name, float(default), float(lo), float(hi), unit, doc)


class MamboController(_QuadController):
    """The Simulink Parrot Minidrone template flight control system (reference/minidrone.md §2)
    with a position/velocity interface around it. Gains in the template's absolute units."""

    PARAMS = (
        # XY defaults deviate from the template (0.24, 0.1): on our plant the template loop
        # has 28/17 deg phase margin (x/y) and 38/52 % overshoot; 0.2/0.2 gives 52/37 deg and
        # ~1 % (python -m mav.tune mambo --preset template; mav/README.md "Controllers").
        _p("MC_XY_P", 0.2, 0.0, 2.0, "rad/m",
           "XY position gain, tilt per metre of error (template 0.24)"),
        _p("MC_XY_D", 0.2, 0.01, 1.0, "rad/(m/s)",
           "XY velocity damping = velocity-mode P gain (template 0.1)"),
        _p("MC_XY_ERR_MAX", 3.0, 0.1, 10.0, "m", "XY position error saturation per axis"),
        _p("MPC_XY_VEL_MAX", 2.0, 0.1, 7.0, "m/s", "horizontal speed limit"),
        _p("MPC_TILTMAX_AIR", 25.0, 5.0, 45.0, "deg", "tilt (roll/pitch reference) limit"),
        _p("MPC_Z_VEL_MAX", 1.5, 0.1, 3.0, "m/s", "climb and descent rate limit"),
        _p("MC_PITCH_P", 0.013, 0.0, 0.1, "N m/rad", "pitch angle P"),
        _p("MC_ROLL_P", 0.011, 0.0, 0.1, "N m/rad", "roll angle P"),
        _p("MC_RP_I", 0.01, 0.0, 0.1, "N m/(rad s)", "roll and pitch I"),
        _p("MC_RP_I_LIM", 2.0, 0.0, 10.0, "N m", "roll and pitch integrator limit"),
        _p("MC_RP_AW", 0.001, 0.0, 1.0, "-", "roll/pitch anti-windup back-calculation gain"),
        _p("MC_PITCH_D", 0.002, 0.0, 0.02, "N m s/rad", "pitch D on body rate q"),
        _p("MC_ROLL_D", 0.003, 0.0, 0.02, "N m s/rad", "roll D on body rate p"),
        _p("MC_YAW_P", 0.004, 0.0, 0.05, "N m/rad", "yaw angle P"),
        _p("MC_YAW_D", 0.0012, 1e-5, 0.02, "N m s/rad", "yaw D on body rate r"),
        _p("MC_YAWRATE_MAX", 200.0, 10.0, 720.0, "deg/s", "yaw rate limit"),
        _p("MC_Z_P", 0.8, 0.0, 10.0, "N/m", "altitude P"),
        _p("MC_Z_I", 0.24, 0.0, 5.0, "N/(m s)", "altitude I (on the altitude error)"),
        _p("MC_Z_I_LIM", 2.0, 0.0, 10.0, "N", "altitude integrator limit"),
        _p("MC_Z_D", 0.5, 0.01, 5.0, "N s/m", "altitude D on vz = vertical velocity P"),
        _p("MC_THR_MAX", 0.92, 0.1, 1.0, "-", "total thrust limit, fraction of 4*T_max"),
        _p("MC_TKO_BOOST", 0.45, 0.0, 1.0, "-", "take-off boost, fraction of m*g"),
        _p("MC_TKO_TICKS", 100.0, 0.0, 1000.0, "ticks",
           "take-off boost duration after arming (ticks of dt)"),
    )
    # The template's exact gains (no limits beyond its own +-3 m error saturation).
    PRESETS = {
        "template": {
            "MC_XY_P": 0.24, "MC_XY_D": 0.1, "MC_XY_ERR_MAX": 3.0, "MPC_XY_VEL_MAX": 7.0,
            "MPC_TILTMAX_AIR": 45.0, "MPC_Z_VEL_MAX": 3.0,
            "MC_PITCH_P": 0.013, "MC_ROLL_P": 0.011, "MC_RP_I": 0.01, "MC_RP_I_LIM": 2.0,
            "MC_RP_AW": 0.001, "MC_PITCH_D": 0.002, "MC_ROLL_D": 0.003,
            "MC_YAW_P": 0.004, "MC_YAW_D": 0.0012, "MC_YAWRATE_MAX": 720.0,
            "MC_Z_P": 0.8, "MC_Z_I": 0.24, "MC_Z_I_LIM": 2.0, "MC_Z_D": 0.5,
            "MC_THR_MAX": 0.92, "MC_TKO_BOOST": 0.45, "MC_TKO_TICKS": 100.0,
        },
    }
    YAW_RATE_INTEGRATES = True

    def _gains(self) -> dict[str, float]:
        p = self._p
        v = self.vehicle
        return {
            "pitch_kp": p["MC_PITCH_P"], "pitch_ki": p["MC_RP_I"], "pitch_kd": p["MC_PITCH_D"],
            "roll_kp": p["MC_ROLL_P"], "roll_ki": p["MC_RP_I"], "roll_kd": p["MC_ROLL_D"],
            "att_i_lim": p["MC_RP_I_LIM"], "att_kb": p["MC_RP_AW"] * self.dt,
            # template yaw P*e - D*r == D*((P/D)*e - r)
            "k_psi": p["MC_YAW_P"] / p["MC_YAW_D"], "k_r": p["MC_YAW_D"],
            "yawrate_max": p["MC_YAWRATE_MAX"] * _D2R,
            # template altitude P*e + I*int(e) - D*vz == D*((P/D)*e - vz) + I*int(e)
            "k_z": p["MC_Z_P"] / p["MC_Z_D"], "k_vz": p["MC_Z_D"],
            "ki_z_pos": p["MC_Z_I"], "ki_z_vpos": 0.0,
            # velocity mode: the same integral action expressed on the velocity error
            "ki_z_vel": (p["MC_Z_I"] * p["MC_Z_D"] / p["MC_Z_P"]) if p["MC_Z_P"] > 0.0 else 0.0,
            "z_i_lim": p["MC_Z_I_LIM"],
            "vz_max": p["MPC_Z_VEL_MAX"],
            "thrust_max_total": p["MC_THR_MAX"] * 4.0 * v.thrust_max,
            "boost": p["MC_TKO_BOOST"] * v.weight, "boost_ticks": p["MC_TKO_TICKS"],
            # template pitch_ref = -P*e_x + D*vx == -D*((P/D)*e_x - vx)
            "k_xy": p["MC_XY_P"] / p["MC_XY_D"], "k_vxy": p["MC_XY_D"],
            # velocity feed-forward also cancels the airframe drag: tilt = drag*v/(m*g)
            "c_drag": v.drag_xy / v.weight,
            "xy_err_max": p["MC_XY_ERR_MAX"], "vxy_max": p["MPC_XY_VEL_MAX"],
            "tilt_max": p["MPC_TILTMAX_AIR"] * _D2R,
        }


# ===================================================================== Bebop 2
class Bebop2Controller(_QuadController):
    """Velocity-commanded low level with Parrot's limits (max tilt, vertical speed, rotation
    speed). Gains are normalised (per unit inertia or mass), so the loop dynamics follow
    the Airframe; the defaults give first-order velocity responses close to the
    identified Bebop 2 model (Pinto et al. 2020): tau_z = 0.25 s, tau_yawrate = 0.21 s."""

    PARAMS = (
        _p("MPC_XY_P", 1.0, 0.0, 5.0, "1/s", "position -> horizontal velocity gain"),
        _p("MPC_XY_VEL_P", 2.0, 0.1, 10.0, "1/s",
           "horizontal velocity gain (acceleration per velocity error)"),
        _p("MPC_XY_ERR_MAX", 5.0, 0.1, 20.0, "m", "XY position error saturation per axis"),
        _p("MPC_XY_VEL_MAX", 5.0, 0.5, 15.0, "m/s", "horizontal speed limit"),
        _p("MPC_TILTMAX_AIR", 20.0, 5.0, 35.0, "deg", "Parrot MaxTilt"),
        _p("MPC_Z_P", 1.5, 0.0, 5.0, "1/s", "altitude -> vertical velocity gain"),
        _p("MPC_Z_VEL_P", 4.0, 0.5, 20.0, "1/s",
           "vertical velocity gain (acceleration per velocity error)"),
        _p("MPC_Z_VEL_I", 1.0, 0.0, 10.0, "1/s^2", "vertical velocity integral gain"),
        _p("MPC_Z_VEL_MAX", 1.0, 0.5, 2.5, "m/s", "Parrot MaxVerticalSpeed (up and down)"),
        _p("MC_RP_P", 100.0, 0.0, 1000.0, "1/s^2", "roll/pitch P (angular accel per rad)"),
        _p("MC_RP_I", 20.0, 0.0, 1000.0, "1/s^3", "roll/pitch I"),
        _p("MC_RP_D", 18.0, 0.0, 100.0, "1/s", "roll/pitch D on body rates"),
        _p("MC_RP_I_LIM", 5.0, 0.0, 50.0, "rad/s^2", "roll/pitch integrator limit"),
        _p("MC_YAW_P", 2.0, 0.0, 10.0, "1/s", "heading -> yaw rate gain"),
        _p("MC_YAWRATE_P", 4.73, 0.5, 50.0, "1/s",
           "yaw rate gain (angular accel per rate error)"),
        _p("MC_YAWRATE_MAX", 100.0, 10.0, 200.0, "deg/s", "Parrot MaxRotationSpeed"),
        _p("MC_THR_MAX", 0.95, 0.1, 1.0, "-", "total thrust limit, fraction of 4*T_max"),
    )
    PRESETS: dict[str, dict[str, float]] = {}
    YAW_RATE_INTEGRATES = False

    def _gains(self) -> dict[str, float]:
        p = self._p
        v = self.vehicle
        g = v.g
        return {
            "pitch_kp": p["MC_RP_P"] * v.Iyy, "pitch_ki": p["MC_RP_I"] * v.Iyy,
            "pitch_kd": p["MC_RP_D"] * v.Iyy,
            "roll_kp": p["MC_RP_P"] * v.Ixx, "roll_ki": p["MC_RP_I"] * v.Ixx,
            "roll_kd": p["MC_RP_D"] * v.Ixx,
            "att_i_lim": p["MC_RP_I_LIM"] * max(v.Ixx, v.Iyy), "att_kb": 0.0,
            "k_psi": p["MC_YAW_P"], "k_r": p["MC_YAWRATE_P"] * v.Izz,
            "yawrate_max": p["MC_YAWRATE_MAX"] * _D2R,
            "k_z": p["MPC_Z_P"], "k_vz": p["MPC_Z_VEL_P"] * v.mass,
            "ki_z_pos": 0.0,
            "ki_z_vpos": p["MPC_Z_VEL_I"] * v.mass, "ki_z_vel": p["MPC_Z_VEL_I"] * v.mass,
            "z_i_lim": 0.3 * v.weight,
            "vz_max": p["MPC_Z_VEL_MAX"],
            "thrust_max_total": p["MC_THR_MAX"] * 4.0 * v.thrust_max,
            "boost": 0.0, "boost_ticks": 0.0,
            "k_xy": p["MPC_XY_P"], "k_vxy": p["MPC_XY_VEL_P"] / g,
            "c_drag": v.drag_xy / v.weight,
            "xy_err_max": p["MPC_XY_ERR_MAX"], "vxy_max": p["MPC_XY_VEL_MAX"],
            "tilt_max": p["MPC_TILTMAX_AIR"] * _D2R,
        }


def make_controller(vehicle: Airframe, dt: float = 0.005) -> Controller:
    """The low-level controller for `vehicle` ('mambo' -> MamboController, 'bebop2' ->
    Bebop2Controller), with default parameters."""
    if vehicle.name == "mambo":
        return MamboController(vehicle, dt)
    if vehicle.name == "bebop2":
        return Bebop2Controller(vehicle, dt)
    raise ValueError(f"no controller for vehicle {vehicle.name!r}; known: mambo, bebop2")
