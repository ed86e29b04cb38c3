"""The lead over peers, measured side by side in one run: the seed mission's tick loop (the
default feed: sensor models and the onboard estimator) against the Python quadrotor simulators
its users would otherwise pick, rounds interleaved so a neighbour's load falls on all alike.

- **gym-pybullet-drones** (github.com/utiasDSL/gym-pybullet-drones; not on PyPI: install its
  checkout with ``pip install --no-deps``, its dependencies from ``pip install '.[peers]'``):
  `CtrlAviary` with one Crazyflie 2.x, PyBullet's physics at 240 Hz and its `DSLPIDControl` at
  48 Hz (the rates of its ``examples/pid.py``), following a 0.5 m circle 1 m up, no GUI, no
  camera, no obstacles, no logger.
- **RotorPy** (github.com/spencerfolk/rotorpy; ``pip install '.[peers]'``): its Crazyflie model
  with its geometric SE(3) controller along its 3-D circle at 100 Hz (its default rate), no
  sensors and no camera.

Both do less per simulated second than our mission (200 Hz, a camera frame every 40 ticks,
MAVLink both ways, the sensors and the estimator). All are timed over the same simulated time,
setup excluded where each allows it (our tick loop alone; gym-pybullet-drones' step and control
loop, the environment made before; RotorPy's `Environment.run`, its loop and the results'
packing). The targets are issue 41's: >= 5x gym-pybullet-drones, >= 50x RotorPy.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import statistics
import time
import warnings
from collections.abc import Callable, Iterator
from typing import Any

from cosim.bench.common import seed_scenario

GPD_INSTALL = ("gym-pybullet-drones is not installed (it is not on PyPI): pip install "
               "'.[peers]', then pip install --no-deps "
               "git+https://github.com/utiasDSL/gym-pybullet-drones (or a checkout of it)")


def _importable(name: str) -> bool:
    try:
        __import__(name)
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """PyBullet and the aviary print their build and model at the C level (fds 1 and 2) and
    warn about their spaces: kept out of the bench's report (an exception still propagates)."""
    saved = [os.dup(1), os.dup(2)]
    try:
        with open(os.devnull, "wb") as null, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            os.dup2(null.fileno(), 1)
            os.dup2(null.fileno(), 2)
            yield
    finally:
        ctypes.CDLL(None).fflush(None)     # C's buffered output, while it still goes nowhere
        for fd, s in enumerate(saved, 1):
            os.dup2(s, fd)
            os.close(s)


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


def _gpd_rtf(t_final: float) -> float:
    import numpy as np

    ctrl_hz, r = 48, 0.5
    with _quiet():
        from gym_pybullet_drones.control.DSLPIDControl import DSLPIDControl
        from gym_pybullet_drones.envs.CtrlAviary import CtrlAviary
        from gym_pybullet_drones.utils.enums import DroneModel, Physics

        env = CtrlAviary(drone_model=DroneModel.CF2X, num_drones=1,
                         initial_xyzs=np.array([[0.0, 0.0, 0.1]]), physics=Physics.PYB,
                         pyb_freq=240, ctrl_freq=ctrl_hz, gui=False, record=False,
                         obstacles=False)
        ctrl = DSLPIDControl(drone_model=DroneModel.CF2X)
    try:
        action = np.zeros((1, 4))
        rpy = np.zeros(3)
        n = int(round(t_final * ctrl_hz))
        t0 = time.perf_counter()
        for i in range(n):
            obs = env.step(action)[0]
            w = 0.5 * i / ctrl_hz
            target = np.array([r * np.cos(w) - r, r * np.sin(w), 1.0])
            action[0, :] = ctrl.computeControlFromState(
                control_timestep=env.CTRL_TIMESTEP, state=obs[0], target_pos=target,
                target_rpy=rpy)[0]
        elapsed = time.perf_counter() - t0
    finally:
        with _quiet():
            env.close()
    if not 0.5 < obs[0][2] < 1.5:       # it flew: 1 m up at the end
        raise RuntimeError(f"gym-pybullet-drones did not fly its circle (z {obs[0][2]:.2f} m)")
    return n / ctrl_hz / elapsed


def _ours_rtf(t_final: float | None) -> tuple[float, float]:
    from cosim.sim.master import RunOptions, run_scenario

    sets = {"sensors.feed": "hil"}
    if t_final is not None:
        sets["timing.t_final_s"] = t_final
    res = run_scenario(seed_scenario(sets), RunOptions(mode="mil"))
    return res.loop_real_time_factor, res.t_end_s


# name -> (module to import, how to install it, its run, its description, the target ratio)
PEERS: dict[str, tuple[str, str, Callable[[float], float], str, float]] = {
    "gym_pybullet_drones": ("gym_pybullet_drones", GPD_INSTALL, _gpd_rtf,
                            "gym-pybullet-drones (PyBullet 240 Hz, DSLPID 48 Hz, no camera)",
                            5.0),
    "rotorpy": ("rotorpy", "RotorPy is not installed: pip install '.[peers]'", _rotorpy_rtf,
                "RotorPy (SE3, 100 Hz, no sensors)", 50.0),
}


def bench_peers(rounds: int = 4, t_final: float | None = None) -> dict[str, Any]:
    """x real time of ours and of each installed peer, median over `rounds` interleaved
    rounds, and ours / the peer per round; the whole seed mission, or its first `t_final`
    seconds. A peer not installed is reported as missing, with how to install it."""
    have = {k: p for k, p in PEERS.items() if _importable(p[0])}
    out: dict[str, Any] = {"rounds": rounds,
                           "peers": {k: {"missing": p[1]} for k, p in PEERS.items()
                                     if k not in have}}
    if not have:
        return out
    ours: list[float] = []
    runs: dict[str, list[float]] = {k: [] for k in have}
    for _ in range(rounds):
        o, t_sim = _ours_rtf(t_final)
        ours.append(o)
        for k, p in have.items():
            runs[k].append(p[2](t_sim))
    out.update(ours_x_real_time=statistics.median(ours), ours_runs=ours, sim_time_s=t_sim)
    for k, p in have.items():
        ratios = [o / x for o, x in zip(ours, runs[k], strict=True)]
        ratio = statistics.median(ratios)
        out["peers"][k] = {"name": p[3], "x_real_time": statistics.median(runs[k]),
                           "runs": runs[k], "ratio": ratio, "ratios": ratios,
                           "target_ratio": p[4], "meets_target": ratio >= p[4]}
    return out


def format_peers(d: dict[str, Any]) -> list[str]:
    lines = []
    if "ours_x_real_time" in d:
        lines.append(f"against peers, side by side ({d['rounds']} interleaved rounds of "
                     f"{d['sim_time_s']:.0f} s simulated): the seed mission on the estimate "
                     f"{d['ours_x_real_time']:.1f}x real time")
    for p in d["peers"].values():
        if "missing" in p:
            lines.append(f"  against a peer: {p['missing']}")
            continue
        lines.append(f"  {p['name']} {p['x_real_time']:.2f}x: ours / it {p['ratio']:.1f}x "
                     f"(rounds {', '.join(f'{r:.1f}' for r in p['ratios'])}; target >= "
                     f"{p['target_ratio']:g}x)  {'ok' if p['meets_target'] else 'MISSED'}")
    return lines
