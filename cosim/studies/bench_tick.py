"""`cosim bench`'s tick breakdown: where the MIL tick of the seed mission goes, part by part,
and the floor (the essentials of a tick measured alone)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from cosim.studies.bench_common import SEED, _per_call_us

# (module, class, method, label, parent label or None): the parts of a MIL tick, timed by
# wrapping the methods for one run (bench_tick_breakdown); class None: a module attribute the
# tick looks up at run or call time (the compiled battery step and HIL answer decoder)
_HIL = "HIL exchange (onboard)"
_CTRL = "  onboard controller"
_SETPOINT = "  setpoint encode+send"
_TICK_PARTS = (
    ("cosim.sensors.odometry", "OdometrySensor", "measure", "sensor model", None),
    ("cosim.sensors.down", "DownwardCamera", "render", "camera render (per tick)", None),
    ("cosim.apps.line_follower", "LineFollowerApp", "on_frame", "app on_frame: IPS", None),
    ("cosim.apps.line_follower", "LineFollowerApp", "on_tick", "app on_tick", None),
    ("mav.client", "OffboardClient", "poll", "  client poll (telemetry in)", "app on_tick"),
    ("mav.client", "OffboardClient", "_setpoint", _SETPOINT, "app on_tick"),
    ("mav.hil", "HilSimulatorCodec", "encode_odometry", "ODOMETRY encode", None),
    ("cosim.sim.onboard", "OnboardHandle", "exchange_call", "HIL exchange (onboard)", None),
    ("mav.onboard.links", "LinkInput", "drain", "  onboard drain api+gcs", _HIL),
    ("mav.onboard.vehicle", "Onboard", "_step_modes", "  onboard modes", "HIL exchange (onboard)"),
    ("mav.cascade", "QuadCascade", "update", _CTRL, _HIL),
    ("mav.battery", "Battery", "step", "  onboard battery", "HIL exchange (onboard)"),
    ("mav._fastpath", None, "battery_step", "  onboard battery", "HIL exchange (onboard)"),
    ("mav.onboard.telemetry", "Telemetry", "publish", "  onboard telemetry out", _HIL),
    ("mav.wire", None, "decode_hil_actuator_controls", "HIL_ACTUATOR_CONTROLS decode", None),
    ("cosim.plant.fmu", "Plant", "step", "plant step", None),
)


def _timing_attr(setup: Callable, attr: str, timed: Callable, label: str) -> Callable:
    """A set-up method that then times the instance attribute `attr` it bound, if any."""
    def wrapper(self: Any, *a: Any, **kw: Any) -> None:
        setup(self, *a, **kw)
        if attr in self.__dict__:
            setattr(self, attr, timed(self.__dict__[attr], label))
    return wrapper


def _timed_result(fn: Callable, timed: Callable, label: str) -> Callable:
    """fn returning a callable -> the same returning that callable timed under `label`."""
    def wrapper(*a: Any, **kw: Any) -> Any:
        return timed(fn(*a, **kw), label)
    return wrapper


def bench_tick_breakdown() -> dict[str, Any]:
    """Where the MIL tick of the seed mission goes, in us per tick (averaged over the run).

    One run with every part of `_TICK_PARTS` wrapped in a timer. The cost of a timer (measured
    here on a no-op) is taken out of the parent's figure for each timed call inside it; what
    is left of the loop is the master's own work (recording, exit checks, tlog taps, loop).
    The timed run is slower than an untimed one by about that timer cost per call.
    """
    import importlib

    from cosim.scenario.parse import load_scenario
    from cosim.sim.master import RunOptions, run_scenario

    acc: dict[str, list[int]] = {}

    def timed(fn: Callable, label: str) -> Callable:
        cell = acc.setdefault(label, [0, 0])
        clock = time.perf_counter_ns

        def wrapper(*a: Any, **kw: Any) -> Any:
            t0 = clock()
            try:
                return fn(*a, **kw)
            finally:
                cell[0] += clock() - t0
                cell[1] += 1
        return wrapper

    # timer cost: a wrapped no-op minus a bare no-op
    def noop() -> None:
        return None
    w = timed(noop, "_noop")
    n = 200_000
    bare = min(_per_call_us(noop, n, 1)[0] for _ in range(3))
    wrapped = min(_per_call_us(w, n, 1)[0] for _ in range(3))
    overhead_us = max(0.0, wrapped - bare)
    del acc["_noop"]

    saved = []
    try:
        for mod, cls, meth, label, _ in _TICK_PARTS:
            try:
                m = importlib.import_module(mod)
            except ImportError:            # mav._fastpath not built: its parts run in Python
                continue
            c = m if cls is None else getattr(m, cls)
            orig = c.__dict__[meth]
            saved.append((c, meth, orig))
            if meth == "exchange_call":     # it returns the callable the master's loop calls
                setattr(c, meth, _timed_result(orig, timed, label))
            else:
                setattr(c, meth, timed(orig, label))
        # the compiled parts bound as instance attributes when their object is set up (the
        # controller, mav/fastpath.py; the FMI stepper, cosim/plant/fmu.py; the ODOMETRY
        # encoder, mav/hil.py; the client's setpoint, mav/client.py): timed there
        from cosim.plant.fmu import Plant
        from mav.cascade import QuadCascade
        from mav.client import OffboardClient
        from mav.hil import HilSimulatorCodec
        for c, setup, attr, label in (
                (QuadCascade, "__init__", "update", _CTRL),
                (Plant, "_use_stepper", "step", "plant step"),
                (HilSimulatorCodec, "__init__", "encode_odometry", "ODOMETRY encode"),
                (OffboardClient, "__init__", "set_position_target", _SETPOINT)):
            orig = c.__dict__[setup]
            saved.append((c, setup, orig))
            setattr(c, setup, _timing_attr(orig, attr, timed, label))
        res = run_scenario(load_scenario(SEED), RunOptions(mode="mil"))
    finally:
        for c, meth, orig in reversed(saved):
            setattr(c, meth, orig)
    ticks = res.ticks
    parts: dict[str, float] = {}
    # (label, parent) once each: a part may have two implementations (Python, compiled)
    labels = list(dict.fromkeys((label, parent) for _, _, _, label, parent in _TICK_PARTS))
    # a part never called on its own is not a row: the compiled tick (mav/csrc/tick.c) runs
    # the drain of setpoints, the modes and the battery step inside its one call, so they
    # are in "HIL exchange (onboard): rest" then
    labels = [(lb, pa) for lb, pa in labels if acc.get(lb, [0, 0])[1] > 0 or pa is None]
    for label, _parent in labels:
        ns = acc.get(label, [0, 0])[0]
        inner = sum(acc.get(lb, [0, 0])[1] for lb, pa in labels if pa == label)
        parts[label] = (ns / 1e3 - inner * overhead_us) / ticks
    top_calls = sum(acc.get(lb, [0, 0])[1] for lb, pa in labels if pa is None)
    top = sum(parts[lb] for lb, pa in labels if pa is None)
    loop_us = res.loop_wall_s * 1e6 / ticks - top_calls * overhead_us / ticks
    for label, parent in labels:
        if parent is not None:
            parts[parent + ": rest"] = parts.get(parent + ": rest", parts[parent]) - parts[label]
    parts["master loop itself (record, exit checks, taps)"] = loop_us - top
    st = res.onboard_stats
    sc = res.scenario
    return {"ticks": ticks, "timer_overhead_us": overhead_us, "loop_us_per_tick": loop_us,
            "parts_us_per_tick": parts,
            "setpoints_per_tick": st.get("setpoints", 0) / ticks,
            "telemetry_per_tick": (st.get("tx_api", 0) + st.get("tx_gcs", 0)) / ticks,
            "frames_per_tick": 1.0 / sc.timing.camera_every}


def floor_estimate(res: dict[str, Any]) -> dict[str, float]:
    """The work a MIL tick cannot skip, each part measured alone (no glue, warm caches), in
    us per tick: plant, controller, the MAVLink encode + decode of ODOMETRY, of
    HIL_ACTUATOR_CONTROLS, of the app's setpoints and of the telemetry at the rates of the
    seed mission, and the camera frame + image processing spread over the camera period."""
    c = res["codec"]
    b = res["mil_tick_breakdown"]

    def m(d: dict[str, Any]) -> float:
        return d["median"]
    parts = {
        "plant step": m(res["plant_step"]),
        "controller": m(res["controller_update"]),
        "ODOMETRY encode + decode": m(c["odometry_encode_ours"]) + m(c["odometry_decode_ours"]),
        "HIL_ACTUATOR_CONTROLS encode + decode": m(c["actuators_encode_ours"])
        + m(c["actuators_decode_ours"]),
        "setpoints encode + decode": b["setpoints_per_tick"] * (
            m(c["setpoint_encode_ours"]) + m(c["setpoint_decode_ours"])),
        "telemetry encode + decode": b["telemetry_per_tick"] * (
            m(c["telemetry_encode_ours"]) + m(c["telemetry_decode_ours"])),
        "render + image processing": b["frames_per_tick"] * (m(res["render"]) + m(res["ips"])),
    }
    parts["total"] = sum(parts.values())
    parts["max real-time factor"] = 5000.0 / parts["total"]
    return parts
