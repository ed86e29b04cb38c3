"""A small quadrotor written as a PythonFMU class: the test plant of another FMU toolchain.

`pythonfmu build -f EnuQuad.py` exports it as an FMI 2.0 Co-Simulation FMU (the tests build it
into a temporary folder: tests/test_plant_fmu_own.py). Everything about its interface differs
from the project's plant on purpose, so the scenario's map has work to do:

- world frame ENU (x east, y north, z up; the floor is z = 0), body frame FLU (x forward,
  y left, z up);
- attitude as Euler angles roll, pitch, yaw (z-y-x) in DEGREES, yaw counter-clockwise from
  east; body rates in deg/s;
- acceleration: the kinematic acceleration in the world frame (not an accelerometer);
- inputs: the rotor speed commands in rad/s of rotors named by where they sit
  (w_fr front-right, w_rl rear-left, w_fl front-left, w_rr rear-right; fr and rl spin
  counter-clockwise seen from above), and the wind in ENU;
- its own parameter names (m, Jxx, ..., kf, km, arm, tau_m, cd_xy, cd_z, cd_rot, grav);
- with the Boolean parameter `wrench` true it takes the thrust (N, along body up) and the
  torques (N m, FLU) as inputs instead of the rotor speeds (no rotors then).

No unit is declared (PythonFMU has no unit attribute): the scenario's map names the degrees.
The model: rigid body, quaternion state, first-order rotor lag, linear drag against the
air, a floor that stops the fall and levels the body; RK4 with substeps of at most 2.5 ms.
"""

import math

from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real

DEG = 180.0 / math.pi
SUBSTEP = 0.0025    # s


