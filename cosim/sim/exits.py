"""Why a run ends: the exit reasons and the conditions checked after every plant step.

`ExitMonitor.check` runs once per tick on the plant state at t_k+1 and returns the first
condition met (in this order: non-finite state, hard touchdown, flipped over, left the arena,
landed), or None to go on. The time limit and failures of a part are decided by the loop.
"""

from __future__ import annotations

import cython

from cosim.errors import ComponentError
from cosim.plant.fmu import Y_ON_GROUND, Y_QX, Y_QY, Y_VZ, Y_X, Y_Y, Y_Z
from cosim.scenario.records import ExitReason
from cosim.world.clearance import sphere_clearance

CEILING_M = 5.0            # m above the floor: higher is "left the arena"
ARENA_MARGIN_M = 0.5       # m outside the arena bounds before LEFT_ARENA
CRASH_VZ_MPS = 2.0         # m/s, touchdown faster than this is a crash
CRASH_TILT_COS = 0.0       # cos(90 deg): flipped over
FLIP_PRECHECK = 0.49        # qx^2 + qy^2 above which flipped() is asked (flipped: > 0.5)
AIRBORNE_Z_M = -0.10       # m, higher than this counts as having flown
REST_TIMEOUT_S = 3.0       # s on the ground, armed, after flying: LANDED anyway

Exit = tuple[ExitReason, str]

# C copies of the state's indices and the limits the per-tick check compares with (compiled,
# a comparison of two doubles; Python floats in the interpreted module)
# the values checked finite: position and velocity, what the vehicle must have (and what the
# framed exchange's integer fields refuse when not finite); a plant mapped from another FMU
# may leave outputs it lacks (rotor speeds, accelerations) NaN
_N_STATE = cython.declare(cython.Py_ssize_t, Y_VZ + 1)
_YX = cython.declare(cython.Py_ssize_t, Y_X)
_YY = cython.declare(cython.Py_ssize_t, Y_Y)
_YZ = cython.declare(cython.Py_ssize_t, Y_Z)
_YQX = cython.declare(cython.Py_ssize_t, Y_QX)
_YQY = cython.declare(cython.Py_ssize_t, Y_QY)
_YGND = cython.declare(cython.Py_ssize_t, Y_ON_GROUND)
_AIRBORNE_Z = cython.declare(cython.double, AIRBORNE_Z_M)
_FLIP_PRE = cython.declare(cython.double, FLIP_PRECHECK)
_CEILING = cython.declare(cython.double, CEILING_M)


def hard_touchdown(vz_mps: float) -> Exit | None:
    if abs(vz_mps) > CRASH_VZ_MPS:
        return ExitReason.CRASHED, f"hard touchdown at {vz_mps:.2f} m/s"
    return None


def flipped(qx: float, qy: float) -> Exit | None:
    if 1.0 - 2.0 * (qx * qx + qy * qy) < CRASH_TILT_COS:
        return ExitReason.CRASHED, "flipped over"
    return None


def left_arena(arena, n: float, e: float, d: float) -> Exit | None:
    if (n < arena[0] - ARENA_MARGIN_M or n > arena[1] + ARENA_MARGIN_M
            or e < arena[2] - ARENA_MARGIN_M or e > arena[3] + ARENA_MARGIN_M or d < -CEILING_M):
        return ExitReason.LEFT_ARENA, f"left the arena at N {n:.2f} E {e:.2f} D {d:.2f} m"
    return None


# the vehicle's failsafes a run's message names when one fired (onboard_stats counters)
FAILSAFES = (("failsafe_est_tilt", "estimator failure (attitude)"),
             ("failsafe_est_vel", "estimator failure (velocity)"),
             ("failsafe_imu", "no valid IMU data"))


def failsafe_note(stats: dict) -> str:
    """"; failsafe: <what>" for each failsafe of the vehicle that fired (`stats`: its
    onboard_stats), or "" (the message of a run without one is unchanged)."""
    return "".join(f"; failsafe: {what}" for k, what in FAILSAFES if stats.get(k, 0) > 0)


