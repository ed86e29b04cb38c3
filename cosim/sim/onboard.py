"""The onboard flight stack seen from the master: in this process (MIL) or as its own OS
process (SIL), behind one interface: `exchange` one HIL datagram for the answer (MIL:
`exchange_record`, the same without the frames), the API and
GCS links (tapped into the run's tlog), `stats`, `close`; for `cosim sitl`, `respawn`."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

from cosim import tempdirs
from cosim.errors import ComponentError
from cosim.outputs.tlog import Tlog, tap
from cosim.scenario.records import Scenario
from cosim.scenario.vehicles import get_vehicle
from cosim.sim.options import RunOptions
from mav.links import SpinPolicy, UdpLink, UnixLink, memory_link, memory_pair


class OnboardHandle:
    """The onboard stack seen from the master: MIL in-process or SIL subprocess."""

    def __init__(self, sc: Scenario, opts: RunOptions, tlog: Tlog, log_dir: Path,
                 hooks=None, *, sysid: int = 1,
                 origin: tuple[float, float, float] | None = None) -> None:
        """`hooks`: fault injection on the links (cosim.sim.hooks); `sysid`: the vehicle's
        MAVLink system id; `origin`: the geodetic origin of its local frame (lat deg, lon deg,
        alt m AMSL; None: the flight stack's default)."""
        self.mode = opts.mode
        if opts.hil_exchange not in ("auto", "typed", "framed"):
            raise ValueError(f"hil_exchange: 'auto', 'typed' or 'framed', not "
                             f"{opts.hil_exchange!r}")
        if opts.hil_exchange == "typed" and (opts.mode != "mil" or hooks is not None):
            raise ValueError("hil_exchange 'typed' is MIL's, without fault hooks (they act "
                             "on the HIL datagrams): use 'framed' or 'auto'")
        # the typed exchange (`exchange_record`) or datagrams (`exchange`)
        self.typed = opts.mode == "mil" and hooks is None and opts.hil_exchange != "framed"
        self.proc = None
        self._own: tuple = ()
        self.bound: dict[str, tuple[str, int]] = {}   # external links: their local addresses
        self._sock_dir = None     # SIL over a Unix-domain HIL link: the sockets' folder
        self._stats0: dict[str, int] = {}             # counters of the stacks before a respawn
        vname = sc.vehicle.name
        if opts.mode == "mil":
            from mav.onboard import Onboard, OnboardConfig

            hil_m, hil_v = memory_pair()
            if opts.external_links:
                api_app = gcs_m = memory_link()  # nothing of the master's on these links
                udp = []
                try:
                    for name in ("api", "gcs"):
                        udp.append(UdpLink(*opts.external_links[name]))
                except OSError as exc:
                    for link in udp:
                        link.close()
                    raise ComponentError("onboard", f"cannot bind the API/GCS links: {exc}"
                                         ) from None
                self.bound = {"api": udp[0].local_address, "gcs": udp[1].local_address}
                # the outside clients' traffic goes straight to the vehicle: tapped there
                api_v, gcs_v = tap(udp[0], tlog), tap(udp[1], tlog)
            else:
                api_app, api_v = memory_pair()
                gcs_m, gcs_v = memory_pair()
            geo = {} if origin is None else dict(
                zip(("origin_lat_deg", "origin_lon_deg", "origin_alt_m"), origin, strict=True))
            self.onboard = Onboard(OnboardConfig(vehicle=vname, sysid=sysid,
                                                 signing_key=opts.signing_key,
                                                 param_file=_param_file(sc, log_dir), **geo),
                                   hil_v, api_v, gcs_v)
            if opts.external_links:
                self._own = (api_v, gcs_v)
            if sc.vehicle != get_vehicle(vname):   # the flight stack flies the changed plant
                self.onboard.set_airframe(sc.vehicle.airframe())
            self.hil = hil_m
            self._hil_v = hil_v                  # the vehicle's end: datagrams still queued
            self.api = tap(api_app, tlog)
            self.gcs = tap(gcs_m, tlog)
        else:
            try:
                self._start_sil(sc, opts, tlog, log_dir, sysid, origin)
            except BaseException:
                self.close_partial()
                raise
        if hooks is not None:  # faults between the app / GCS and the vehicle, and on HIL
            self.api.inner = hooks.wrap_link("api", self.api.inner)    # (battery faults)
            self.gcs.inner = hooks.wrap_link("gcs", self.gcs.inner)
            self.hil = hooks.wrap_link("hil", self.hil)

    def close_partial(self) -> None:
        """After a failed SIL start: close what was opened (process, sockets)."""
        for link in self._own:
            link.close()
        if self.proc is not None:
            self.proc.close()
        if self._sock_dir is not None:
            self._sock_dir.cleanup()

    def _start_sil(self, sc: Scenario, opts: RunOptions, tlog: Tlog, log_dir: Path,
                   sysid: int, origin: tuple[float, float, float] | None) -> None:
        from cosim.sim.sil import OnboardProcess

        vname = sc.vehicle.name
        if opts.hil_transport == "unix":
            # short paths in a private folder (a socket path has ~100 bytes at most)
            self._sock_dir = tempdirs.folder("hil")
            vehicle_sock = os.path.join(self._sock_dir.name, "vehicle")
            hil = UnixLink(os.path.join(self._sock_dir.name, "sim"), remote=vehicle_sock)
        else:
            hil = UdpLink(("127.0.0.1", 0))
        api = UdpLink(("127.0.0.1", 0))
        gcs = UdpLink(("127.0.0.1", 0))
        self._own = (hil, api, gcs)
        preset = get_vehicle(vname)
        overrides = tuple(  # scenario vehicle.overrides, passed to the process
            f"--vehicle-param={k}={v!r}" for k, v in sc.vehicle.fmu_parameters().items()
            if getattr(preset, k) != v
        )
        if opts.signing_key is not None:
            overrides += (f"--signing-key={opts.signing_key.hex()}",)
        params = _param_file(sc, log_dir)
        if params is not None:
            overrides += (f"--params={params}",)
        if sysid != 1:
            overrides += (f"--sysid={sysid}",)
        if opts.hil_transport == "unix":
            overrides += (f"--hil-unix={vehicle_sock}",)
        if origin is not None:
            overrides += ("--origin=" + ",".join(repr(float(v)) for v in origin),)
        spin_us = opts.hil_spin_us
        if spin_us is None:
            spin_us = 200.0 if (os.cpu_count() or 1) >= 2 and not opts.realtime else 0.0
        if spin_us > 0:
            overrides += (f"--hil-spin-us={spin_us!r}",)
        self.proc = OnboardProcess(
            vname, api.local_address, gcs.local_address, log_dir / "onboard.log",
            hil_timeout_s=max(10.0, 5 * opts.hil_timeout_s), extra_args=overrides,
        )
        ports = self.proc.ports
        for link, name in ((hil, "hil"), (api, "api"), (gcs, "gcs")):
            if ports[name]:           # UDP; a Unix-domain HIL link already has its peer
                link.remote = ("127.0.0.1", ports[name])
            link._fixed_remote = True
        self._spin = SpinPolicy(round(1000 * spin_us))
        self._hil_timeout_s = opts.hil_timeout_s
        self.hil = hil
        self.api = tap(api, tlog)
        self.gcs = tap(gcs, tlog)
        self._own = ()

    def exchange(self, data: bytes) -> bytes:
        """Send one HIL datagram (a tick's ODOMETRY, after the fault commands a `hil` hook
        sends first) and return the answer."""
        self.hil.send(data)
        if self.proc is None:
            try:   # one poll per datagram, as the SIL process polls once per readable event
                poll, queued = self.onboard.poll, self._hil_v.pending
                while not poll() and queued():
                    pass
            except Exception as exc:  # the onboard stack is a separate part: name it
                raise ComponentError("onboard", f"{type(exc).__name__}: {exc}") from exc
            ans = self.hil.recv()
            if ans is None:
                raise ComponentError("onboard", "no HIL_ACTUATOR_CONTROLS answer")
            return ans
        try:
            spin = self._spin
            if spin.spin_ns:
                t0 = time.perf_counter_ns()
                ans = self.hil.recv_spin(spin.ns, self._hil_timeout_s)
                spin.record(time.perf_counter_ns() - t0 <= spin.ns)
            else:
                ans = self.hil.recv_spin(0, self._hil_timeout_s)
        except OSError:
            ans = None
        if ans is None:
            what = self.proc.failure_text()
            raise ComponentError("onboard", f"stopped answering HIL ({what})")
        return ans

    def exchange_record(self, rec):
        """MIL's typed exchange (`typed`): `exchange` of the record the datagram's frames
        decode to (`Onboard.step_record`: the simulator's ODOMETRY fields or sensor messages,
        not framed), the answer as the record its frames decode to."""
        try:
            ans = self.onboard.step_record(rec)
        except Exception as exc:  # the onboard stack is a separate part: name it
            raise ComponentError("onboard", f"{type(exc).__name__}: {exc}") from exc
        if ans is None:
            raise ComponentError("onboard", "no HIL_ACTUATOR_CONTROLS answer")
        return ans

    def respawn(self) -> None:
        """MIL: the flight stack rebooted on the same links and sysid (`Onboard.rebooted`):
        disarmed, on the ground, home and local origin from the next ODOMETRY."""
        if self.proc is not None:
            raise RuntimeError("respawn: the onboard stack runs in this process only (MIL)")
        for k, v in self.onboard.stats.items():
            self._stats0[k] = self._stats0.get(k, 0) + v
        self.onboard = self.onboard.rebooted()

    def stats(self) -> dict[str, Any]:
        """The onboard stack's counters (SIL: as the process reported them at exit)."""
        if self.proc is None:
            st = dict(self._stats0)
            for k, v in getattr(self.onboard, "stats", {}).items():
                st[k] = st.get(k, 0) + v
            return st
        return dict(self.proc.stats)

    def close(self) -> None:
        if self.proc is None and self._own:   # cosim sitl's UDP links, in this process:
            self.onboard.count_kernel_drops()  # what their full buffers shed (SIL: at exit)
        for link in (self.hil, self.api, self.gcs, *self._own):
            try:
                link.close()
            except Exception:
                pass
        if self.proc is not None:
            self.proc.close()
        if self._sock_dir is not None:
            self._sock_dir.cleanup()


def _param_file(sc: Scenario, log_dir: Path) -> str | None:
    """The scenario's `[onboard.params]` as a parameter file in the run's log folder (both
    modes read it the same way: OnboardConfig.param_file / --params), or None."""
    if not sc.onboard_params:
        return None
    from mav.params import write_param_file

    path = Path(log_dir) / "onboard.params"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_param_file(path, sc.onboard_params)
    return str(path)
