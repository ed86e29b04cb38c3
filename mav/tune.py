"""Loop analysis of the onboard controllers with python-control (`python -m mav.tune mambo`).

Every loop is linearised about hover from the Airframe: small-angle rigid body, first-order
motor lag (motor_tau, on thrust and reaction torque alike), linear airframe drag and rotational
damping. The plant is discretised with the exact zero-order hold at the controller period
(5 ms) and closed with the controller's own discrete law (forward-Euler integrators, D on the
measured rate), using the gains the controller's hot path runs (`linear_gains()`), so what
is analysed is what flies. Limits and saturations are left out (small-signal analysis).

Loops (the break point for the margins is the input of the loop's plant):

=========  ==============================================  ===========================
loop       law                                             plant input / output
=========  ==============================================  ===========================
roll       L = kp*(phi_r - phi) + I - kd*p                 roll torque / roll
pitch      M = kp*(theta_r - theta) + I - kd*q             pitch torque / pitch
yaw        N = k_r*(k_psi*(psi_r - psi) - r)               yaw torque / heading
yaw_rate   N = k_r*(r_r - r) (Bebop 2 only)                yaw torque / yaw rate
alt        T = k_vz*(vz - k_z*(z_r - z)) - I               thrust / z (position mode)
vz         T = k_vz*(vz - vz_r) - I                        thrust / vz (velocity mode)
x, y       tilt_r = k_vxy*(k_xy*e - v) + I, through attitude   tilt reference / position
vx, vy     tilt_r = k_vxy*(v_r - v) + c_drag*v_r + I        tilt reference / velocity
           (I: the horizontal velocity integral, ki_vxy * integral of the velocity error)
=========  ==============================================  ===========================
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import control as ct
import numpy as np

from mav.airframe import Airframe, get_airframe
from mav.control import make_controller

__all__ = [
    "GM_MIN_DB", "IDENTIFIED_BEBOP2", "PM_MIN_DEG", "analyse", "check", "main", "step_response",
]

PM_MIN_DEG = 30.0  # deg, phase margin every loop must have
GM_MIN_DB = 6.0    # dB, gain margin every loop must have

# Pinto et al. (ICUAS 2020), reference/mavlink.md: x'' = F1*u - F2*x' for (x, y, z, yaw),
# u normalised to +-1 (PCMD percent / 100).
IDENTIFIED_BEBOP2 = {
    "F1": {"x": 0.8417, "y": 0.8354, "z": 3.966, "yaw": 9.8524},   # (m/s^2 or rad/s^2) per unit
    "F2": {"x": 0.18227, "y": 0.17095, "z": 4.001, "yaw": 4.7295},  # 1/s
}


# ----------------------------------------------------------------------------- linear models
def _rot_axis(J: float, damp: float, tau: float) -> ct.StateSpace:
    """Torque command -> [angle, rate]: states angle (rad), rate (rad/s), torque (N m)."""
    A = [[0.0, 1.0, 0.0], [0.0, -damp / J, 1.0 / J], [0.0, 0.0, -1.0 / tau]]
    B = [[0.0], [0.0], [1.0 / tau]]
    C = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    return ct.ss(A, B, C, np.zeros((2, 1)))


def _drop_pos(sys_c: ct.StateSpace) -> ct.StateSpace:
    """The same model without its first state and output (the position/angle, on which nothing
    else depends): what a velocity- or rate-mode loop sees (no unobservable integrator)."""
    A, B, C = np.asarray(sys_c.A), np.asarray(sys_c.B), np.asarray(sys_c.C)
    assert not np.any(A[:, 0]), "state 0 must be a pure integrator"
    return ct.ss(A[1:, 1:], B[1:], C[1:, 1:], np.zeros((C.shape[0] - 1, 1)))


def _vertical(v: Airframe) -> ct.StateSpace:
    """Downward force deviation command (= -thrust deviation) -> [z, vz] (NED, m, m/s)."""
    return _rot_axis(v.mass, v.drag_z, v.motor_tau)


def _lateral(v: Airframe, axis: str) -> ct.StateSpace:
    """Torque command -> [pos, vel, tilt, rate] for x (through pitch) or y (through roll).
    Small angle: x'' = -g*theta - (drag/m)*x', y'' = +g*phi - (drag/m)*y'."""
    J = v.Iyy if axis == "x" else v.Ixx
    sg = -v.g if axis == "x" else v.g
    dm = v.drag_xy / v.mass
    A = [
        [0.0, 1.0, 0.0, 0.0, 0.0],
        [0.0, -dm, sg, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0],
        [0.0, 0.0, 0.0, -v.drag_rot / J, 1.0 / J],
        [0.0, 0.0, 0.0, 0.0, -1.0 / v.motor_tau],
    ]
    B = [[0.0], [0.0], [0.0], [0.0], [1.0 / v.motor_tau]]
    C = np.eye(5)[:4]
    return ct.ss(A, B, C, np.zeros((4, 1)))


@dataclass(frozen=True)
class _Law:
    """u = sign*(kp*(r - y0) + kff*r - kd*y1 + xi);  xi+ = xi + dt*(ki0*(r - y0) - ki1*y1).

    y0 = outputs[i0], y1 = outputs[i1] (i1 None: no rate term)."""

    kp: float
    kd: float = 0.0
    ki0: float = 0.0
    ki1: float = 0.0
    kff: float = 0.0
    i0: int = 0
    i1: int | None = 1
    sign: float = 1.0

    def matrices(self, ny: int, dt: float):
        """(Ak, Bkr, Bky, Ck, Dkr, Dky) of the discrete law with ny plant outputs."""
        s = self.sign
        Dky = np.zeros((1, ny))
        Dky[0, self.i0] = -s * self.kp
        Bky = np.zeros((1, ny))
        Bky[0, self.i0] = -dt * self.ki0
        if self.i1 is not None:
            Dky[0, self.i1] += -s * self.kd
            Bky[0, self.i1] += -dt * self.ki1
        Dkr = np.array([[s * (self.kp + self.kff)]])
        if self.ki0 == 0.0 and self.ki1 == 0.0:
            return (np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((0, ny)), np.zeros((1, 0)),
                    Dkr, Dky)
        return (np.eye(1), np.array([[dt * self.ki0]]), Bky, np.array([[s]]), Dkr, Dky)


def _loop_transfer(G: ct.StateSpace, law: _Law) -> ct.StateSpace:
    """Open loop broken at the plant input, negative-feedback convention: L = -K_y*G."""
    Ak, _, Bky, Ck, _, Dky = law.matrices(G.noutputs, G.dt)
    K = ct.ss(Ak, Bky, Ck, Dky, G.dt) if Ak.size else ct.ss([], np.zeros((0, G.noutputs)),
                                                             np.zeros((1, 0)), Dky, G.dt)
    return -K * G


def _close(G: ct.StateSpace, law: _Law) -> ct.StateSpace:
    """Closed loop r -> all plant outputs (G discrete, strictly proper)."""
    Ap, Bp, Cp = np.asarray(G.A), np.asarray(G.B), np.asarray(G.C)
    Ak, Bkr, Bky, Ck, Dkr, Dky = law.matrices(G.noutputs, G.dt)
    n_p, n_k = Ap.shape[0], Ak.shape[0]
    A = np.zeros((n_p + n_k, n_p + n_k))
    A[:n_p, :n_p] = Ap + Bp @ Dky @ Cp
    A[:n_p, n_p:] = Bp @ Ck
    A[n_p:, :n_p] = Bky @ Cp
    A[n_p:, n_p:] = Ak
    B = np.vstack([Bp @ Dkr, Bkr])
    C = np.hstack([Cp, np.zeros((Cp.shape[0], n_k))])
    return ct.ss(A, B, C, np.zeros((Cp.shape[0], 1)), G.dt)


# ----------------------------------------------------------------------------- metrics
def _freq(L: ct.StateSpace, w: np.ndarray) -> np.ndarray:
    """Complex frequency response of a SISO discrete state space at w (rad/s)."""
    A, B, C, D = (np.asarray(M, dtype=float) for M in (L.A, L.B, L.C, L.D))
    if A.size == 0:
        return np.full(w.shape, D[0, 0], dtype=complex)
    z = np.exp(1j * w * L.dt)
    M = z[:, None, None] * np.eye(A.shape[0]) - A
    x = np.linalg.solve(M, np.broadcast_to(B, (w.size, *B.shape)).astype(complex))
    return (C @ x)[:, 0, 0] + D[0, 0]


def _margins(L: ct.StateSpace, n: int = 6000) -> tuple[float, float, float, float]:
    """(upper gain margin dB, lower gain margin dB, phase margin deg, gain crossover rad/s).

    Evaluated on a dense log grid up to the Nyquist frequency, crossings interpolated
    (python-control's `stability_margins` gives the same numbers, see tests, but falls back to
    a slow spline method on these loops). With an integrator in the loop the phase also
    crosses -180 deg at low frequency where |L| > 1 (conditional stability): that crossing
    gives the *lower* gain margin (how far the gain may drop, negative dB); the upper margin
    is the usual one. inf / -inf: no such crossing."""
    w = np.logspace(-3, math.log10(math.pi / L.dt) - 1e-6, n)
    h = _freq(L, w)
    mag = np.abs(h)
    lm = np.log(np.maximum(mag, 1e-300))
    # gain crossovers: |L| = 1
    pm, wgc = math.inf, math.nan
    for i in np.nonzero(np.sign(lm[:-1]) != np.sign(lm[1:]))[0]:
        f = lm[i] / (lm[i] - lm[i + 1])
        hc = h[i] + f * (h[i + 1] - h[i])
        p = (math.degrees(math.atan2(hc.imag, hc.real)) + 180.0) % 360.0
        p = p - 360.0 if p > 180.0 else p
        if p < pm:
            pm, wgc = p, float(w[i] * (w[i + 1] / w[i]) ** f)
    # phase crossovers: Im L = 0 with Re L < 0
    up, low = [], []
    im = h.imag
    for i in np.nonzero((np.sign(im[:-1]) != np.sign(im[1:])) & (im[:-1] != 0))[0]:
        f = im[i] / (im[i] - im[i + 1])
        re = h[i].real + f * (h[i + 1].real - h[i].real)
        if re < 0:
            gm = -1.0 / re
            (up if gm >= 1.0 else low).append(gm)
    gm_db = 20.0 * math.log10(min(up)) if up else math.inf
    gm_low_db = 20.0 * math.log10(max(low)) if low else -math.inf
    return gm_db, gm_low_db, pm, wgc


def _step(cl: ct.StateSpace, out: int, t_end: float) -> dict[str, float]:
    """Unit step metrics of output `out`: 10-90 % rise, overshoot, 2 % settling, 63 % time."""
    dt = cl.dt
    T = np.arange(0.0, t_end + dt / 2, dt)
    resp = ct.step_response(cl[out, 0], T)
    y = np.squeeze(resp.outputs)
    stable = bool(np.all(np.abs(np.linalg.eigvals(np.asarray(cl.A))) < 1.0))
    yf = float(ct.dcgain(cl[out, 0])) if stable else math.nan
    if not stable or not np.isfinite(yf) or abs(yf) < 1e-12:
        return {"stable": stable, "rise_s": math.nan, "overshoot_pct": math.nan,
                "settling_s": math.nan, "t63_s": math.nan, "final": yf}
    yn = y / yf

    def first(th: float) -> float:
        idx = np.nonzero(yn >= th)[0]
        return float(T[idx[0]]) if idx.size else math.nan

    outside = np.nonzero(np.abs(yn - 1.0) > 0.02)[0]
    settling = float(T[outside[-1] + 1]) if outside.size and outside[-1] + 1 < T.size else (
        0.0 if not outside.size else math.nan)
    return {
        "stable": stable,
        "rise_s": first(0.9) - first(0.1),
        "overshoot_pct": max(0.0, float(np.max(yn) - 1.0) * 100.0),
        "settling_s": settling,
        "t63_s": first(1.0 - math.exp(-1.0)),
        "final": yf,
    }


# ----------------------------------------------------------------------------- analysis
def _controller(vehicle_name: str, params: dict[str, float] | None, preset: str,
                vehicle_overrides: dict[str, float] | None):
    v = get_airframe(vehicle_name)
    if vehicle_overrides:
        v = v.with_overrides(**vehicle_overrides)
    ctrl = make_controller(v)
    if preset != "default":
        ctrl.apply_preset(preset)  # type: ignore[attr-defined]
    for k, val in (params or {}).items():
        ctrl.set_param(k, val)
    return v, ctrl


def _loops(v: Airframe, ctrl) -> dict[str, tuple[ct.StateSpace, _Law, float]]:
    """Every loop as (discrete plant seen by the law, law, step horizon s); output 0 of the
    plant is the loop's controlled variable."""
    g = ctrl.linear_gains()
    dt = ctrl.dt

    def zoh(sys_c: ct.StateSpace) -> ct.StateSpace:
        return ct.c2d(sys_c, dt, method="zoh")

    loops: dict[str, tuple[ct.StateSpace, _Law, float]] = {}
    # attitude and the lateral loops through it
    for ax, tilt, J, sign in (("pitch", "x", v.Iyy, -1.0), ("roll", "y", v.Ixx, 1.0)):
        att = _Law(kp=g[f"{ax}_kp"], kd=g[f"{ax}_kd"], ki0=g[f"{ax}_ki"])
        loops[ax] = (zoh(_rot_axis(J, v.drag_rot, v.motor_tau)), att, 5.0)
        k_vxy, k_xy = g["k_vxy"], g["k_xy"]
        # position loop: attitude closed inside, plant outputs [pos, vel, tilt, rate]
        inner = _close(zoh(_lateral(v, tilt)), _Law(kp=att.kp, kd=att.kd, ki0=att.ki0,
                                                     i0=2, i1=3))
        ki_v = g.get("ki_vxy", 0.0)   # horizontal velocity integral (wind)
        loops[tilt] = (inner, _Law(kp=k_vxy * k_xy, kd=k_vxy, ki0=ki_v * k_xy, ki1=ki_v,
                                   i0=0, i1=1, sign=sign), 20.0)
        # velocity loop: plant outputs [vel, tilt, rate]
        inner_v = _close(zoh(_drop_pos(_lateral(v, tilt))),
                         _Law(kp=att.kp, kd=att.kd, ki0=att.ki0, i0=1, i1=2))
        loops["v" + tilt] = (inner_v, _Law(kp=k_vxy, kff=g["c_drag"], ki0=ki_v, i0=0,
                                           i1=None, sign=sign), 20.0)
    # heading
    loops["yaw"] = (zoh(_rot_axis(v.Izz, v.drag_rot, v.motor_tau)),
                    _Law(kp=g["k_r"] * g["k_psi"], kd=g["k_r"]), 5.0)
    if not g["yaw_rate_integrates"]:
        loops["yaw_rate"] = (zoh(_drop_pos(_rot_axis(v.Izz, v.drag_rot, v.motor_tau))),
                             _Law(kp=g["k_r"], i1=None), 5.0)
    # vertical (plant input: downward force; the law is written for it)
    k_z, k_vz = g["k_z"], g["k_vz"]
    loops["alt"] = (zoh(_vertical(v)),
                    _Law(kp=k_vz * k_z, kd=k_vz, ki0=g["ki_z_pos"] + g["ki_z_vpos"] * k_z,
                         ki1=g["ki_z_vpos"]), 20.0)
    loops["vz"] = (zoh(_drop_pos(_vertical(v))), _Law(kp=k_vz, ki0=g["ki_z_vel"], i1=None),
                   10.0)
    return loops


