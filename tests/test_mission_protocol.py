"""The MAVLink mission protocol's edge cases, as a ground station would hit them (MIL rig,
vehicle at rest): round trip, legacy float items, partial upload, cancel, wrong sequence,
timeout, refused items, clear, set-current, other mission types, two clients at once."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import common as mavlink2
from test_onboard_auto import upload, waypoint
from test_onboard_rig import Rig

M = mavlink2


def rig_with_mission(n: int = 3) -> tuple[Rig, list]:
    rig = Rig()
    rig.tick()
    items = [waypoint(rig, i, float(i), 0.5 * i, 1.0 + 0.1 * i) for i in range(n)]
    assert upload(rig, items) == M.MAV_MISSION_ACCEPTED
    rig.clear()
    return rig, items


def download(rig: Rig, use_int: bool = True, link: str = "gcs") -> list:
    rig.send(link, M.MAVLink_mission_request_list_message(1, 1, 0))
    rig.tick()
    n = rig.last(link, "MISSION_COUNT").count
    got = []
    for seq in range(n):
        if use_int:
            rig.send(link, M.MAVLink_mission_request_int_message(1, 1, seq, 0))
        else:
            rig.send(link, M.MAVLink_mission_request_message(1, 1, seq, 0))
        rig.tick()
        got.append(rig.last(link, "MISSION_ITEM_INT" if use_int else "MISSION_ITEM"))
    rig.send(link, M.MAVLink_mission_ack_message(1, 1, M.MAV_MISSION_ACCEPTED, 0))
    rig.tick()
    return got


def current(rig: Rig):
    rig.tick(210)                        # MISSION_CURRENT streams at 1 Hz
    return rig.last("gcs", "MISSION_CURRENT")


def test_upload_download_round_trip_int_and_legacy_float():
    rig, items = rig_with_mission(3)
    got = download(rig)
    assert [(m.seq, m.command, m.frame, m.x, m.y) for m in got] == [
        (m.seq, m.command, m.frame, m.x, m.y) for m in items]
    assert all(abs(g.z - i.z) < 1e-6 for g, i in zip(got, items, strict=True))
    assert [m.current for m in got] == [1, 0, 0]
    legacy = download(rig, use_int=False)
    assert [m.frame for m in legacy] == [M.MAV_FRAME_GLOBAL_RELATIVE_ALT] * 3
    # float32 degrees: about 4e-6 deg (0.4 m) apart at these latitudes, which is why
    # MISSION_ITEM_INT exists
    assert all(abs(f.x - i.x * 1e-7) < 5e-6 and abs(f.y - i.y * 1e-7) < 1e-5
               for f, i in zip(legacy, items, strict=True))
    cur = current(rig)
    assert (cur.seq, cur.total, cur.mission_state) == (0, 3, 2)      # NOT_STARTED
    # a legacy MISSION_ITEM upload is stored like the INT one
    floats = [M.MAVLink_mission_item_message(1, 1, m.seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                                             m.command, 0, 1, 0, 0, 0, math.nan, m.x * 1e-7,
                                             m.y * 1e-7, m.z, 0) for m in items]
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 3, 0))
    served = 0
    for _ in range(50):
        rig.tick()
        reqs = rig.msgs("gcs", "MISSION_REQUEST_INT")
        for r in reqs[served:]:
            rig.send("gcs", floats[r.seq])
        served = len(reqs)
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    assert all(abs(g.x - i.x) <= 50 and abs(g.y - i.y) <= 100
               for g, i in zip(download(rig), items, strict=True))


def test_partial_upload_cancelled_or_timed_out_keeps_the_old_mission():
    rig, items = rig_with_mission(3)
    new = [waypoint(rig, i, 5.0, 5.0, 2.0) for i in range(4)]
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 4, 0))
    rig.tick()
    rig.send("gcs", new[0])
    rig.tick()
    rig.send("gcs", M.MAVLink_mission_ack_message(1, 1, M.MAV_MISSION_OPERATION_CANCELLED, 0))
    rig.tick()
    assert "Mission upload cancelled" in rig.texts()
    assert [m.x for m in download(rig)] == [m.x for m in items]
    # silence after two items: the vehicle asks again, then gives up after 5 s
    rig.clear()
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 4, 0))
    rig.tick()
    rig.send("gcs", new[0])
    rig.tick()
    rig.send("gcs", new[1])
    rig.tick(200 * 6)
    asks = [m.seq for m in rig.msgs("gcs", "MISSION_REQUEST_INT")]
    assert asks[:3] == [0, 1, 2] and set(asks[3:]) == {2} and len(asks) >= 8   # re-asked
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_OPERATION_CANCELLED
    assert [m.x for m in download(rig)] == [m.x for m in items]


def test_wrong_sequence_is_not_stored_and_the_expected_item_is_asked_again():
    rig = Rig()
    rig.tick()
    items = [waypoint(rig, i, float(i), 0.0, 1.0) for i in range(3)]
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 3, 0))
    rig.tick()
    rig.send("gcs", items[2])                    # skipped ahead
    rig.tick()
    assert [m.seq for m in rig.msgs("gcs", "MISSION_REQUEST_INT")] == [0, 0]
    for it in items:
        rig.send("gcs", it)
        rig.send("gcs", it)                     # a duplicate (a client's retry)
        rig.tick()
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    assert rig.ob.stats["mission_out_of_seq"] >= 3
    assert [m.seq for m in download(rig)] == [0, 1, 2]


def test_refused_items_name_the_fault_and_keep_the_old_mission():
    rig, items = rig_with_mission(2)
    lat, lon, _ = rig.ob.geo.to_int(1.0, 0.0, 0.0)
    bad = {
        M.MAV_MISSION_UNSUPPORTED: M.MAVLink_mission_item_int_message(
            1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_VTOL_TAKEOFF, 0, 1,
            0, 0, 0, 0, lat, lon, 1.0, 0),
        M.MAV_MISSION_UNSUPPORTED_FRAME: M.MAVLink_mission_item_int_message(
            1, 1, 0, M.MAV_FRAME_BODY_FRD, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, lat, lon,
            1.0, 0),
        M.MAV_MISSION_INVALID_PARAM7: M.MAVLink_mission_item_int_message(
            1, 1, 0, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0,
            0, 0, lat, lon, math.inf, 0),
        M.MAV_MISSION_INVALID_PARAM5_X: waypoint(rig, 0, 50_000.0, 0.0, 1.0),   # 50 km
        M.MAV_MISSION_INVALID_PARAM1: waypoint(rig, 0, 1.0, 0.0, 1.0, p1=-3.0),
    }
    for result, item in bad.items():
        rig.clear()
        assert upload(rig, [item, items[1]]) == result, result
        assert "Mission rejected: item 0" in rig.texts()[-1]
    assert [m.x for m in download(rig)] == [m.x for m in items]
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 65535, 0))
    rig.tick()
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_NO_SPACE


def test_clear_set_current_start_and_other_mission_types():
    rig, items = rig_with_mission(3)
    rig.send("gcs", M.MAVLink_mission_set_current_message(1, 1, 2))
    cur = current(rig)
    assert (cur.seq, cur.total) == (2, 3)
    rig.cmd(M.MAV_CMD_DO_SET_MISSION_CURRENT, 7)
    rig.tick()
    assert rig.ack(M.MAV_CMD_DO_SET_MISSION_CURRENT) == M.MAV_RESULT_DENIED
    rig.cmd(M.MAV_CMD_DO_SET_MISSION_CURRENT, 1)
    rig.tick()
    assert rig.ack(M.MAV_CMD_DO_SET_MISSION_CURRENT) == M.MAV_RESULT_ACCEPTED
    assert current(rig).seq == 1
    # fence and rally: nothing stored, count 0, items refused
    for mtype in (M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY):
        rig.send("gcs", M.MAVLink_mission_request_list_message(1, 1, mtype))
        rig.tick()
        assert rig.last("gcs", "MISSION_COUNT").count == 0
        rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 2, mtype))
        rig.tick()
        ack = rig.last("gcs", "MISSION_ACK")
        assert (ack.type, ack.mission_type) == (M.MAV_MISSION_UNSUPPORTED, mtype)
    rig.send("gcs", M.MAVLink_mission_clear_all_message(1, 1, M.MAV_MISSION_TYPE_ALL))
    rig.tick()
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    cur = current(rig)
    assert (cur.total, cur.mission_state) == (0xFFFF, 1)     # NO_MISSION
    rig.cmd(M.MAV_CMD_MISSION_START, 0, 0)
    rig.tick()
    assert rig.ack(M.MAV_CMD_MISSION_START) == M.MAV_RESULT_DENIED
    assert "Mission denied: no mission uploaded" in rig.texts()


def test_second_client_is_refused_while_an_upload_runs_and_targets_are_checked():
    rig = Rig()
    rig.tick()
    items = [waypoint(rig, i, float(i), 0.0, 1.0) for i in range(2)]
    rig.send("gcs", M.MAVLink_mission_count_message(1, 1, 2, 0))
    rig.tick()
    rig.send("api", M.MAVLink_mission_count_message(1, 1, 5, 0))
    rig.tick()
    assert rig.last("api", "MISSION_ACK").type == M.MAV_MISSION_DENIED
    rig.send("gcs", M.MAVLink_mission_count_message(2, 1, 5, 0))   # for system 2: ignored
    rig.tick()
    for it in items:
        rig.send("gcs", it)
        rig.tick()
    assert rig.last("gcs", "MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
    assert rig.ob.stats["not_for_us"] >= 1 and rig.ob.stats["handler_errors"] == 0
