"""MAVLink 2 signing on the api and gcs links: accept signed, reject unsigned / wrong key /
replayed, sign everything sent, deterministic timestamps; the HIL link stays unsigned."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_rig import Rig

from mav import wire

M = mavlink2
KEY = bytes(range(32))
EPOCH_2024 = 283996800 * 100000           # 10 us units since 2015-01-01


def test_signed_commands_accepted_and_output_signed():
    rig = Rig(signing_key=KEY, app_key=KEY, gcs_key=KEY)
    rig.tick()
    rig.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    rig.tick(10)
    assert rig.ob.armed and rig.ack(400) == M.MAV_RESULT_ACCEPTED
    for link in ("api", "gcs"):
        msgs = [m for _, m in rig.rx[link]]
        assert msgs and all(m.get_signed() for m in msgs)
        assert all(d[2] & wire.IFLAG_SIGNED for d in rig.raw[link])
    # HIL answers are not signed: the simulator is trusted
    assert rig.ob.stats["unsigned_rejected"] == rig.ob.stats["badsig_rejected"] == 0


def test_unsigned_wrong_key_and_replay_are_rejected():
    rig = Rig(signing_key=KEY, gcs_key=KEY)
    rig.tick()
    plain = M.MAVLink(None, 255, 190)
    rig.send_raw("gcs", wire.send_msg(plain, M.MAVLink_command_long_message(
        1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    wrong = M.MAVLink(None, 255, 190)
    sg = wrong.signing
    sg.secret_key, sg.sign_outgoing, sg.timestamp = bytes(32), True, EPOCH_2024 + 10
    rig.send_raw("gcs", wire.send_msg(wrong, M.MAVLink_command_long_message(
        1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
    # unsigned setpoints on the API link too (the fast path must not bypass the check)
    plain_app = M.MAVLink(None, 1, 191)
    rig.send_raw("api", wire.encode_set_position_target_local_ned(
        plain_app, 0, 1, 1, 1, 0x0DF8, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0))
    rig.tick()
    st = rig.ob.stats
    assert not rig.ob.armed and st["setpoints"] == 0
    assert st["unsigned_rejected"] == 2 and st["badsig_rejected"] == 1
    assert rig.msgs("gcs", "COMMAND_ACK") == []
    # a correctly signed command works; replaying its exact bytes does not
    data = rig.send("gcs", M.MAVLink_command_long_message(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    rig.tick()
    assert rig.ob.armed
    rig.cmd(400, 0)
    rig.tick()
    assert not rig.ob.armed
    rig.send_raw("gcs", data)                        # replay "arm"
    rig.tick()
    assert not rig.ob.armed and st["badsig_rejected"] == 2


def test_signing_timestamps_follow_the_hil_clock_and_runs_are_identical():
    def run() -> tuple[list[bytes], list[bytes]]:
        rig = Rig(signing_key=KEY, gcs_key=KEY, decode=False)
        rig.k = 2000                                # t = 10 s
        rig.tick(50)
        return rig.raw["api"], rig.raw["gcs"]

    a, b = run(), run()
    assert a == b
    checker = M.MAVLink(None, 9, 9)
    checker.signing.secret_key = KEY
    first = a[0][0]
    checker.decode(bytearray(first))
    ts = checker.signing.stream_timestamps[(0, 1, 1)]
    assert ts == EPOCH_2024 + 10 * 100000           # 2024-01-01 + 10 s, in 10 us units


def test_signed_client_flies_the_signed_vehicle():
    rig = Rig(signing_key=KEY, app_key=KEY, client=True)
    c = rig.client
    rig.run_until(lambda r: c.heartbeat_seen, 1.0)
    c.arm()
    c.takeoff(1.0)
    rig.run_until(lambda r: c.ack(22) is not None, 0.5)
    assert c.ack(400) == c.ack(22) == M.MAV_RESULT_ACCEPTED and rig.ob.mode_name == "AUTO.TAKEOFF"
    assert c.stats["rejected_unsigned"] == 0 and not math.isnan(c.position[0])


def test_a_packet_captured_on_one_link_is_a_replay_on_the_other():
    """Issue 14 item 4: a signed PARAM_SET captured on the GCS link was accepted again on the
    API link (each link kept its own replay table)."""
    rig = Rig(signing_key=KEY, app_key=KEY, gcs_key=KEY)
    rig.tick()
    data = rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"TPL_LAND_SPEED", 0.25,
                                                       M.MAV_PARAM_TYPE_REAL32))
    rig.tick()
    assert rig.ob.params.get("TPL_LAND_SPEED") == 0.25
    st = rig.ob.stats
    rejected = st["badsig_rejected"]
    rig.send("gcs", M.MAVLink_param_set_message(1, 1, b"TPL_LAND_SPEED", 0.5,
                                                M.MAV_PARAM_TYPE_REAL32))
    rig.tick()
    assert rig.ob.params.get("TPL_LAND_SPEED") == 0.5
    rig.send_raw("api", data)                        # the captured 0.25, on the other link
    rig.tick()
    assert rig.ob.params.get("TPL_LAND_SPEED") == 0.5
    assert st["badsig_rejected"] == rejected + 1


def test_sitl_signing_key_file_reaches_the_vehicle(tmp_path):
    """Issue 14 item 5: `cosim sitl --signing-key FILE`; the key file is 32 bytes or 64 hex
    digits, a bad one is exit 2 naming the flag, and the vehicle built with it rejects unsigned
    input and accepts signed input."""
    import subprocess
    import sys

    from cosim.cli_sitl import read_signing_key
    from cosim.errors import ScenarioError
    from cosim.load import load_scenario
    from cosim.outputs.tlog import Tlog
    from cosim.sim.onboard import OnboardHandle
    from cosim.sim.options import RunOptions
    from mav.hil import HilSimulatorCodec

    raw, hexf, bad = tmp_path / "k.bin", tmp_path / "k.hex", tmp_path / "bad"
    raw.write_bytes(KEY)
    hexf.write_text(KEY.hex() + "\n")
    bad.write_text("not a key")
    assert read_signing_key(raw, "--signing-key") == read_signing_key(hexf, "--k") == KEY
    for f in (bad, tmp_path / "missing"):
        try:
            read_signing_key(f, "--signing-key")
            raise AssertionError("accepted a bad key file")
        except ScenarioError as exc:
            assert exc.field == "--signing-key"
    r = subprocess.run([sys.executable, "-m", "cosim.cli", "sitl", "--signing-key", str(bad),
                        "--gcs-bind", "127.0.0.1:0", "--api-bind", "127.0.0.1:0"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--signing-key" in r.stderr

    from cosim.load import with_set

    sc = with_set(load_scenario(__import__("pathlib").Path(__file__).resolve().parents[1]
                                / "scenarios" / "scripted_square.toml"),
                  {"sensors.feed": "truth"})     # this test sends the vehicle ODOMETRY
    h = OnboardHandle(sc, RunOptions(signing_key=KEY), Tlog(tmp_path / "t.tlog"), tmp_path)
    codec = HilSimulatorCodec()
    meas = (sc.start.n, sc.start.e, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    try:
        plain = M.MAVLink(None, 255, 190)
        h.api.send(wire.send_msg(plain, M.MAVLink_command_long_message(
            1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
        for k in range(3):
            h.exchange(codec.encode_odometry(k * 5000, meas))
        assert not h.onboard.armed and h.onboard.stats["unsigned_rejected"] == 1
        signed = M.MAVLink(None, 255, 190)
        sg = signed.signing
        sg.secret_key, sg.sign_outgoing, sg.timestamp = KEY, True, EPOCH_2024 + 10
        h.api.send(wire.send_msg(signed, M.MAVLink_command_long_message(
            1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)))
        h.exchange(codec.encode_odometry(15000, meas))
        assert h.onboard.armed
    finally:
        h.close()
