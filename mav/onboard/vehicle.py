"""The vehicle: the onboard stack's parts put together, and its tick.

Three links (see `mav/links.py`): `hil` (the simulator: ODOMETRY in, HIL_ACTUATOR_CONTROLS out),
`api` (offboard apps, like PX4's link to 14540) and `gcs` (ground stations, like 14550).

Lockstep contract (ARCHITECTURE.md, "Time and order within a tick"): `poll()` does nothing
unless a HIL datagram is waiting. With a valid ODOMETRY it first drains and handles everything
queued on `api` and `gcs` (on the vehicle clock of the previous tick), then sets the vehicle
clock to the ODOMETRY's time_usec, copies the state, runs modes, failsafes and the
controller, publishes due telemetry and answers on `hil` with exactly one
HIL_ACTUATOR_CONTROLS stamped with the same time_usec (`step_record`: the same, typed). Every
timer runs on this clock, so a run is deterministic; api/gcs are read only at HIL time.

Embedded style: the records are preallocated and updated in place; the per-tick path uses
the fast codec of `mav/wire.py`; telemetry is only encoded when due.

The parts (one job each, sharing the `VehicleStatus` record): links.py (link input, signing,
STATUSTEXT), commander.py (arming, modes), navigator.py (take-off, land, ground detection),
offboard.py (setpoints), failsafe.py, parameters.py, commands.py, telemetry.py.
"""

from __future__ import annotations

import cython
from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.airframe import Airframe, get_airframe
from mav.battery import BATTERIES, Battery
from mav.estimator.core import Estimator
from mav.fields import f32
from mav.hil import SIM_SYSID, tick_refusal
from mav.links import kernel_drops
from mav.onboard.channels import Chan, LinkInput, Outbox, Stream
from mav.onboard.commander import Commander
from mav.onboard.commands import Commands
from mav.onboard.config import OnboardConfig
from mav.onboard.defs import (
    FRAME_BODY_FRD,
    FRAME_LOCAL_NED,
    HIL_MODE_ARMED,
    HIL_MODE_DISARMED,
    LAND,
    LOITER,
    MISSION,
    MODE_NAMES,
    OFFBOARD,
    ON_GROUND,
    POSCTL,
    RTL,
    STREAMS,
    TAKEOFF,
    hz_to_us,
)
from mav.onboard.failsafe import Failsafe
from mav.onboard.inject import hil_other
from mav.onboard.manual import Manual
from mav.onboard.mission import Mission
from mav.onboard.navigator import Navigator
from mav.onboard.offboard import Offboard
from mav.onboard.parameters import Parameters
from mav.onboard.status import VehicleStatus
from mav.onboard.telemetry import Telemetry
from mav.rotations import rotate_body_to_world
from mav.types import Setpoint, VehicleState

M = mavlink2

MAX_TIME_US = 1 << 62        # an ODOMETRY stamped later than this (146,000 years) is refused
STATS = ("ticks", "rx_hil", "rx_api", "rx_gcs", "tx_api", "tx_gcs", "dropped_bad_hil",
         "dropped_bad_api", "dropped_bad_gcs", "dropped_stale_hil", "dropped_jump_hil",
         "dropped_foreign_hil", "hil_ignored", "hil_bad_values", "unknown_msgs", "unhandled_msgs",
         "not_for_us", "unsigned_rejected", "badsig_rejected", "setpoints", "rejected_setpoints",
         "commands", "commands_unsupported", "param_sets", "param_rejected", "param_denied_armed",
         "drain_deferred", "handler_errors", "odometry_lost", "faults_injected", "inject_denied",
         "failsafe_imu", "failsafe_est_tilt", "failsafe_est_vel")


