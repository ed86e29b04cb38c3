"""The odometry sensor: without noise it hands over the truth (picked out of the plant's
outputs by a C itemgetter, the same tuple as the method's); with noise the seeded draw."""

from __future__ import annotations

import random

import numpy as np

from cosim.plant.fmu import OUTPUT_NAMES
from cosim.scenario.records import SensorNoise
from cosim.sensors.odometry import OdometrySensor


def test_noise_free_measure_is_the_truth_tuple():
    s = OdometrySensor(SensorNoise(), np.random.default_rng(0))
    rng = random.Random(1)
    for _ in range(100):
        y = [rng.uniform(-5, 5) for _ in OUTPUT_NAMES]
        got = s.measure(y)
        assert got == OdometrySensor.measure(s, y) and type(got) is tuple and len(got) == 13
        # the same bits (compiled, the method reboxes the floats: equal, not the same objects)
        assert all(type(a) is float and a.hex() == b.hex()
                   for a, b in zip(got, OdometrySensor.measure(s, y), strict=True))


def test_noisy_measure_draws_from_the_seeded_generator():
    a = OdometrySensor(SensorNoise(pos_std_m=0.01), np.random.default_rng(5))
    b = OdometrySensor(SensorNoise(pos_std_m=0.01), np.random.default_rng(5))
    y = [0.5] * len(OUTPUT_NAMES)
    ma, mb = a.measure(y), b.measure(y)
    assert ma == mb and ma[0] != 0.5          # noisy, and reproducible
    assert "measure" not in vars(a)            # the method, not the truth picker
