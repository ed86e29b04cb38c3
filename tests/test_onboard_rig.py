"""A MIL test rig for the onboard vehicle (imported by the other test_onboard_* files).

`Rig` puts an `Onboard` on three MemoryLink pairs and plays the other ends: the simulator
(ODOMETRY out, checks every HIL_ACTUATOR_CONTROLS answer), an app on the API link and a ground
station on the GCS link, decoding everything the vehicle sends with pymavlink. The state fed
to the vehicle is either fixed (`rig.odo`, for protocol tests) or a `cosim.plant.Plant`.
"""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2

from mav import wire
from mav.links import MemoryLink
from mav.onboard import Onboard, OnboardConfig

M = mavlink2
TICK_US = 5000
GCS_SYSID, GCS_COMPID = 255, 190
APP_SYSID, APP_COMPID = 1, 191


class Rig:
    def __init__(self, *, plant: bool = False, vehicle: str = "mambo", controller=None,
                 app_key: bytes | None = None, gcs_key: bytes | None = None,
                 decode: bool = True, client: bool = False, **cfg) -> None:
        self.hil, hil_v = MemoryLink.pair()
        self.api_link, api_v = MemoryLink.pair()
        self.gcs_link, gcs_v = MemoryLink.pair()
        self.cfg = OnboardConfig(vehicle=vehicle, **cfg)
        self.ob = Onboard(self.cfg, hil_v, api_v, gcs_v, controller=controller)
        self.sim = M.MAVLink(None, 250, M.MAV_COMP_ID_SYSTEM_CONTROL)
        self.mavs = {"api": M.MAVLink(None, APP_SYSID, APP_COMPID),
                     "gcs": M.MAVLink(None, GCS_SYSID, GCS_COMPID)}
        for name, key in (("api", app_key), ("gcs", gcs_key)):
            if key is not None:
                sg = self.mavs[name].signing
                sg.secret_key, sg.sign_outgoing, sg.link_id = key, True, 7
                sg.timestamp = 283996800 * 100000 + 1     # 2024-01-01, like the vehicle
        self.links = {"api": self.api_link, "gcs": self.gcs_link}
        self.client = None
        if client:                  # an OffboardClient owns the app's end of the API link
            from mav.client import OffboardClient

            self.client = OffboardClient(self.api_link, signing_key=app_key)
        self.k = 0
        # x, y, z, qw, qx, qy, qz, vx, vy, vz, p, q, r: at rest on the floor, heading north
        self.odo = [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        self.decode = decode
        self.rx: dict[str, list] = {"api": [], "gcs": []}
        self.raw: dict[str, list[bytes]] = {"api": [], "gcs": []}
        self.u = (0.0, 0.0, 0.0, 0.0)
        self.answers: list[tuple] = []
        self.plant = None
        if plant:
            from cosim.plant.fmu import Plant
            from cosim.scenario.vehicles import get_vehicle

            self.plant = Plant(get_vehicle(vehicle))

    @property
    def t_us(self) -> int:
        return self.k * TICK_US

    @property
    def t(self) -> float:
        return self.k * TICK_US * 1e-6

    def run_until(self, cond, timeout_s: float, each=None) -> float:
        """Tick until cond(rig) is true; returns the time it took (s); fails on timeout."""
        t0 = self.k
        limit = self.k + round(timeout_s * 200)
        while not cond(self):
            assert self.k < limit, f"not reached within {timeout_s} s (t = {self.t:.2f} s)"
            self.tick(1, each)
        return (self.k - t0) * TICK_US * 1e-6

    def set_yaw(self, yaw: float) -> None:
        self.odo[3:7] = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]

    def tick(self, n: int = 1, each=None) -> None:
        """n lockstep ticks; `each(rig)` runs before each HIL exchange (the app's tick, after
        `client.poll(t)` when the rig has a client)."""
        for _ in range(n):
            if self.client is not None:
                self.client.poll(self.k * TICK_US * 1e-6)
            if each is not None:
                each(self)
            if self.plant is not None:
                from cosim.plant.fmu import Y_P, Y_QW, Y_VX, Y_X

                y = self.plant.y
                o = (y[Y_X:Y_X + 3] + y[Y_QW:Y_QW + 4] + y[Y_VX:Y_VX + 3] + y[Y_P:Y_P + 3])
            else:
                o = self.odo
            t_us = self.t_us
            self.hil.send(wire.encode_odometry(self.sim, t_us, *o))
            assert self.ob.poll() is True
            ans = self.hil.recv()
            assert ans is not None and self.hil.recv() is None, "exactly one answer per tick"
            f = wire.decode_fast(wire.HIL_ACTUATOR_CONTROLS, ans)
            assert f is not None and f[0] == t_us
            self.u = f[2:6]
            self.answers.append(f)
            self._collect()
            if self.plant is not None:
                self.plant.step(*self.u)
            self.k += 1

    def _collect(self) -> None:
        for name, link in self.links.items():
            if name == "api" and self.client is not None:
                continue
            while (d := link.recv()) is not None:
                self.raw[name].append(d)
                if self.decode:
                    msg = self.mavs[name].decode(bytearray(d))
                    self.rx[name].append((self.t_us, msg))

    # ---- sending as the app / GCS
    def send(self, link: str, msg) -> bytes:
        data = wire.send_msg(self.mavs[link], msg)
        self.links[link].send(data)
        return data

    def send_raw(self, link: str, data: bytes) -> None:
        self.links[link].send(data)

    def cmd(self, command: int, *params: float, link: str = "gcs", target: int = 1) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(link, M.MAVLink_command_long_message(target, 1, command, 0, *p))

    def cmd_int(self, command: int, frame: int, p1=0.0, p2=0.0, p3=0.0, p4=0.0, x=0, y=0,
                z=0.0, link: str = "gcs") -> None:
        self.send(link, M.MAVLink_command_int_message(1, 1, frame, command, 0, 0, p1, p2, p3,
                                                      p4, x, y, z))

    def setpoint(self, mask: int, x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0,
                 yaw_rate=0.0, frame: int = M.MAV_FRAME_LOCAL_NED, target: int = 1,
                 link: str = "api") -> None:
        self.links[link].send(wire.encode_set_position_target_local_ned(
            self.mavs[link], self.k * 5, target, 1, frame, mask, x, y, z, vx, vy, vz, 0.0, 0.0,
            0.0, yaw, yaw_rate))

    def set_mode(self, main: int, sub: int = 0, link: str = "gcs") -> None:
        self.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, link=link)

    # ---- reading what the vehicle sent
    def msgs(self, link: str, mtype: str, since_us: int = -1) -> list:
        return [m for t, m in self.rx[link] if m.get_type() == mtype and t >= since_us]

    def last(self, link: str, mtype: str):
        ms = self.msgs(link, mtype)
        return ms[-1] if ms else None

    def ack(self, command: int, link: str = "gcs") -> int | None:
        acks = [m for m in self.msgs(link, "COMMAND_ACK") if m.command == command]
        return acks[-1].result if acks else None

    def texts(self, link: str = "gcs") -> list[str]:
        out: list[str] = []
        last_id = 0
        for m in self.msgs(link, "STATUSTEXT"):   # chunked texts (id != 0) joined
            if m.id and m.id == last_id and m.chunk_seq > 0:
                out[-1] += m.text
            else:
                out.append(m.text)
            last_id = m.id
        return out

    def clear(self) -> None:
        self.rx = {"api": [], "gcs": []}
        self.raw = {"api": [], "gcs": []}


