"""tlog records and sweep argument parsing."""

from __future__ import annotations

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from cosim.errors import ScenarioError
from cosim.outputs.tlog import Tlog, read_tlog
from cosim.scenario.sets import parse_sets, split_values


def test_tlog_roundtrip_readable_by_pymavlink(tmp_path):
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    log = Tlog(tmp_path / "stream.tlog")   # streamed as the datagrams pass
    msgs = []
    for i in range(5):
        log.t_us = 5000 * i
        data = mav.heartbeat_encode(2, 12, 0, i, 3).pack(mav)
        msgs.append(data)
        log.add(data)
    path = tmp_path / "flight.tlog"
    log.write(path)   # a copy elsewhere
    log.close()
    assert path.read_bytes() == log.read() == (tmp_path / "stream.tlog").read_bytes()
    recs = read_tlog(path)
    assert [t for t, _ in recs] == [0, 5000, 10000, 15000, 20000]
    assert [d for _, d in recs] == msgs
    m = mavutil.mavlink_connection(str(path))
    got = []
    while (msg := m.recv_match(type="HEARTBEAT")) is not None:
        got.append((msg.custom_mode, round(m.timestamp * 1e6)))
    assert got == [(i, 5000 * i) for i in range(5)]


def test_split_and_parse_sets():
    assert split_values("1,2,[3,4], 5") == ["1", "2", "[3,4]", "5"]
    g = parse_sets(["app.alpha=0.002,0.004", "seed=1"], multi=True)
    assert g == {"app.alpha": [0.002, 0.004], "seed": [1]}
    assert parse_sets(["app.name=scripted"], multi=False) == {"app.name": ["scripted"]}
    with pytest.raises(ScenarioError, match="--set"):
        parse_sets(["alpha"], multi=True)