def analyse(
    vehicle_name: str,
    params: dict[str, float] | None = None,
    *,
    preset: str = "default",
    vehicle_overrides: dict[str, float] | None = None,
) -> dict[str, dict[str, float]]:
    """Margins and step metrics of every loop of `vehicle_name`'s controller.

    Parameters
    ----------
    vehicle_name : 'mambo' or 'bebop2'
    params : controller parameters to set (MAVLink names, units of the param table)
    preset : controller preset applied before `params` ('default', or e.g. 'template')
    vehicle_overrides : Airframe fields to replace (e.g. {'motor_tau': 0.05}, s)

    Returns
    -------
    {loop: {'gm_db' (upper gain margin), 'gm_low_db' (lower gain margin of a conditionally
            stable loop, -inf if none), 'pm_deg', 'wc_rad_s' (gain crossover),
            'stable' (closed loop), 'rise_s' (10-90 %), 'overshoot_pct', 'settling_s' (2 %),
            't63_s' (time to 63 %), 'final' (DC gain)}}
    plus for the Bebop 2 an entry '_identified' comparing first-order time constants.
    """
    v, ctrl = _controller(vehicle_name, params, preset, vehicle_overrides)
    res: dict[str, dict[str, float]] = {}
    for name, (G, law, t_end) in _loops(v, ctrl).items():
        gm, gm_low, pm, wc = _margins(_loop_transfer(G, law))
        res[name] = {"gm_db": gm, "gm_low_db": gm_low, "pm_deg": pm, "wc_rad_s": wc,
                     **_step(_close(G, law), 0, t_end)}

    if v.name == "bebop2":
        ident = {}
        for loop, key in (("vx", "x"), ("vy", "y"), ("vz", "z"), ("yaw_rate", "yaw")):
            ident[key + "_tau_s"] = res[loop]["t63_s"]
            ident[key + "_tau_id_s"] = 1.0 / IDENTIFIED_BEBOP2["F2"][key]
        # the identified x/y model is the open-loop response to a tilt command: its F2 is the
        # airframe drag pole, which the plant has as drag_xy/mass
        ident["drag_pole_plant_1_s"] = v.drag_xy / v.mass
        ident["F1_z_equiv"] = ctrl.get_param("CAS_Z_VEL_MAX") / res["vz"]["t63_s"]
        ident["F1_yaw_equiv"] = (math.radians(ctrl.get_param("MC_YAWRATE_MAX"))
                                 / res["yaw_rate"]["t63_s"])
        res["_identified"] = ident
    return res


