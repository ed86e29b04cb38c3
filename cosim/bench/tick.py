"""`cosim bench`'s tick breakdown: where the MIL tick of the seed mission goes, part by part,
and the floor (the essentials of a tick measured alone)."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

from cosim.bench.common import seed_scenario

# (module, class, method, label, parent label or None, set-up method or None): the parts of a
# MIL tick, timed by wrapping them (bench_tick_breakdown). With a set-up method: `method` is an
# instance attribute that set-up binds (the noise-free sensor's itemgetter, the FMI stepper),
# timed on each instance as it is set up
_HIL = "HIL exchange (onboard)"
_TICK_PARTS = (
    ("cosim.sensors.odometry", "OdometrySensor", "measure", "sensor model", None, "__init__"),
    # sensor-fed (feed = "hil"): the sensor models, the vehicle's estimator, the answer split
    # (the suite is a compiled extension type: timed through the feed that calls it)
    # (each part's framed and typed forms, cosim/sim/onboard.py, under one label: a run
    # uses one of them)
    ("cosim.sim.estimate", "SensorFeed", "encode_odometry", "sensor models + HIL_SENSOR & co.",
     None, None),
    ("cosim.sim.estimate", "SensorFeed", "record_odometry", "sensor models + HIL_SENSOR & co.",
     None, None),
    ("cosim.sensors.down", "DownwardCamera", "render", "camera render (per tick)", None, None),
    ("cosim.apps.line_follower", "LineFollowerApp", "on_frame", "app on_frame: IPS", None, None),
    ("cosim.apps.line_follower", "LineFollowerApp", "on_tick", "app on_tick", None, None),
    ("mav.client", "OffboardClient", "poll", "  client poll (telemetry in)", "app on_tick",
     None),
    ("mav.client", "OffboardClient", "set_position_target", "  setpoint encode+send",
     "app on_tick", None),
    ("mav.hil", "HilSimulatorCodec", "encode_odometry", "ODOMETRY encode", None, None),
    ("mav.hil", "HilSimulatorCodec", "record_odometry", "ODOMETRY encode", None, None),
    ("cosim.sim.onboard", "OnboardHandle", "exchange", _HIL, None, None),
    ("cosim.sim.onboard", "OnboardHandle", "exchange_record", _HIL, None, None),
    ("mav.estimator.core", "Estimator", "estimate", "  onboard estimator (decode + filters)",
     _HIL, None),
    ("mav.estimator.core", "Estimator", "estimate_parts",
     "  onboard estimator (decode + filters)", _HIL, None),
    ("mav.onboard.channels", "LinkInput", "drain", "  onboard drain api+gcs", _HIL, None),
    ("mav.onboard.vehicle", "Onboard", "_step_modes", "  onboard modes", _HIL, None),
    ("mav.cascade", "QuadCascade", "update", "  onboard controller", _HIL, None),
    ("mav.onboard.telemetry", "Telemetry", "publish", "  onboard telemetry out", _HIL, None),
    ("mav.hil", "HilSimulatorCodec", "decode_actuators", "HIL_ACTUATOR_CONTROLS decode", None,
     None),
    ("mav.hil", "HilSimulatorCodec", "decode_record", "HIL_ACTUATOR_CONTROLS decode", None,
     None),
    ("cosim.sim.estimate", "SensorFeed", "decode_actuators", "HIL answer + estimate decode",
     None, None),
    ("cosim.sim.estimate", "SensorFeed", "decode_record", "HIL answer + estimate decode",
     None, None),
    ("cosim.plant.fmu", "Plant", "step", "plant step", None, "_use_stepper"),
)
MASTER = "master loop itself (record, exit test, taps)"
# compiled extension types cannot have a class attribute replaced: their instances are timed
# one by one, wrapped as the function that makes them in a run returns them (module, name,
# and the attribute of what it returns that is the instance, or None: the instance itself)
_IMMUTABLE = 1 << 8          # Py_TPFLAGS_IMMUTABLETYPE
# (the battery's step is no longer a row: compiled, it is a few dozen instructions, less than
# timing a call to it)
MADE_BY = {"QuadCascade": ("mav.control", "make_controller", None),
           "Onboard": ("mav.onboard", "Onboard", None),
           "OffboardClient": ("mav.client", "OffboardClient", None),
           "LineFollowerApp": ("cosim.apps.line_follower", "LineFollowerApp", None),
           "LinkInput": ("mav.onboard", "Onboard", "input"),
           "Telemetry": ("mav.onboard", "Onboard", "telemetry"),
           "Estimator": ("mav.onboard", "Onboard", "estimator")}


def _timing_attr(setup: Callable, attr: str, timed: Callable, label: str) -> Callable:
    """A set-up method that then times the instance's `attr` (what set-up bound, or the
    method) as an instance attribute."""
    def wrapper(self: Any, *a: Any, **kw: Any) -> None:
        setup(self, *a, **kw)
        setattr(self, attr, timed(getattr(self, attr), label))
    return wrapper


def _wrap(label: str, timed: Callable) -> list[tuple[Any, str, Any]]:
    """Wrap every implementation of the part `label` in `timed`; the (owner, name, original)
    to put back."""
    import importlib

    saved = []
    for mod, cls, meth, lb, _, setup in _TICK_PARTS:
        if lb != label:
            continue
        m = importlib.import_module(mod)
        c = m if cls is None else getattr(m, cls)
        name = setup or meth
        orig = c.__dict__[name]
        if cls in MADE_BY and isinstance(c, type) and c.__flags__ & _IMMUTABLE:
            # a compiled extension type (immutable: its methods cannot be replaced): wrap the method
            # on each instance its maker returns (an instance attribute; the calls that
            # matter look the method up on the instance)
            fmod, fname, part = MADE_BY[cls]
            owner = importlib.import_module(fmod)
            make = getattr(owner, fname)
            saved.append((owner, fname, make))
            setattr(owner, fname, _timed_instances(make, meth, timed, label, part))
            continue
        saved.append((c, name, orig))
        if setup is not None:
            setattr(c, setup, _timing_attr(orig, meth, timed, label))
        else:
            setattr(c, meth, timed(orig, label))
    return saved


def _timed_instances(make: Callable, attr: str, timed: Callable, label: str,
                     part: str | None = None) -> Callable:
    """`make` whose results (or their `part`) have their `attr` timed under `label` (an
    instance attribute: a compiled caller's C call of a cpdef method finds it too)."""
    def wrapper(*a: Any, **kw: Any) -> Any:
        obj = make(*a, **kw)
        inst = obj if part is None else getattr(obj, part)
        setattr(inst, attr, timed(getattr(inst, attr), label))
        return obj
    return wrapper


def bench_tick_breakdown(repeats: int = 3, sets: dict[str, Any] | None = None
                         ) -> dict[str, Any]:
    """Where the MIL tick of the seed mission goes, in us per tick (averaged over the run).

    One part timed per run: each part of `_TICK_PARTS` is wrapped in a timer alone, in its own
    run of the mission, so no other timer sits inside or around it; its figure is the time
    inside its calls, less what a timed trivial call measures inside (a clock read and the
    call through the wrapper). Each timed run follows an untimed one; over `repeats` rounds,
    each figure (a part's, the untimed tick's) is its least: the shared host's speed drifts
    between runs, and the least is the figure least disturbed by it. A part's "rest" is its
    time less its inner parts' (measured in their own runs); the master loop's own work
    (recording, the exit test, tlog taps, the loop) is the untimed tick less the top-level
    parts. (Timing all
    parts in one run, as this did before, made the run ~1.9x slower than an untimed one: the
    timers' Python frames called from the compiled tick cost far more than a timer measured
    alone, and that went into the master loop's and the onboard tick's figures.)
    """
    from cosim.sim.master import RunOptions, run_scenario

    sc = seed_scenario(sets)   # truth-fed; {"sensors.feed": "hil"}: the sensor-fed tick
    acc: dict[str, list[int]] = {}
    clock = time.perf_counter_ns

    def timed(fn: Callable, label: str) -> Callable:
        cell = acc.setdefault(label, [0, 0])

        def wrapper(*a: Any, **kw: Any) -> Any:
            t0 = clock()
            try:
                return fn(*a, **kw)
            finally:
                cell[0] += clock() - t0
                cell[1] += 1
        return wrapper

    # what the time inside a timed call holds besides the call's work (one clock read, the
    # call through the wrapper): measured on a trivial compiled call, taken out per call
    probe_us = []
    for _ in range(3):
        acc.clear()
        probe = timed(abs, "_probe")
        for _ in range(100_000):
            probe(1)
        ns, calls = acc["_probe"]
        probe_us.append(ns / 1e3 / calls)
    clock_us = min(probe_us)
    labels = list(dict.fromkeys((label, parent) for _, _, _, label, parent, _ in _TICK_PARTS))
    untimed: list[float] = []
    before: dict[str, list[float]] = {label: [] for label, _ in labels}   # untimed, by label
    got: dict[str, list[float]] = {label: [] for label, _ in labels}
    calls: dict[str, int] = {}
    res = None
    for _ in range(repeats):          # rounds: the host's speed drifts; each figure's least
        for label, _parent in labels:
            res = run_scenario(sc, RunOptions(mode="mil"))
            untimed.append(res.loop_wall_s * 1e6 / res.ticks)
            before[label].append(untimed[-1])
            acc.clear()
            saved = _wrap(label, timed)
            try:
                timed_res = run_scenario(sc, RunOptions(mode="mil"))
            finally:
                for c, meth, orig in reversed(saved):
                    setattr(c, meth, orig)
            if timed_res.ticks != res.ticks:
                raise RuntimeError(f"timing {label!r} changed the flight "
                                   f"({timed_res.ticks} ticks)")
            ns, n_calls = acc.get(label, [0, 0])
            calls[label] = n_calls
            got[label].append((ns / 1e3 - n_calls * clock_us) / res.ticks)
    assert res is not None
    ticks = res.ticks
    # the untimed tick as a least of `repeats` runs too (the least of all of them would be
    # lower than any part's, which has only `repeats` tries): the median over the parts' slots
    loop_us = statistics.median(min(v) for v in before.values())
    # a part never called on its own is not a row (truth-fed: the sensor models; sensor-fed:
    # the ODOMETRY codec)
    labels = [(lb, pa) for lb, pa in labels if calls[lb] > 0]
    parts = {lb: min(got[lb]) for lb, _ in labels}
    for label, parent in labels:
        if parent is not None:
            parts[parent + ": rest"] = parts.get(parent + ": rest", parts[parent]) - parts[label]
    parts[MASTER] = loop_us - sum(parts[lb] for lb, pa in labels if pa is None)
    st = res.onboard_stats
    return {"ticks": ticks, "timer_overhead_us": clock_us, "loop_us_per_tick": loop_us,
            "loop_us_per_tick_runs": untimed, "parts_us_per_tick": parts,
            "repeats": repeats,
            "method": "one part timed per run, the tick untimed between; least of the rounds",
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
