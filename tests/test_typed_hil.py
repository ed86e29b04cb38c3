"""MIL's typed HIL exchange (cosim/sim/onboard.py `exchange_record`, RunOptions.hil_exchange)
against the framed one: the master and the vehicle hand each other the records the MAVLink
frames decode to, and a flight must be the same bit for bit as with the frames. Each flight is
a real `cosim run` process; the recorded series, the MAVLink log (the api and gcs links), the
estimate and the summary (the onboard counters included) less its wall-clock fields must be
equal. Plus the option's refusals, and the record's rounding against the frame's bytes."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from cosim.errors import ComponentError
from cosim.plant.fmu import OUTPUT_NAMES, Y_AX, Y_ON_GROUND, Y_QW, Y_VZ, Y_Z
from cosim.sim.exits import ExitMonitor
from mav import wire
from mav.fields import f32
from mav.hil import SIM_SYSID, HilSimulatorCodec, odometry_record

ROOT = Path(__file__).resolve().parent.parent
SC = ROOT / "scenarios"
WALL = ("wall_time_s", "real_time_factor", "realtime_stalls", "realtime_lost_s")


def cosim(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosim.cli", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, check=False)


def fly(tmp: Path, scenario: str, exchange: str, *extra: str) -> tuple[Path, dict]:
    out = tmp / exchange
    p = cosim("run", str(SC / scenario), "--out", str(out), "--hil-exchange", exchange,
              "--quiet", *extra)
    assert p.returncode in (0, 1), p.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text())


@pytest.mark.flight
@pytest.mark.parametrize("extra", [
    (),
    ("--set", "sensors.feed=truth"),
    ("--set", "sensors.feed=truth", "--set", "onboard.params.TPL_EST_TYPE=1"),
], ids=["sensor-fed", "truth-fed", "truth-fed-estimator-on"])
def test_typed_and_framed_fly_bit_for_bit(tmp_path, extra):
    """The seed mission on the sensors and the onboard estimator (the default: the records are
    the sensor messages and the estimate), truth-fed (ODOMETRY's fields), and truth-fed to a
    vehicle whose estimator is on (it passes ODOMETRY through, as motion capture)."""
    a, sa = fly(tmp_path, "mambo_seed_track.toml", "framed", *extra)
    b, sb = fly(tmp_path, "mambo_seed_track.toml", "typed", *extra)
    names = sorted(p.name for p in a.iterdir() if p.suffix in (".csv", ".tlog"))
    assert "flight.tlog" in names and "timeseries.csv" in names
    if not extra:   # the estimate the vehicle answered with, logged beside the truth
        assert "est_roll" in (a / "timeseries.csv").read_text().splitlines()[0]
    for name in names:
        x, y = (a / name).read_bytes(), (b / name).read_bytes()
        assert len(x) > 1000 and x == y, name
    for s in (sa, sb):
        for k in WALL:
            s.pop(k, None)
    assert sa == sb
    st = sa["onboard_stats"]
    assert st["ticks"] == st["rx_hil"] == sa["ticks"] > 10_000
    if "onboard.params.TPL_EST_TYPE=1" in extra:   # its estimator never aligns on ODOMETRY
        assert sa["exit_reason"] == "time_limit" and st["est_imu"] == 0   # alone: not armed
    else:
        assert sa["exit_reason"] == "mission_complete", sa["exit_reason"]


def test_typed_is_refused_where_it_cannot_apply(tmp_path):
    p = cosim("run", str(SC / "mambo_seed_track.toml"), "--mode", "sil", "--hil-exchange",
              "typed", "--out", str(tmp_path / "a"))
    assert p.returncode == 2 and "--hil-exchange" in p.stderr, p.stderr
    p = cosim("run", str(SC / "mambo_seed_dropout.toml"), "--hil-exchange", "typed",
              "--out", str(tmp_path / "b"))
    assert p.returncode == 2 and "[faults]" in p.stderr, p.stderr


@pytest.mark.parametrize("v", [0.0, -0.0, 1.0 / 3.0, 1e-45, 3.4028234663852886e38, -2.5e-39,
                               math.inf, -math.inf, 123456.789])
def test_f32_is_the_frames_rounding(v):
    """f32 gives what a MAVLink 'f' field carries (struct's packing, the frames')."""
    import struct

    got = f32(v)
    want = struct.unpack("<f", struct.pack("<f", v))[0]
    assert got == want and math.copysign(1, got) == math.copysign(1, want)


def test_f32_nan_and_overflow():
    assert math.isnan(f32(math.nan))
    with pytest.raises(OverflowError):
        f32(1e39)


def test_odometry_record_is_the_frames_fields():
    """odometry_record gives what wire.decode_odometry reads from the frame of the same values
    (the simulator's truth and the estimator's estimate, lost or not)."""
    codec = HilSimulatorCodec()
    m = (1.1, -2.2, -0.7, 0.9, 0.1, -0.2, 0.3, 0.25, -1.5, 0.05, 0.01, -0.02, 3.3)
    for lost in (False, True):
        frame = (codec.encode_odometry_lost if lost else codec.encode_odometry)(123_456, m)
        rec = (codec.record_odometry_lost if lost else codec.record_odometry)(123_456, m)
        assert rec == wire.decode_odometry(frame)
        assert rec == odometry_record(123_456, *m, lost)
    assert frame[5] == SIM_SYSID


@pytest.mark.parametrize("i", range(len(OUTPUT_NAMES)))
def test_a_non_finite_position_or_velocity_ends_the_run_before_anything_reads_it(i):
    """A position or velocity that is not finite is the plant's failure at the exit check,
    which runs on the state before the sensors or the vehicle read it: the framed exchange's
    integer fields (position, velocity) would refuse it, the typed records carry it, so
    without the check a typed run flew on where the framed one stopped. Other outputs may be
    NaN (a plant mapped from another FMU leaves those it lacks NaN: rotor speeds,
    accelerations) and the run goes on."""
    mon = ExitMonitor((-3.0, 3.0, -3.0, 3.0), 0.005, None)
    y = [0.0] * len(OUTPUT_NAMES)
    y[Y_QW], y[Y_Z], y[Y_ON_GROUND] = 1.0, -1.0, 0.0
    assert mon.check(0.0, y, 0.0, (0.5,) * 4) is None
    for bad in (math.nan, math.inf, -math.inf):
        y_bad = list(y)
        y_bad[i] = bad
        if i <= Y_VZ:
            with pytest.raises(ComponentError, match="non-finite state"):
                mon.check(0.0, y_bad, 0.0, (0.5,) * 4)
        elif i >= Y_AX and i != Y_ON_GROUND:
            assert mon.check(0.0, y_bad, 0.0, (0.5,) * 4) is None
