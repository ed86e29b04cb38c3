"""The lead over a peer, measured side by side in one run: the seed mission's tick loop (the
default feed: sensor models and the onboard estimator) against RotorPy, a Python quadrotor
simulator from the registry (`pip install '.[peers]'`), rounds interleaved so a neighbour's load
falls on both alike.

RotorPy (github.com/spencerfolk/rotorpy) flies its Crazyflie model with its geometric SE(3)
controller along its 3-D circle at 100 Hz (its default rate), no sensors and no camera: less
than our mission does per simulated second (200 Hz, a camera frame every 40 ticks, MAVLink
both ways, the sensors and the estimator). Both are timed over the same simulated time, setup
excluded where each allows it (our tick loop alone; RotorPy's `Environment.run`, which is
its loop and the results' packing).
"""

from __future__ import annotations

import statistics
import time
from typing import Any

from cosim.bench.common import seed_scenario


def rotorpy_available() -> bool:
    try:
        import rotorpy  # noqa: F401
    except ImportError:
        return False
    return True


def _rotorpy_rtf(t_final: float) -> float:
    from rotorpy.controllers.quadrotor_control import SE3Control
    from rotorpy.environments import Environment
    from rotorpy.trajectories.circular_traj import ThreeDCircularTraj
    from rotorpy.vehicles.crazyflie_params import quad_params
    from rotorpy.vehicles.multirotor import Multirotor

    sim = Environment(vehicle=Multirotor(quad_params), controller=SE3Control(quad_params),
                      trajectory=ThreeDCircularTraj(), sim_rate=100)
    t0 = time.perf_counter()
    sim.run(t_final=t_final, use_mocap=False, terminate=False, plot=False,
            animate_bool=False, verbose=False)
    return t_final / (time.perf_counter() - t0)


def _ours_rtf(t_final: float | None) -> tuple[float, float]:
    from cosim.sim.master import RunOptions, run_scenario

    sets = {"sensors.feed": "hil"}
    if t_final is not None:
        sets["timing.t_final_s"] = t_final
    res = run_scenario(seed_scenario(sets), RunOptions(mode="mil"))
    return res.loop_real_time_factor, res.t_end_s


def bench_peers(rounds: int = 4, t_final: float | None = None) -> dict[str, Any]:
    """x real time of each, median over `rounds` interleaved rounds, and the ratio per round;
    the whole seed mission, or its first `t_final` seconds."""
    if not rotorpy_available():
        return {"missing": "RotorPy is not installed: pip install '.[peers]'"}
    ours, peer, ratios = [], [], []
    for _ in range(rounds):
        o, t_sim = _ours_rtf(t_final)
        p = _rotorpy_rtf(t_sim)
        ours.append(o)
        peer.append(p)
        ratios.append(o / p)
    return {"ours_x_real_time": statistics.median(ours),
            "rotorpy_x_real_time": statistics.median(peer),
            "ratio": statistics.median(ratios), "ratios": ratios, "sim_time_s": t_sim,
            "rounds": rounds, "target_ratio": 50.0,
            "meets_target": statistics.median(ratios) >= 50.0}


def format_peers(d: dict[str, Any]) -> list[str]:
    if "missing" in d:
        return [f"against a peer: {d['missing']}"]
    return [f"against a peer, side by side ({d['rounds']} interleaved rounds of "
            f"{d['sim_time_s']:.0f} s simulated): the seed mission on the estimate "
            f"{d['ours_x_real_time']:.1f}x real time, RotorPy (SE3, 100 Hz, no sensors) "
            f"{d['rotorpy_x_real_time']:.2f}x: ours / RotorPy {d['ratio']:.1f}x (rounds "
            f"{', '.join(f'{r:.1f}' for r in d['ratios'])}; target >= "
            f"{d['target_ratio']:g}x)  {'ok' if d['meets_target'] else 'MISSED'}"]
