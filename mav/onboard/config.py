"""What the vehicle is built from (the process's command line fills it in)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from mav.airframe import get_airframe
from mav.onboard.defs import API_RATES_HZ, GCS_RATES_HZ, SIGNING_EPOCH_2024, STREAMS, M


@dataclass
class OnboardConfig:
    """Everything the vehicle is built from. Times in s, rates in Hz, angles in deg."""

    vehicle: str = "mambo"                 # 'mambo' | 'bebop2'
    sysid: int = 1                         # MAVLink system id of the vehicle
    compid: int = M.MAV_COMP_ID_AUTOPILOT1
    origin_lat_deg: float = 42.299886      # geodetic origin of the local NED frame
    origin_lon_deg: float = -71.350447
    origin_alt_m: float = 71.3232          # m AMSL
    api_rates_hz: dict[str, float] = field(default_factory=lambda: dict(API_RATES_HZ))
    gcs_rates_hz: dict[str, float] = field(default_factory=lambda: dict(GCS_RATES_HZ))
    offboard_loss_s: float = 1.0           # COM_OF_LOSS_T default
    failsafe_land_s: float = 5.0           # COM_FAIL_ACT_T default: hold this long, then land
    signing_key: bytes | None = None       # 32 bytes: sign api/gcs and reject unsigned input
    signing_epoch_unix_s: float = SIGNING_EPOCH_2024   # signing timestamp at vehicle time 0
    param_file: str | None = None          # NAME VALUE lines (QGC .params tolerated)
    control_dt_s: float = 0.005            # s, controller period (= HIL tick)

    def __post_init__(self) -> None:
        get_airframe(self.vehicle)          # ValueError naming the choices
        if not 1 <= self.sysid <= 255:
            raise ValueError(f"sysid: got {self.sysid}; allowed 1..255")
        if not 1 <= self.compid <= 255:
            raise ValueError(f"compid: got {self.compid}; allowed 1..255")
        if self.signing_key is not None and len(self.signing_key) != 32:
            raise ValueError(f"signing_key: got {len(self.signing_key)} bytes; need 32")
        for name, lim in (("origin_lat_deg", 90.0), ("origin_lon_deg", 180.0),
                          ("origin_alt_m", 1e5)):
            v = getattr(self, name)
            if not (math.isfinite(v) and -lim <= v <= lim):
                raise ValueError(f"{name}: got {v!r}; allowed: finite, in [-{lim:g}, {lim:g}]")
        for which in ("api_rates_hz", "gcs_rates_hz"):
            for name, hz in getattr(self, which).items():
                if name not in STREAMS:
                    raise ValueError(f"{which}.{name}: unknown stream; known: "
                                     f"{', '.join(STREAMS)}")
                if not (math.isfinite(hz) and hz >= 0.0):
                    raise ValueError(f"{which}.{name}: got {hz!r}; need a rate >= 0 Hz")
        for name in ("offboard_loss_s", "failsafe_land_s", "control_dt_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{name}: got {v!r}; need a time > 0 s")
