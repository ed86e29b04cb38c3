"""The run recorder: rows spooled to disk in blocks; memory bounded by one block."""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

from cosim.errors import ScenarioError
from cosim.load import parse_scenario
from cosim.outputs.series import CHUNK, COL, SERIES_COLUMNS, SeriesSpool
from cosim.plant.fmu import OUTPUT_NAMES
from cosim.sensors.camera import parse_camera


def test_spool_round_trips_bit_exact_and_memory_stays_one_block(tmp_path):
    rng = np.random.default_rng(0)
    n = 5 * CHUNK + 123
    ref = rng.standard_normal((n, len(SERIES_COLUMNS)))
    ref[7, 3] = np.nan                      # NaN setpoints are recorded as they are
    spool = SeriesSpool(tmp_path / "s.f64")
    most_in_ram = 0
    for k, row in enumerate(ref):
        spool.append(spool.pack(*row.tolist()))
        most_in_ram = max(most_in_ram, len(spool.rows))
        if k & (CHUNK - 1) == CHUNK - 1:
            spool.flush()
    rec = spool.finish()
    assert most_in_ram == CHUNK                 # never more than one block of rows in memory
    assert rec.ticks == n
    assert rec.array().tobytes() == ref.tobytes()
    assert np.concatenate(list(rec.blocks(rows=1000))).tobytes() == ref.tobytes()
    x, ph = rec.columns("x", "phase")
    assert x.tobytes() == ref[:, COL["x"]].tobytes()
    assert ph.tobytes() == ref[:, COL["phase"]].tobytes()
    d = rec.decimated(max_rows=1000)
    step = -(-n // 1000)
    assert d.tobytes() == ref[::step].tobytes() and len(d) <= 1000


def test_empty_spool(tmp_path):
    rec = SeriesSpool(tmp_path / "e.f64").finish()
    assert rec.ticks == 0 and rec.array().shape == (0, len(SERIES_COLUMNS))
    assert rec.columns("t")[0].shape == (0,)


def test_camera_kind_is_chosen_by_name():
    cfg = parse_camera({"kind": "down", "width": 64})
    assert cfg.width == 64
    assert parse_camera({}) == parse_camera({"kind": "down"})
    with pytest.raises(ScenarioError, match="camera.kind"):
        parse_camera({"kind": "sideways"})


def test_scenario_holds_typed_world_and_camera():
    sc = parse_scenario({"vehicle": {"preset": "mambo"},
                         "world": {
                             "arena": {"n_min": 0, "n_max": 4, "e_min": 0, "e_max": 4},
                             "start": {"n": 1.0, "e": 2.0, "yaw_deg": 90.0}},
                         "camera": {"kind": "down"}})
    assert sc.world.arena[1] == 4.0
    assert sc.camera.width == 160
    assert (sc.start.n, sc.start.e, sc.start.yaw_deg) == (1.0, 2.0, 90.0)


def test_a_ticks_row_is_packed_as_pack_packs_it(tmp_path):
    """SeriesSpool.row (the tick's row, written without a tuple when compiled) gives the bytes
    of `pack` for the same values, NaNs, infinities, signed zeros and subnormals included;
    anything else (a y that is not a list of floats, a value that is not a number) goes
    through `pack`: its numbers alike, its errors struct's."""
    spool = SeriesSpool(tmp_path / "r.f64")
    rng = random.Random(3)
    n = len(OUTPUT_NAMES)
    for k in range(300):
        y = [rng.uniform(-1e3, 1e3) for _ in range(n)]
        y[rng.randrange(n)] = rng.choice([math.nan, math.inf, -math.inf, -0.0, 5e-324])
        tail = [rng.uniform(-10.0, 10.0) for _ in range(10)] + [rng.randrange(7)]
        assert spool.row(0.005 * k, y, *tail) == spool.pack(0.005 * k, *y, *tail)
    assert spool.row(1.0, tuple(y), *tail) == spool.pack(1.0, *y, *tail)    # not a list
    with pytest.raises(struct.error):                                      # not a number
        spool.row(1.0, y, *tail[:-1], "x")
    y[0] = 3
    assert spool.row(1.0, y, *tail) == spool.pack(1.0, *y, *tail)
    y[0] = "x"
    with pytest.raises(struct.error):
        spool.row(1.0, y, *tail)
    spool.finish()