class ExitMonitor:
    """The exit conditions and the touchdown bookkeeping they need.

    `sitl`: only crashes (hard touchdown, flipped, a collision) are reported (a vehicle for
    outside clients has no mission and no arena; `cosim sitl` respawns it). `app`: the app
    object or None; a landed, disarmed vehicle whose app is done (or that has no app)
    completes the mission.
    """

    def __init__(self, arena, tick_s: float, app, *, sitl: bool = False, scene=None,
                 body_radius: float = 0.0) -> None:
        self.arena = arena
        self.arena_box = (arena[0] - ARENA_MARGIN_M, arena[1] + ARENA_MARGIN_M,
                          arena[2] - ARENA_MARGIN_M, arena[3] + ARENA_MARGIN_M)
        self.h = tick_s
        self.app = app
        self.seq = getattr(app, "seq", None)    # its FlightSequencer: arming refused ends it
        self.sitl = sitl
        self.airborne = False
        self.ground_ticks = 0
        self.t_touch: tuple[float, float, float] | None = None   # (t, n, e) of the touchdown
        self.touchdown: tuple[float, float, float] | None = None  # the final one, at exit
        self.rest_ticks = int(round(REST_TIMEOUT_S / tick_s))
        self.disarmed_ticks = 0     # ticks on the ground disarmed (the app's time to see it)
        # 3D worlds: clearance of the body sphere to walls, ceiling, boxes, columns
        self.scene = scene if scene is not None and not scene.empty else None
        if self.scene is not None:
            self.walls, self.solids = self.scene.walls(), self.scene.solids()
        self.body_radius = body_radius
        self.min_clearance: tuple[float, float, str] | None = None   # (m, t s, what)

    @cython.locals(d=cython.double, qx=cython.double, qy=cython.double, n=cython.double,
                   e=cython.double, airborne=cython.bint, s=cython.double, v=cython.double,
                   i=cython.Py_ssize_t, a=tuple, n0=cython.double, n1=cython.double,
                   e0=cython.double, e1=cython.double)
    def check(self, t: float, y, vz_before: float, u) -> Exit | None:
        """State `y` at t_k+1 = t + h; `vz_before` the vertical speed at t_k; `u` the motor
        commands held over the step. Runs every tick: the common case (flying, nothing to
        report) is a few comparisons; the named conditions build the exit. A position or
        velocity that is not finite is the plant's failure, before anything reads it: so the
        run ends alike whether the sensors' frames (whose integer fields would refuse it) or
        MIL's typed records (which carry it) come next."""
        s = 0.0
        for i in range(_N_STATE):
            v = y[i]
            s += v
        if s - s != 0.0:                       # a NaN or an infinity among them
            raise ComponentError("plant", "non-finite state")
        d = y[_YZ]
        airborne = self.airborne
        if not airborne and d < _AIRBORNE_Z:
            self.airborne = airborne = True
        elif not airborne and self.seq is not None and self.seq.state == "refused":
            return ExitReason.APP_ABORTED, f"arming refused: {self.seq.refused}"
        if airborne:
            if y[_YGND] > 0.5:
                if self.ground_ticks == 0:
                    self.t_touch = (t + self.h, y[_YX], y[_YY])
                    hard = hard_touchdown(vz_before)
                    if hard:
                        self.touchdown = self.t_touch
                        return hard
                self.ground_ticks += 1
            elif self.ground_ticks:
                self.ground_ticks = 0
        qx = y[_YQX]
        qy = y[_YQY]
        if qx * qx + qy * qy > _FLIP_PRE:    # tilted past ~81 deg: flipped() decides
            out = flipped(qx, qy)
            if out:
                return out
        if self.scene is not None:
            hit = self.clearance(t + self.h, y[_YX], y[_YY], d)
            if hit:
                return hit
        if self.sitl:
            return None
        n = y[_YX]
        e = y[_YY]
        a = self.arena_box
        n0, n1, e0, e1 = a
        if n < n0 or n > n1 or e < e0 or e > e1 or d < -_CEILING:
            return left_arena(self.arena, n, e, d)
        if airborne and self.ground_ticks > 0:
            return self.landed(u[0] == 0.0 and u[1] == 0.0 and u[2] == 0.0 and u[3] == 0.0)
        return None

    def clearance(self, t: float, n: float, e: float, d: float) -> Exit | None:
        """Track the smallest clearance; a negative one is a collision with the named thing."""
        gap, what = sphere_clearance(self.walls, self.solids, n, e, d, self.body_radius)
        mc = self.min_clearance
        if mc is None or gap < mc[0]:
            self.min_clearance = (gap, t, what)
        if gap < 0.0:
            return ExitReason.COLLISION, (f"collision with the {what} at t = {t:.3f} s "
                                          f"(N {n:.2f} E {e:.2f} D {d:.2f} m)")
        return None

    def landed(self, disarmed: bool) -> Exit | None:
        """On the ground after flying: complete when disarmed and the app is done; LANDED when
        disarmed for REST_TIMEOUT_S / 3 (counted from the disarm, so a land detector that
        takes its time does not cut the app's turn) or armed on the ground for REST_TIMEOUT_S
        without the app finishing."""
        app = self.app
        if disarmed and (app is None or app.done):
            self.touchdown = self.t_touch
            if getattr(app, "goal_reached", True) is False:
                return ExitReason.APP_ABORTED, (f"the app ended without reaching its goal: "
                                                f"{getattr(app, 'outcome', 'no reason')}")
            return ExitReason.MISSION_COMPLETE, "mission complete"
        self.disarmed_ticks = self.disarmed_ticks + 1 if disarmed else 0
        if (self.disarmed_ticks > self.rest_ticks // 3
                or self.ground_ticks > self.rest_ticks):
            self.touchdown = self.t_touch
            return ExitReason.LANDED, "landed before the app finished"
        return None
