"""Paper 1's released estimator (mav/estimator/release.py, TPL_EST_TYPE 2, the Mambo's default;
issue 44 item 1): its filters are MATLAB's designs, its Kalman gains the steady-state ones of
its matrices, it is the Mambo's default, and a flight on it shows its structure."""

from __future__ import annotations

import csv
import math
import random
from pathlib import Path

import numpy as np
import pytest
from scipy import linalg, signal

from cosim.errors import ScenarioError
from cosim.load import load_scenario, with_set
from mav.estimator import release as rel
from mav.params import EST_OURS, EST_RELEASE

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "scenarios" / "mambo_seed_track.toml"


def test_filters_are_matlabs_designs():
    """designfilt('lowpassfir','FilterOrder',5,'CutoffFrequency',0.1) (a Hamming-window FIR,
    fir1), cheby2(5, 40, 0.8) and butter(3, 0.01) (estimatorVars.m lines 10-12, 21-22)."""
    np.testing.assert_allclose(rel.FIR_ACC, signal.firwin(6, 0.1), rtol=0, atol=1e-15)
    b, a = signal.cheby2(5, 40, 0.8)
    np.testing.assert_allclose(rel.CHEBY2_B, b, atol=1e-14)
    np.testing.assert_allclose(rel.CHEBY2_A, a, atol=1e-14)
    b, a = signal.butter(3, 0.01)
    np.testing.assert_allclose(rel.BUTTER_B, b, atol=1e-18)
    np.testing.assert_allclose(rel.BUTTER_A, a, atol=1e-14)


@pytest.mark.parametrize("b,a", [(rel.FIR_ACC, (1.0,)), (rel.CHEBY2_B, rel.CHEBY2_A),
                                 (rel.BUTTER_B, rel.BUTTER_A)], ids=["fir", "cheby2", "butter"])
def test_a_filter_channel_is_matlabs_filter(b, a):
    rng = random.Random(3)
    x = [rng.gauss(0.0, 1.0) for _ in range(400)]
    f = rel.Lti(b, a)
    y = [f.step(v) for v in x]
    np.testing.assert_allclose(y, signal.lfilter(b, a, x), rtol=1e-9, atol=1e-12)
    f.reset()
    assert f.step(0.0) == 0.0


def test_kalman_gains_are_the_steady_state_ones():
    """The Kalman Filter blocks are time-invariant, so Simulink runs their steady-state gain:
    M = P C' (C P C' + R)^-1 with P the discrete Riccati equation's prior covariance."""
    ts = rel.TS
    a = np.array([[1.0, ts], [0.0, 1.0]])
    c = np.array([[1.0, 0.0]])
    q = np.array([[0.0, 0.0], [0.0, rel.ALT_Q]])
    p = linalg.solve_discrete_are(a.T, c.T, q, np.array([[rel.ALT_R]]))
    m = p @ c.T / (c @ p @ c.T + rel.ALT_R)
    k0, k1 = rel.steady_gain_alt(rel.ALT_Q, rel.ALT_R, ts)
    assert k0 == pytest.approx(m[0, 0], rel=1e-9) and k1 == pytest.approx(m[1, 0], rel=1e-9)
    pv = linalg.solve_discrete_are(np.eye(1), np.eye(1), 0.09 * np.eye(1), 5.0 * np.eye(1))
    assert rel.steady_prior_vel(0.09, 5.0) == pytest.approx(pv[0, 0], rel=1e-12)


def _kind(**over) -> float | None:
    sc = with_set(load_scenario(SEED), over)
    return dict(sc.onboard_params).get("TPL_EST_TYPE")


def test_the_mambo_flies_paper_1s_estimator_by_default():
    assert _kind() == EST_RELEASE
    assert _kind(**{"sensors.gps.enabled": True}) == EST_OURS       # the release has no GPS
    assert _kind(**{"vehicle.preset": "bebop2"}) == EST_OURS
    assert _kind(**{"onboard.params.TPL_EST_TYPE": 1}) == EST_OURS
    with pytest.raises(ScenarioError) as ei:
        _kind(**{"sensors.gps.enabled": True, "onboard.params.TPL_EST_TYPE": 2})
    assert ei.value.field == "onboard.params.TPL_EST_TYPE"


def _length(rows: list[dict[str, str]], kx: str, ky: str) -> float:
    return sum(math.hypot(float(b[kx]) - float(a[kx]), float(b[ky]) - float(a[ky]))
               for a, b in zip(rows, rows[1:], strict=False))


@pytest.mark.flight
def test_a_flight_on_the_release_shows_its_flow_correction(tmp_path):
    """The release scales the flow by 1.15 after its first 4 s (opticalFlowErrorCorrect, a
    correction of the real Mambo's flow sensor); ours has no such error, so the estimated
    path is ~15 % longer than the flown one, while the mission still passes on vision."""
    from cosim.cli import main

    assert main(["run", str(SEED), "--out", str(tmp_path), "--quiet"]) == 0
    rows = [r for r in csv.DictReader((tmp_path / "timeseries.csv").open())
            if r["phase_name"] == "following"][::20]
    ratio = _length(rows, "est_x", "est_y") / _length(rows, "x", "y")
    assert 1.08 < ratio < 1.22, ratio


@pytest.mark.parametrize("b,a", [((1.0,) * 7, (1.0,)), ((1.0,), (0.0,)), ((), ()),
                                 ((1.0, 1.0), (1.0, 2.0, 3.0))])
def test_a_filter_of_more_coefficients_than_it_holds_is_refused(b, a):
    """Its coefficients live in fixed C arrays of 6 once compiled: more is a ValueError,
    never a write past them."""
    with pytest.raises(ValueError):
        rel.Lti(b, a)