def step_response(
    vehicle_name: str,
    loop: str,
    t_end: float,
    params: dict[str, float] | None = None,
    *,
    preset: str = "default",
    vehicle_overrides: dict[str, float] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Linear closed-loop unit-step response of one loop: (t in s, controlled variable)."""
    v, ctrl = _controller(vehicle_name, params, preset, vehicle_overrides)
    loops = _loops(v, ctrl)
    if loop not in loops:
        raise ValueError(f"unknown loop {loop!r}; choose one of {', '.join(loops)}")
    G, law, _ = loops[loop]
    cl = _close(G, law)
    T = np.arange(0.0, t_end + cl.dt / 2, cl.dt)
    return T, np.squeeze(ct.step_response(cl[0, 0], T).outputs)


def check(res: dict[str, dict[str, float]], pm_min: float = PM_MIN_DEG,
          gm_min_db: float = GM_MIN_DB) -> list[str]:
    """Violations (empty list = every loop stable with PM >= pm_min and GM >= gm_min_db)."""
    bad = []
    for name, m in res.items():
        if name.startswith("_"):
            continue
        if not m["stable"]:
            bad.append(f"{name}: closed loop unstable")
        if not m["pm_deg"] >= pm_min:
            bad.append(f"{name}: phase margin {m['pm_deg']:.1f} deg < {pm_min:g}")
        if not m["gm_db"] >= gm_min_db:
            bad.append(f"{name}: gain margin {m['gm_db']:.1f} dB < {gm_min_db:g}")
        if not m["gm_low_db"] <= -gm_min_db:
            bad.append(f"{name}: lower gain margin {m['gm_low_db']:.1f} dB > {-gm_min_db:g}")
    return bad


def format_table(vehicle_name: str, res: dict[str, dict[str, float]]) -> str:
    lines = [
        f"{vehicle_name}: loop margins (ZOH 5 ms, motor lag, drag) and closed-loop unit steps",
        f"{'loop':<9}{'GM dB':>7}{'GMlow':>7}{'PM deg':>8}{'wc rad/s':>10}{'stable':>8}"
        f"{'rise s':>8}{'overshoot %':>12}{'settle s':>10}{'t63 s':>8}",
    ]
    for name, m in res.items():
        if name.startswith("_"):
            continue
        lines.append(
            f"{name:<9}{m['gm_db']:>7.1f}{m['gm_low_db']:>7.1f}{m['pm_deg']:>8.1f}{m['wc_rad_s']:>10.2f}"
            f"{'yes' if m['stable'] else 'NO':>8}{m['rise_s']:>8.3f}{m['overshoot_pct']:>12.1f}"
            f"{m['settling_s']:>10.2f}{m['t63_s']:>8.3f}")
    ident = res.get("_identified")
    if ident:
        lines.append("velocity time constants vs the identified Bebop 2 model (1/F2):")
        for key in ("x", "y", "z", "yaw"):
            lines.append(f"  {key:<4} closed loop {ident[key + '_tau_s']:.3f} s, "
                         f"identified {ident[key + '_tau_id_s']:.3f} s")
        lines.append(f"  plant drag pole drag_xy/mass = {ident['drag_pole_plant_1_s']:.3f} 1/s "
                     f"(identified F2_x = {IDENTIFIED_BEBOP2['F2']['x']})")
        lines.append(f"  equivalent F1: z {ident['F1_z_equiv']:.2f} (identified 3.966), "
                     f"yaw {ident['F1_yaw_equiv']:.2f} (identified 9.852)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Print the loop table; exit 1 if a loop misses the margin thresholds."""
    ap = argparse.ArgumentParser(
        prog="python -m mav.tune",
        description="Loop margins and step responses of the onboard controllers.",
        epilog="examples:\n  python -m mav.tune mambo\n  python -m mav.tune mambo --preset "
               "template\n  python -m mav.tune bebop2 --set CAS_RP_D=30 --vehicle motor_tau=0.05",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("vehicle", nargs="+", help="mambo, bebop2 (one or more)")
    ap.add_argument("--preset", default="default", help="controller preset (mambo: template)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="controller parameter")
    ap.add_argument("--vehicle-param", "--vehicle", dest="vp", action="append", default=[],
                    metavar="FIELD=VALUE", help="Airframe override, e.g. motor_tau=0.05")
    args = ap.parse_args(argv)

    def kv(items: list[str]) -> dict[str, float]:
        d = {}
        for it in items:
            k, sep, val = it.partition("=")
            try:
                v = float(val)
            except ValueError:
                v = math.nan
            if not sep or not math.isfinite(v):
                ap.error(f"expected NAME=VALUE with a finite number, got {it!r}")
            d[k.strip()] = v
        return d

    for it in args.vp:  # airframe values are physical magnitudes: > 0 (drag_rot >= 0)
        k, _, val = it.partition("=")
        v = kv([it])[k.strip()]
        if not (v > 0.0 or (k.strip() == "drag_rot" and v == 0.0)):
            ap.error(f"--vehicle-param {k.strip()}: got {val!r}; expected a number > 0")

    rc = 0
    for name in args.vehicle:
        try:
            res = analyse(name, kv(args.set), preset=args.preset,
                          vehicle_overrides=kv(args.vp))
        except (ValueError, TypeError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        print(format_table(name, res))
        bad = check(res)
        for b in bad:
            print(f"  FAIL {b}")
        print(f"  thresholds: PM >= {PM_MIN_DEG:g} deg, GM >= {GM_MIN_DB:g} dB: "
              f"{'ok' if not bad else 'NOT MET'}\n")
        rc = rc or (1 if bad else 0)
    return rc


if __name__ == "__main__":
    sys.exit(main())