class EnuQuad(Fmi2Slave):
    author = "cosim tests"
    description = "Quadrotor in ENU/FLU with Euler angles in degrees (PythonFMU test plant)"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        # parameters (defaults: a 0.5 kg quadrotor; the scenario sets its own)
        self.m, self.Jxx, self.Jyy, self.Jzz = 0.5, 2e-3, 2e-3, 3e-3
        self.kf, self.km, self.arm, self.tau_m = 1.7e-6, 2.7e-8, 0.13, 0.0125
        self.cd_xy, self.cd_z, self.cd_rot, self.grav = 0.1, 0.1, 3e-5, 9.81
        for name in ("m", "Jxx", "Jyy", "Jzz", "kf", "km", "arm", "tau_m", "cd_xy", "cd_z",
                     "cd_rot", "grav"):
            self.register_variable(Real(name, causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed))
        self.wrench = False
        self.register_variable(Boolean("wrench", causality=Fmi2Causality.parameter,
                                       variability=Fmi2Variability.fixed))
        self.w_fr = self.w_rl = self.w_fl = self.w_rr = 0.0
        self.wind_e = self.wind_n = self.wind_u = 0.0
        self.thrust = self.torque_x = self.torque_y = self.torque_z = 0.0
        for name in ("w_fr", "w_rl", "w_fl", "w_rr", "wind_e", "wind_n", "wind_u", "thrust",
                     "torque_x", "torque_y", "torque_z"):
            self.register_variable(Real(name, causality=Fmi2Causality.input))
        # state: position, velocity (ENU), quaternion (FLU -> ENU), body rates, rotor speeds
        self.s = [0.0] * 17
        self.s[6] = 1.0
        self.pos_e = self.pos_n = self.pos_u = 0.0
        self.vel_e = self.vel_n = self.vel_u = 0.0
        self.acc_e = self.acc_n = self.acc_u = 0.0
        self.phi_deg = self.theta_deg = self.psi_deg = 0.0
        self.rate_x = self.rate_y = self.rate_z = 0.0
        for name in ("pos_e", "pos_n", "pos_u", "vel_e", "vel_n", "vel_u", "acc_e", "acc_n",
                     "acc_u", "phi_deg", "theta_deg", "psi_deg", "rate_x", "rate_y",
                     "rate_z"):
            self.register_variable(Real(name, causality=Fmi2Causality.output))

    # ---- the model -------------------------------------------------------------------------
    def deriv(self, s, cmd, wind):
        px, py, pz, vx, vy, vz, qw, qx, qy, qz, p, q, r = s[:13]
        w = s[13:17]
        r00, r01, r02 = (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz),
                         2 * (qx * qz + qw * qy))
        r10, r11, r12 = (2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz),
                         2 * (qy * qz - qw * qx))
        r20, r21, r22 = (2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx),
                         1 - 2 * (qx * qx + qy * qy))
        if self.wrench:
            thrust, tx, ty, tz = self.thrust, self.torque_x, self.torque_y, self.torque_z
        else:
            t = [self.kf * wi * wi for wi in w]            # fr, rl, fl, rr
            a = self.arm * math.sqrt(0.5)
            # FLU: fr (+a, -a), rl (-a, +a), fl (+a, +a), rr (-a, -a); tau = r x (0, 0, T)
            thrust = sum(t)
            tx = a * (-t[0] + t[1] + t[2] - t[3])
            ty = -a * (t[0] - t[1] + t[2] - t[3])
            tz = self.km * (-w[0] * w[0] - w[1] * w[1] + w[2] * w[2] + w[3] * w[3])
        ax_, ay_, az_ = vx - wind[0], vy - wind[1], vz - wind[2]        # air-relative, ENU
        bx = r00 * ax_ + r10 * ay_ + r20 * az_
        by = r01 * ax_ + r11 * ay_ + r21 * az_
        bz = r02 * ax_ + r12 * ay_ + r22 * az_
        fx, fy, fz = -self.cd_xy * bx, -self.cd_xy * by, -self.cd_z * bz + thrust
        im = 1.0 / self.m
        dv = ((r00 * fx + r01 * fy + r02 * fz) * im, (r10 * fx + r11 * fy + r12 * fz) * im,
              (r20 * fx + r21 * fy + r22 * fz) * im - self.grav)
        jx, jy, jz = self.Jxx, self.Jyy, self.Jzz
        dp = (tx - self.cd_rot * p - (jz - jy) * q * r) / jx
        dq = (ty - self.cd_rot * q - (jx - jz) * p * r) / jy
        dr = (tz - self.cd_rot * r - (jy - jx) * p * q) / jz
        dqw = 0.5 * (-qx * p - qy * q - qz * r)
        dqx = 0.5 * (qw * p + qy * r - qz * q)
        dqy = 0.5 * (qw * q + qz * p - qx * r)
        dqz = 0.5 * (qw * r + qx * q - qy * p)
        dw = [(c - wi) / self.tau_m for c, wi in zip(cmd, w, strict=True)]
        return [vx, vy, vz, *dv, dqw, dqx, dqy, dqz, dp, dq, dr, *dw]

    def do_step(self, current_time, step_size):
        cmd = (self.w_fr, self.w_rl, self.w_fl, self.w_rr)
        wind = (self.wind_e, self.wind_n, self.wind_u)
        n = max(1, math.ceil(step_size / SUBSTEP - 1e-9))
        h = step_size / n
        s = self.s
        for _ in range(n):
            k1 = self.deriv(s, cmd, wind)
            k2 = self.deriv([a + 0.5 * h * b for a, b in zip(s, k1, strict=True)], cmd, wind)
            k3 = self.deriv([a + 0.5 * h * b for a, b in zip(s, k2, strict=True)], cmd, wind)
            k4 = self.deriv([a + h * b for a, b in zip(s, k3, strict=True)], cmd, wind)
            s = [a + h / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
                 for a, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4, strict=True)]
            nq = math.sqrt(sum(c * c for c in s[6:10]))
            s[6:10] = [c / nq for c in s[6:10]]
            if s[2] < 0.0:        # the floor: stop, level, keep the heading
                yaw = math.atan2(2 * (s[6] * s[9] + s[7] * s[8]), 1 - 2 * (s[8] ** 2 + s[9] ** 2))
                s[2] = 0.0
                s[3:6] = [0.0, 0.0, 0.0]
                s[6:10] = [math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)]
                s[10:13] = [0.0, 0.0, 0.0]
        acc = self.deriv(s, cmd, wind)[3:6]
        self.s = s
        self.publish(s, acc)
        return True

    def publish(self, s, acc):
        self.pos_e, self.pos_n, self.pos_u = s[0:3]
        self.vel_e, self.vel_n, self.vel_u = s[3:6]
        self.acc_e, self.acc_n, self.acc_u = acc
        if s[2] <= 0.0 and acc[2] < 0.0:     # resting on the floor: it holds the weight
            self.acc_e = self.acc_n = self.acc_u = 0.0
        qw, qx, qy, qz = s[6:10]
        self.phi_deg = math.atan2(2 * (qw * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy)) * DEG
        self.theta_deg = math.asin(max(-1.0, min(1.0, 2 * (qw * qy - qz * qx)))) * DEG
        self.psi_deg = math.atan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)) * DEG
        self.rate_x, self.rate_y, self.rate_z = (c * DEG for c in s[10:13])