class Onboard:
    """The vehicle. `poll()` once per HIL datagram; see the module docstring for the contract.

    Attributes for the master and tests: `stats` (dict of counters), `mode` (int, see
    MODE_NAMES), `mode_name`, `armed`, `landed_state`, `state` (VehicleState), `setpoint`
    (the Setpoint in use), `u` (the last motor commands), `params` (ParamTable),
    `warnings` (parameter-file notes), `status` (the shared VehicleStatus record).
    """

    def __init__(self, config: OnboardConfig, hil, api, gcs, *, controller=None) -> None:
        self.cfg = cfg = config
        self._hil = hil
        self.vehicle: Airframe = get_airframe(cfg.vehicle)
        self.status = vs = VehicleStatus(stats=dict.fromkeys(STATS, 0))
        self.stats = vs.stats
        self._hil_mav = M.MAVLink(None, cfg.sysid, cfg.compid)
        chans: list[Chan] = []
        self.outbox = out = Outbox(vs, chans, cfg.signing_epoch_unix_s)
        # replay protection is per (link id, system, component) stream of the signing key
        # (MAVLink signing spec), across all links of the vehicle: one table for both, so a
        # packet captured on one link is old news on the other
        seen: dict[tuple[int, int, int], int] = {}
        for i, (name, link) in enumerate((("api", api), ("gcs", gcs))):
            ch = Chan(name, link, M.MAVLink(None, cfg.sysid, cfg.compid), self.stats)
            if cfg.signing_key is not None:
                sg = ch.mav.signing
                sg.stream_timestamps = seen
                sg.secret_key = bytes(cfg.signing_key)
                sg.sign_outgoing = True
                sg.allow_unsigned_callback = None
                sg.link_id = i
                sg.timestamp = out.signing_ts(0)
                ch.signed = True
            chans.append(ch)
        self._api, self._gcs = chans
        self._chans = chans

        # ---- the parts
        self.geo = wire.FlatEarth(cfg.origin_lat_deg, cfg.origin_lon_deg, cfg.origin_alt_m)
        self.origin = (0.0, 0.0)   # m, simulator NED of the local origin (set by the 1st ODOMETRY)
        self._blind_state = VehicleState()   # what the controller sees without an estimate
        self.commander = cmd = Commander(vs, out)
        self.navigator = nav = Navigator(vs, out, cmd, cfg.control_dt_s, self.geo)
        self.offboard = ofb = Offboard(vs, out, cmd, cfg.sysid, cfg.compid, self.geo)
        self.mission = mis = Mission(vs, out, cmd, nav, cfg.sysid, cfg.compid)
        self.manual = man = Manual(vs, cmd, nav, cfg.sysid)
        cmd.navigator, cmd.offboard, cmd.mission, cmd.manual = nav, ofb, mis, man
        self.parameters = prm = Parameters(vs, out, chans, lambda s, c: self.commands.for_us(s, c))
        self.failsafe = Failsafe(vs, out, cmd, prm.apply)
        self.telemetry = tel = Telemetry(vs, out, cmd, prm, self.geo, cfg.sysid,
                                         cfg.origin_alt_m, mis, self.vehicle.g)
        self.commands = Commands(vs, out, cmd, nav, tel, cfg.sysid, cfg.compid, mis)
        handlers = self.commands.handlers(ofb.on_setpoint_msg, prm, man)
        handlers[M.MAVLINK_MSG_ID_HEARTBEAT] = self.failsafe.on_heartbeat
        handlers.update(ofb.handlers())          # SET_POSITION_TARGET_GLOBAL_INT, attitude
        self.input = LinkInput(vs, out, handlers, ofb.on_setpoint)
        for ch, rates in zip(chans, (cfg.api_rates_hz, cfg.gcs_rates_hz), strict=True):
            for sname, msgid in STREAMS.items():
                st = Stream(msgid, hz_to_us(rates.get(sname, 0.0)), tel.stream_emitter(msgid))
                ch.streams.append(st)
                ch.by_msgid[msgid] = st

        # ---- controller, parameters, battery
        self._ctrl_factory = None
        if controller is None:
            from mav.control import make_controller

            self._ctrl_factory = make_controller
            controller = make_controller(self.vehicle, dt=cfg.control_dt_s)
        vs.ctrl = controller
        vs.battery = Battery(BATTERIES[cfg.vehicle], self.vehicle.u_hover)
        prm.build()
        prm.hover_fraction = self.vehicle.weight / (4.0 * self.vehicle.thrust_max)
        cmd.preflight = self._preflight
        vs.own["COM_OF_LOSS_T"] = cfg.offboard_loss_s
        vs.own["COM_FAIL_ACT_T"] = cfg.failsafe_land_s
        if cfg.param_file:
            prm.load_file(cfg.param_file)
        prm.apply()
        # the estimator (TPL_EST_TYPE 1: the vehicle flies on HIL_SENSOR & co., mav/estimator/):
        # between the HIL link and the tick, it turns sensor datagrams into ODOMETRY
        self.estimator = tel.estimator = Estimator(vs.own, self.stats, self.geo)
        self._decode_hil = wire.decode_odometry    # the tick's reader of a HIL datagram
        self._est_link = None
        if self.estimator.enabled:
            self._hil = self._est_link = self.estimator.link(self._hil, self._hil_mav)
            self._decode_hil = self._hil.decoded   # its estimate, not decoded again
        self._est_resets = 0          # the estimator's resets of a non-finite state, said
        # what a lost position keeps: the estimator's `lost` is its horizontal aiding (flow,
        # GPS), its altitude stays; an ODOMETRY feed's quality -1 (motion capture) loses all
        self._vertical_kept = self.estimator.enabled

    def _preflight(self) -> str | None:
        """Why arming must wait: a parameter outside its envelope, or the onboard estimator's
        attitude not aligned yet (its first CAL_TICKS readings at rest, as PX4 waits for
        EKF2's tilt alignment)."""
        why = self.parameters.arming_problem()
        if why is None and self.estimator.enabled:     # aligned, a plausible IMU at rest
            why = self.estimator.preflight()
        return why

    # ------------------------------------------------------------------ public helpers
    @property
    def mode(self) -> int:
        return self.status.mode

    @property
    def mode_name(self) -> str:
        return MODE_NAMES[self.status.mode]

    @property
    def armed(self) -> bool:
        return self.status.armed

    @property
    def landed_state(self) -> int:
        return self.status.landed_state

    @property
    def state(self):
        return self.status.state

    @property
    def setpoint(self):
        return self.status.setpoint

    @property
    def u(self) -> list[float]:
        return self.status.u

    @property
    def battery(self) -> Battery:
        return self.status.battery

    @property
    def params(self):
        return self.parameters.table

    @property
    def warnings(self) -> list[str]:
        return self.parameters.warnings

    @property
    def t(self) -> float:                  # the vehicle's clock, s
        return self.status.t_us * 1e-6

    @property
    def home(self) -> tuple[float, float, float] | None:
        return self.status.home

    def statustext(self, text: str, severity: int = M.MAV_SEVERITY_INFO) -> None:
        """Send a STATUSTEXT (<= 50 characters) on the api and gcs links."""
        self.outbox.statustext(text, severity)

    def set_airframe(self, vehicle: Airframe) -> None:
        """Use other airframe values (scenario overrides): rebuilds the controller, keeps
        parameters the user set."""
        vs = self.status
        self.vehicle = vehicle
        self.telemetry.g_mps2 = vehicle.g
        if self._ctrl_factory is not None:
            vs.ctrl = self._ctrl_factory(vehicle, dt=self.cfg.control_dt_s)
        vs.battery = Battery(vs.battery.p, vehicle.u_hover)
        self.parameters.hover_fraction = vehicle.weight / (4.0 * vehicle.thrust_max)
        self.parameters.rebuild_keeping_user_values()

    def rebooted(self) -> Onboard:
        """A fresh vehicle on the same links and configuration, as after a reboot (a crash's
        respawn): disarmed, on the ground, clock, origin and home from the next ODOMETRY.
        Kept, as a reboot keeps them: the airframe, the user's parameters, and the signing
        replay table (a packet captured before the reboot is still old news)."""
        ctrl = None if self._ctrl_factory is not None else self.status.ctrl
        if ctrl is not None:
            ctrl.reset()
        new = Onboard(self.cfg, self._hil, self._api.link, self._gcs.link, controller=ctrl)
        if new.vehicle != self.vehicle:
            new.set_airframe(self.vehicle)
        new.status.user_params.update(self.status.user_params)
        new.parameters.rebuild_keeping_user_values()
        seen = self._api.mav.signing.stream_timestamps
        for ch in new._chans:
            ch.mav.signing.stream_timestamps = seen
        return new

    def count_kernel_drops(self) -> dict[str, int]:
        """Set `stats['dropped_kernel_<link>']` for each UDP link (`mav.links.kernel_drops`:
        what the kernel dropped, its receive buffer full). It reads a /proc file, so not per
        tick: the SIL process calls it as it exits; again, it replaces them. Returns them."""
        got = kernel_drops({"hil": self._hil, "api": self._api.link, "gcs": self._gcs.link})
        self.stats.update(got)
        return got

    def load_params(self, path: str) -> None:
        """Apply a parameter file; unknown names are noted in `warnings`, bad values raise."""
        self.parameters.load_file(path)

    # ------------------------------------------------------------------ the tick
    @cython.locals(vs=VehicleStatus, u=list)
    def poll(self) -> bool:
        """Handle one waiting HIL datagram (see module docstring). False if none was waiting
        or it was not a usable ODOMETRY (then nothing else is touched)."""
        data = self._hil.recv()
        if data is None:
            return False
        vs = self.status
        vs.stats["rx_hil"] += 1
        try:   # (defensive: the decoder is total on bytes, but never crash here)
            od = self._decode_hil(data)
        except Exception:
            od = None
        if od is None:   # a battery fault from the simulator (inject.py), another message
            vs.stats[hil_other(vs, self._hil_mav, data, self.cfg.sysid, self.cfg.compid)] += 1
            return False
        # the estimator's ODOMETRY was checked as its sensor datagram (refused ones never get
        # here), and is the vehicle's own system's frame
        own = self._est_link is not None and self._est_link.made(data)
        if not self._tick(od, own, SIM_SYSID if own else data[5]):
            return False
        # HIL_ACTUATOR_CONTROLS (wire.encode_hil_actuator_controls)
        u = vs.u
        pl = wire.HIL_CTRL_PACK(vs.t_us, 1, u[0], u[1], u[2], u[3],
                                HIL_MODE_ARMED if vs.armed else HIL_MODE_DISARMED)
        self._hil.send(wire.frame(self._hil_mav, wire.HIL_ACTUATOR_CONTROLS, pl))
        return True

    @cython.locals(vs=VehicleStatus, u=list, est=Estimator)
    def step_record(self, rec) -> tuple | None:
        """MIL's typed exchange (cosim/sim/onboard.py): `poll` of what a HIL datagram's frames
        decode to (`mav.hil.odometry_record`'s tuple, or the sensor messages' list); the
        answer as its frames decode: ((t_us, u1..u4), `Estimator.record` or None), or None."""
        vs = self.status
        st = vs.stats
        own = type(rec) is list            # the sensor messages, else ODOMETRY's fields
        if own:   # counted as their frames: after the estimator's step and its ODOMETRY
            est = self.estimator
            od = est.record() if self._est_link is not None and est.estimate_parts(rec) else None
            st["rx_hil"] += 1
            if od is None:
                if not est.refused:        # no estimator, or no HIL_SENSOR: not ODOMETRY
                    st["dropped_bad_hil"] += 1
                return None
        else:     # (a vehicle with its estimator passes ODOMETRY through: motion capture)
            st["rx_hil"] += 1
            od = rec
        if not self._tick(od, own, SIM_SYSID):
            return None
        u = vs.u
        return (vs.t_us, f32(u[0]), f32(u[1]), f32(u[2]), f32(u[3])), (od if own else None)

    @cython.locals(vs=VehicleStatus, s=VehicleState, sp=Setpoint, t_us=cython.longlong,
                   dt_us=cython.longlong, x=cython.double, y=cython.double, z=cython.double,
                   qw=cython.double, qx=cython.double, qy=cython.double, qz=cython.double,
                   vx=cython.double, vy=cython.double, vz=cython.double, p=cython.double,
                   q=cython.double, r=cython.double, chk=cython.double, frame_id=cython.int,
                   child=cython.int, quality=cython.int, lost=cython.bint, u=list,
                   own=cython.bint, imu_ok=cython.bint)
    def _tick(self, od: tuple, own: bool, sysid: int) -> bool:
        """The tick on od (`wire.decode_odometry`'s fields) from system `sysid` (`own`: the
        estimator's), its motor commands in `status.u`; False if it is not the next tick or
        its values are unusable (counted; nothing else touched)."""
        vs = self.status
        st = vs.stats
        if not 0 <= od[0] < MAX_TIME_US:      # a clock beyond any flight: not a tick
            st["hil_bad_values"] += 1
            return False
        # the lockstep clock: the simulator's, later than the last tick by at most
        # HIL_MAX_STEP_US (mav/hil.py)
        why = tick_refusal(sysid, od[0], vs.t_us if vs.have_state else -1)
        if why is not None:
            st[why] += 1
            return False
        (t_us, x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r, frame_id, child, quality) = od
        chk = x + y + z + qw + qx + qy + qz + vx + vy + vz + p + q + r
        if chk - chk != 0.0 or frame_id != FRAME_LOCAL_NED or (
                child != FRAME_LOCAL_NED and child != FRAME_BODY_FRD):
            st["hil_bad_values"] += 1
            return False
        if not vs.have_state:
            vs.t_us = t_us
            # the local frame's origin: where the estimator initialised (PX4), i.e. the
            # vehicle's first position; every position it handles is relative to it
            self.origin = (x, y)
        # 1. the offboard and GCS links, at the clock of the previous tick
        api, gcs = self._api, self._gcs
        data = api.link.recv()
        if data is not None:
            self.input.drain(api, data)
        data = gcs.link.recv()
        if data is not None:
            self.input.drain(gcs, data)
        # 2. clock and estimator (ground truth from ODOMETRY)
        dt_us = t_us - vs.t_us
        vs.t_us = t_us
        s = vs.state
        s.t = t_us * 1e-6
        vs.v_prev = (s.vx, s.vy, s.vz)     # for HIGHRES_IMU's mean acceleration over the tick
        vs.dt_us = dt_us
        s.qw, s.qx, s.qy, s.qz = qw, qx, qy, qz
        s.p, s.q, s.r = p, q, r
        lost = quality < 0 and vs.have_state    # ODOMETRY.quality -1: the estimate failed
        if not lost:
            ox, oy = self.origin
            s.x, s.y, s.z = x - ox, y - oy, z
            if child == FRAME_LOCAL_NED:
                s.vx, s.vy, s.vz = vx, vy, vz
            else:   # body FRD velocity -> world NED
                s.vx, s.vy, s.vz = rotate_body_to_world(qw, qx, qy, qz, vx, vy, vz)
            if vs.pos_lost_us >= 0:
                self.failsafe.position_regained()
        else:
            if vs.pos_lost_us < 0:
                self.failsafe.position_lost(t_us)
            if self._vertical_kept:   # the onboard estimator lost its horizontal aiding only:
                s.z, s.vz = z, vz     # the altitude (sonar, baro) stays, as PX4's altitude mode
        if not vs.have_state:
            vs.have_state = True
            self.commander.set_home()
            self.commander.hold_here()
        # 3. modes, failsafes, ground detection, controller: on an estimate that moved on
        # (the onboard estimator's with a usable IMU reading this tick; failsafe.IMU_FAIL_US)
        fs, impl = self.failsafe, self.estimator.impl
        imu_ok = not own or impl.imu_us == t_us
        if own and impl.resets != self._est_resets:   # (no reading may do it)
            self._est_resets = impl.resets
            self.outbox.statustext("Estimator reset: its state was not finite",
                                   M.MAV_SEVERITY_CRITICAL)
        if imu_ok:
            if fs.blind_us >= 0 or fs.est_fail != impl.fail:
                fs.imu_ok(impl)
            self._step_modes(t_us)
        else:
            fs.imu_missing(t_us, impl, self.vehicle)
        u = vs.u
        if vs.armed:
            if fs.blind_us >= 0:
                u[0] = u[1] = u[2] = u[3] = fs.u_blind
            elif vs.landed_state == ON_GROUND and self.commander.motors_idle():
                idle = vs.own["TPL_IDLE_RATIO"] * self.vehicle.u_hover
                u[0] = u[1] = u[2] = u[3] = idle
            elif imu_ok:
                sp = vs.setpoint
                sp.armed = True
                vs.ctrl.update(self._blind(s, sp) if lost else s, sp, u)
            else:       # the collective thrust held, no torque: no attitude to correct
                u[0] = u[1] = u[2] = u[3] = 0.25 * (u[0] + u[1] + u[2] + u[3])
        else:
            u[0] = u[1] = u[2] = u[3] = 0.0
        if dt_us > 0:
            vs.battery.step(dt_us * 1e-6, u[0], u[1], u[2], u[3])
        # 4. telemetry when due (Telemetry.publish's own first test, here: most ticks have
        # nothing due), then the HIL answer
        if (t_us >= api.next_due or t_us >= gcs.next_due or api.param_queue or gcs.param_queue
                or vs.hb_now or vs.ext_now or vs.home_now or vs.mission_now):
            self.telemetry.publish(t_us)
        st["ticks"] += 1
        return True

    def _blind(self, s, sp):
        """Without a position estimate the controller sees the attitude and rates and no
        horizontal error: it holds level and heading, drifting (drag brakes it). The altitude
        is held on the estimator's (sonar, baro: PX4's altitude mode); a lost ODOMETRY feed
        gives no vertical error either (hover thrust)."""
        b = self._blind_state
        b.t, b.qw, b.qx, b.qy, b.qz, b.p, b.q, b.r = s.t, s.qw, s.qx, s.qy, s.qz, s.p, s.q, s.r
        b.x = sp.x if sp.x == sp.x else s.x
        b.y = sp.y if sp.y == sp.y else s.y
        if self._vertical_kept:       # altitude still estimated: held to the setpoint
            b.z, b.vz = s.z, s.vz
        else:
            b.z = sp.z if sp.z == sp.z else s.z
            b.vz = sp.vz if sp.vz == sp.vz else 0.0
        b.vx = sp.vx if sp.vx == sp.vx else 0.0
        b.vy = sp.vy if sp.vy == sp.vy else 0.0
        return b

    @cython.locals(vs=VehicleStatus, t=cython.longlong, mode=cython.int, armed=cython.bint)
    def _step_modes(self, t: int) -> None:
        """The modes' work for this tick, failsafes first (in PX4's order of precedence)."""
        vs = self.status
        mode = vs.mode
        if mode == OFFBOARD:
            if t - vs.of_last_us > vs.of_loss_us:
                self.failsafe.offboard_lost(t)
                mode = LOITER
            elif self.offboard.moveby.active:     # a relative move (frame 9) in flight
                self.offboard.moveby.step(vs.dt_us * 1e-6, vs.of)
        elif mode == TAKEOFF:
            if vs.armed:
                self.navigator.step_takeoff(t)
        elif mode == LAND:
            if vs.armed:
                self.navigator.step_land(t)
        elif vs.armed:
            if mode == LOITER:
                self.navigator.step_loiter(t)
            elif mode == POSCTL:
                self.manual.step(t)
            elif mode == RTL:
                self.navigator.step_rtl(t)
            elif mode == MISSION:
                self.mission.step(t)
        # each check below is called only when its own early return would not apply (the
        # same tick either way, without a call per idle check)
        if self.mission.up is not None:               # an upload in progress
            self.mission.tick(t)
        fs = self.failsafe
        if vs.gcs_last_us >= 0 and not vs.gcs_lost:
            fs.check_gcs(t)
        armed = vs.armed
        own = vs.own
        if (armed and vs.landed_state != ON_GROUND and vs.home is not None
                and (own["GF_MAX_HOR_DIST"] > 0.0 or own["GF_MAX_VER_DIST"] > 0.0)):
            fs.check_geofence()
        if vs.pos_lost_us >= 0:
            fs.check_position(t)
        if vs.fs_active and mode == LOITER and t - vs.fs_t0 > vs.fail_act_us:
            self.failsafe.hold_expired()
        if armed and (vs.landed_state == ON_GROUND or vs.ground_since >= 0):
            self.navigator.detect_air_and_ground(t)
        b = vs.battery
        if b.consumed_mah + b.lost_mah > vs.bat_warn_mah:   # Battery.used_mah: drawn + lost
            self.failsafe.battery_warning()