def test_rig_ticks_and_answers():
    rig = Rig()
    assert rig.ob.poll() is False          # nothing waiting: nothing happens
    rig.tick(3)
    assert [a[0] for a in rig.answers] == [0, 5000, 10000]
    assert rig.ob.stats["ticks"] == 3
    assert rig.last("gcs", "HEARTBEAT") is not None


class UdpSim:
    """The simulator end of a SIL vehicle: ODOMETRY over UDP to the onboard process's HIL
    port, blocking for each HIL_ACTUATOR_CONTROLS answer (lockstep), stepping a Plant or
    feeding a fixed state."""

    def __init__(self, hil_port: int, *, vehicle: str = "mambo", plant: bool = True,
                 timeout_s: float = 3.0) -> None:
        import socket

        from mav.hil import HilSimulatorCodec

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(timeout_s)
        self.remote = ("127.0.0.1", hil_port)
        self.codec = HilSimulatorCodec()
        self.k = 0
        self.odo = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        self.u = (0.0, 0.0, 0.0, 0.0)
        self.plant = None
        if plant:
            from cosim.plant.fmu import Plant
            from cosim.scenario.vehicles import get_vehicle

            self.plant = Plant(get_vehicle(vehicle))

    @property
    def t(self) -> float:
        return self.k * TICK_US * 1e-6

    @property
    def pos(self) -> tuple[float, float, float]:
        if self.plant is None:
            return tuple(self.odo[:3])
        return tuple(self.plant.y[:3])

    def tick(self) -> None:
        from cosim.plant.fmu import Y_P, Y_QW, Y_VX, Y_X

        if self.plant is not None:
            y = self.plant.y
            m = tuple(y[Y_X:Y_X + 3] + y[Y_QW:Y_QW + 4] + y[Y_VX:Y_VX + 3] + y[Y_P:Y_P + 3])
        else:
            m = self.odo
        t_us = self.k * TICK_US
        self.sock.sendto(self.codec.encode_odometry(t_us, m), self.remote)
        t_ans, *u = self.codec.decode_actuators(self.sock.recv(65535))
        assert t_ans == t_us
        self.u = tuple(u)
        if self.plant is not None:
            self.plant.step(*u)
        self.k += 1

    def close(self) -> None:
        self.sock.close()
        if self.plant is not None:
            self.plant.close()
