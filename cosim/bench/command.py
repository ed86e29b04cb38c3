"""`cosim bench`: the cost of every part, and the real-time factor of the seed mission.

Each figure is measured in this one run, on this machine, repeated `repeats` times; we report
the median and the spread (min..max) of the per-repeat figures. Ratios (e.g. our codec vs
pymavlink) come from the same run. No figure here is a pass/fail test: machines are shared
and noisy; the targets are printed beside the figures for the reader.
"""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from cosim.bench.common import (  # noqa: F401
    ROOT,
    SEED,
    _per_call_us,
    _stat,
    seed_scenario,
)
from cosim.bench.flood import bench_flood, format_flood
from cosim.bench.paper2 import bench_paper2, format_paper2
from cosim.bench.tick import bench_tick_breakdown, floor_estimate
from onesource import switch as compiled

QUICK_FLOOD = {"t_final_s": 5.0, "flood_wall_s": 2.0, "realtime_s": 1.0}   # --quick: short


def machine() -> dict[str, Any]:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "system": f"{platform.system()} {platform.release()} {platform.machine()}"}


def bench_plant(n: int, repeats: int) -> dict[str, Any]:
    from cosim.plant.fmu import Plant
    from cosim.scenario.vehicles import MAMBO

    u = MAMBO.u_hover
    out = {}
    for key, stepper in (("stepper", None), ("ctypes", False)):
        with Plant(MAMBO, x0=0.0, y0=0.0, stepper=stepper) as plant:
            step = plant.step
            out[key] = _stat(_per_call_us(lambda step=step: step(u, u, u, u), n, repeats),
                             "us/tick", 3.5)
            out[key]["compiled"] = plant._stepper is not None
    d = out["stepper"]
    d["ctypes"] = out["ctypes"]
    return d


def bench_controller(n: int, repeats: int) -> dict[str, Any]:
    from mav.airframe import MAMBO
    from mav.control import make_controller
    from mav.types import Setpoint, VehicleState

    s, sp, out = VehicleState(), Setpoint(), [0.0] * 4
    s.z = -1.0
    sp.x, sp.y, sp.z, sp.yaw, sp.armed = 0.1, -0.1, -1.1, 0.0, True
    ctl = make_controller(MAMBO)
    d = _stat(_per_call_us(lambda: ctl.update(s, sp, out), n, repeats), "us/tick")
    d["implementation"] = compiled.describe()
    return d


def interpreted(figure: str, *args: Any, **kw: Any) -> dict[str, Any]:
    """A figure of this module measured on the same sources interpreted: in a child process
    with COSIM_COMPILED=0 (a process runs one or the other, onesource/switch.py)."""
    code = ("import json, sys\nfrom cosim.bench import command as bench\n"
            f"print(json.dumps(bench.{figure}(*{args!r}, **{kw!r})))")
    env = dict(os.environ, COSIM_COMPILED="0")
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                       check=False)
    if p.returncode != 0:
        raise RuntimeError(f"the interpreted {figure} failed: {p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def bench_codec(n: int, repeats: int) -> dict[str, Any]:
    """Encode + decode of the per-tick messages, our codec and pymavlink's, in one run."""
    from pymavlink.dialects.v20 import common as mavlink2

    from mav.hil import HilSimulatorCodec

    codec = HilSimulatorCodec()
    meas = (57.0, 95.0, -1.1, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.0, 0.01, 0.02, 0.0)
    pm = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    nan21 = [math.nan] + [0.0] * 20
    out: dict[str, Any] = {}
    out["odometry_encode_ours"] = _stat(
        _per_call_us(lambda: codec.encode_odometry(5000, meas), n, repeats), "us/msg")

    def pm_encode():
        return pm.odometry_encode(5000, 1, 1, 57.0, 95.0, -1.1, [1, 0, 0, 0], 0.1, 0.2, 0.0,
                                  0.01, 0.02, 0.0, nan21, nan21, 0, 1, 100).pack(pm)
    out["odometry_encode_pymavlink"] = _stat(_per_call_us(pm_encode, n, repeats), "us/msg")
    data = pm_encode()
    pm2 = mavlink2.MAVLink(None)
    out["odometry_decode_pymavlink"] = _stat(
        _per_call_us(lambda: pm2.decode(bytearray(data)), n, repeats), "us/msg")
    act = pm.hil_actuator_controls_encode(5000, [0.5] * 4 + [0.0] * 12, 0, 1).pack(pm)
    out["actuators_decode_ours"] = _stat(
        _per_call_us(lambda: codec.decode_actuators(act), n, repeats), "us/msg")
    out["actuators_decode_pymavlink"] = _stat(
        _per_call_us(lambda: pm2.decode(bytearray(act)), n, repeats), "us/msg")
    # the rest of the MAVLink work of a tick, our codec (for the floor estimate)
    from mav import wire

    out["odometry_decode_ours"] = _stat(
        _per_call_us(lambda: wire.decode_odometry(data), n, repeats), "us/msg")
    out["actuators_encode_ours"] = _stat(_per_call_us(
        lambda: wire.encode_hil_actuator_controls(pm, 5000, 0.5, 0.5, 0.5, 0.5, 129), n,
        repeats), "us/msg")
    sp = wire.encode_set_position_target_local_ned(pm, 5, 1, 1, 1, 0xDF8, 1.0, 2.0, -1.1, 0.0,
                                                   0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    out["setpoint_encode_ours"] = _stat(_per_call_us(
        lambda: wire.encode_set_position_target_local_ned(
            pm, 5, 1, 1, 1, 0xDF8, 1.0, 2.0, -1.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), n,
        repeats), "us/msg")
    out["setpoint_decode_ours"] = _stat(_per_call_us(
        lambda: wire.decode_fast(wire.SET_POSITION_TARGET_LOCAL_NED, sp), n, repeats), "us/msg")
    lpn = wire.encode_local_position_ned(pm, 5, 1.0, 2.0, -1.1, 0.1, 0.2, 0.0)
    out["telemetry_encode_ours"] = _stat(_per_call_us(
        lambda: wire.encode_local_position_ned(pm, 5, 1.0, 2.0, -1.1, 0.1, 0.2, 0.0), n,
        repeats), "us/msg")
    out["telemetry_decode_ours"] = _stat(_per_call_us(
        lambda: wire.decode_fast(wire.LOCAL_POSITION_NED, lpn), n, repeats), "us/msg")
    for a, b in (("odometry_encode_pymavlink", "odometry_encode_ours"),
                 ("actuators_decode_pymavlink", "actuators_decode_ours")):
        out[f"ratio_{b}"] = out[a]["median"] / out[b]["median"]
    return out


def bench_udp_roundtrip(n: int, repeats: int) -> dict[str, Any]:
    """ODOMETRY -> HIL_ACTUATOR_CONTROLS through the onboard process over loopback UDP."""
    import tempfile

    from cosim.sim.sil import OnboardProcess
    from mav.hil import HilSimulatorCodec
    from mav.links import UdpLink

    codec = HilSimulatorCodec()
    api, gcs, hil = UdpLink(), UdpLink(), UdpLink()
    with tempfile.TemporaryDirectory() as d, OnboardProcess(
            "mambo", api.local_address, gcs.local_address, Path(d) / "onboard.log") as proc:
        hil.remote = ("127.0.0.1", proc.ports["hil"])
        hil.sock.setblocking(True)
        hil.sock.settimeout(5.0)
        meas = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        k = [0]

        def rt():
            k[0] += 1
            hil.sock.sendto(codec.encode_odometry(k[0] * 5000, meas), hil.remote)
            hil.sock.recv(65535)
            while api.recv() is not None or gcs.recv() is not None:
                pass
        samples = _per_call_us(rt, n, repeats)
    for link in (api, gcs, hil):
        link.close()
    return _stat(samples, "us/tick")


def bench_render_ips(n: int, repeats: int) -> dict[str, Any]:
    from cosim.apps.ips import ImageProcessor
    from cosim.load import load_scenario
    from cosim.sensors.camera import make_camera

    sc = load_scenario(SEED)
    cam = make_camera(sc.camera, sc.world, seed=0)
    p_W = [56.5, 95.0, -1.1]
    q = [0.9990482, 0.0, 0.0436194, 0.0]  # 5 deg nose up
    img = cam.render(p_W, q)
    ips = ImageProcessor()
    return {
        "render": _stat(_per_call_us(lambda: cam.render(p_W, q), n, repeats), "us/frame",
                        1000.0),
        "ips": _stat(_per_call_us(lambda: ips.process(img), n, repeats), "us/frame", 200.0),
    }


def bench_front(n: int, repeats: int) -> dict[str, Any]:
    """The front camera in paper 2's E2 room, along a moving path (issue 10 targets: 8 ms at
    856 x 480, 2.5 ms at 428 x 240, one core)."""
    import math

    from cosim.load import load_scenario
    from cosim.sensors.front import FrontCamera, FrontCameraConfig
    from mav.rotations import quat_from_euler

    sc = load_scenario(ROOT / "scenarios" / "bebop2_room_e2.toml")
    poses = [((4.0 * i / n, 0.3 * math.sin(0.1 * i), -1.0 - 0.2 * math.sin(0.05 * i)),
              quat_from_euler(0.03 * math.sin(0.2 * i), -0.02,
                              math.radians(25 * math.sin(0.03 * i))))
             for i in range(n)]
    out = {}
    for w, h, target in ((856, 480, 8000.0), (428, 240, 2500.0)):
        cam = FrontCamera(sc.world, FrontCameraConfig.from_dict({"width": w, "height": h}))
        it = iter(())

        def frame(cam=cam) -> None:
            nonlocal it
            try:
                p, q = next(it)
            except StopIteration:
                it = iter(poses)
                p, q = next(it)
            cam.render(p, q)

        out[f"front_{w}x{h}"] = _stat(_per_call_us(frame, n, repeats), "us/frame", target)
    return out


def bench_mission(mode: str, repeats: int, sets: dict[str, Any] | None = None,
                  **opts: Any) -> dict[str, Any]:
    from cosim.sim.master import RunOptions, run_scenario

    sc = seed_scenario(sets)
    rtf, loop_rtf, sim = [], [], []
    reason = ""
    for _ in range(repeats):
        res = run_scenario(sc, RunOptions(mode=mode, **opts))
        rtf.append(res.real_time_factor)
        loop_rtf.append(res.loop_real_time_factor)
        sim.append(res.t_end_s)
        reason = res.exit_reason.value
    target = 150.0 if mode == "mil" else 40.0     # issue 16
    d = _stat(loop_rtf, "x real time", target, higher_is_better=True)
    d["sim_time_s"] = sim[0]
    d["exit_reason"] = reason
    d["us_per_tick"] = 1e6 * sc.timing.tick_s / d["median"]
    d["end_to_end"] = _stat(rtf, "x real time", target, higher_is_better=True)
    return d


HIL_FEED = {"sensors.feed": "hil"}     # the seed mission on the vehicle's estimate


def bench_estimate_pairs(pairs: int) -> dict[str, Any]:
    """Issue 27's ratio: the seed mission MIL on the estimate against the truth-fed one, flown
    in pairs back to back (truth-fed, then estimate-fed) so that both of a pair see the same
    host; the ratio is the median of the pairs' ratios (a shared host's speed drifts by more
    than the difference between two runs minutes apart)."""
    truth = bench_mission("mil", 1)
    est = bench_mission("mil", 1, HIL_FEED)
    ratios = [est["median"] / truth["median"]]
    truths, ests = [truth["median"]], [est["median"]]
    for _ in range(pairs - 1):
        t, e = bench_mission("mil", 1)["median"], bench_mission("mil", 1, HIL_FEED)["median"]
        truths.append(t)
        ests.append(e)
        ratios.append(e / t)
    d = {**est, **_stat(ests, "x real time")}
    d["truth_fed_pairs"] = _stat(truths, "x real time")
    d["ratio_pairs"] = ratios
    d["ratio_to_truth_fed"] = statistics.median(ratios)
    d["target_ratio"] = 0.6
    d["target"] = 0.6 * d["truth_fed_pairs"]["median"]
    d["meets_target"] = d["ratio_to_truth_fed"] >= 0.6
    return d


def run(quick: bool = False) -> dict[str, Any]:
    n, r = (2000, 3) if quick else (20000, 7)
    res: dict[str, Any] = {"machine": machine(), "quick": quick}
    res["plant_step"] = bench_plant(n, r)
    res["controller_update"] = bench_controller(n, r)
    res["controller_update"]["python_reference"] = interpreted("bench_controller", n, r)
    res["codec"] = bench_codec(n, r)
    res["udp_hil_roundtrip"] = bench_udp_roundtrip(n // 4, r)
    res.update(bench_render_ips(max(200, n // 20), r))
    res["front"] = bench_front(50 if quick else 200, r)
    from cosim.bench.vision import bench_vision

    res["vision"] = bench_vision(20 if quick else 100, r, _per_call_us, _stat)
    mr = 1 if quick else 3
    res["mission_mil"] = bench_mission("mil", mr)
    res["mission_sil"] = bench_mission("sil", mr)
    res["mission_sil_nospin"] = bench_mission("sil", mr, hil_spin_us=0.0)
    res["mission_sil_unix"] = bench_mission("sil", mr, hil_transport="unix")
    # issue 27: on the estimate (sensor models, HIL_SENSOR & co., the onboard estimator);
    # target >= 0.6x the truth-fed MIL run of the same build, in interleaved pairs
    res["mission_mil_estimate"] = bench_estimate_pairs(5 if quick else 7)
    # the same sources interpreted (COSIM_COMPILED=0: the plant through ctypes too)
    res["mission_mil_python"] = interpreted("bench_mission", "mil", mr)
    res["mission_sil_python"] = interpreted("bench_mission", "sil", mr, hil_spin_us=0.0)
    res["sil_over_mil_time"] = res["mission_mil"]["median"] / res["mission_sil"]["median"]
    res["mil_tick_breakdown"] = bench_tick_breakdown(repeats=mr)
    # one round (~2 min on the whole mission; --quick: its first 20 s, ~40 s): the sensor
    # models and the estimator as lines of their own
    res["mil_tick_breakdown_estimate"] = bench_tick_breakdown(
        repeats=1, sets={**HIL_FEED, "timing.t_final_s": 20.0} if quick else HIL_FEED)
    res["floor_us_per_tick"] = floor_estimate(res)
    # issue 14 item 9: SIL under a UDP flood, lockstep and real time (cosim/bench/flood)
    res["flood"] = bench_flood(**(QUICK_FLOOD if quick else {}))
    res["paper2"] = bench_paper2(quick)     # issue 29: E2-E4, the front-camera tick
    from cosim.bench.numerics import bench_numerics

    if not quick:                  # issue 39: what portable costs (--numerics alone: 1.5 min)
        res["numerics"] = bench_numerics(3)
    from cosim.bench.peers import bench_peers

    res["peers"] = bench_peers(*((1, 20.0) if quick else (4,)))   # the lead over peers
    return res


def format_report(res: dict[str, Any]) -> str:
    m = res["machine"]
    lines = [f"machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, {m['system']}",
             f"{'figure':<34s}{'median':>10s}{'min':>10s}{'max':>10s}  unit         target"]

    def row(name: str, d: dict[str, Any]) -> None:
        tgt = ""
        if "target" in d:
            op = ">=" if d["unit"].startswith("x") else "<="
            tgt = f"{op} {d['target']:g}  {'ok' if d['meets_target'] else 'MISSED'}"
        lines.append(f"{name:<34s}{d['median']:>10.2f}{d['min']:>10.2f}{d['max']:>10.2f}  "
                     f"{d['unit']:<12s} {tgt}")

    row("plant step (set+doStep+get)", res["plant_step"])
    row("  through ctypes (before)", res["plant_step"]["ctypes"])
    row("controller update", res["controller_update"])
    for k, v in res["codec"].items():
        if isinstance(v, dict):
            row(k.replace("_", " "), v)
    row("UDP HIL round trip (SIL)", res["udp_hil_roundtrip"])
    row("render 160x120 frame (down)", res["render"])
    for k, v in res["front"].items():
        row(f"render {k.split('_')[1]} frame (front)", v)
    row("image processing per frame", res["ips"])
    row("paper 2 matching (SIFT, 856x480)", res["vision"]["match_sift_856x480"])
    row("paper 2 servo cycle (LK+H+law)", res["vision"]["servo_cycle_856x480"])
    row("seed mission MIL (tick loop)", res["mission_mil"])
    row("seed mission MIL (end to end)", res["mission_mil"]["end_to_end"])
    row("seed mission SIL (tick loop)", res["mission_sil"])
    row("seed mission SIL (end to end)", res["mission_sil"]["end_to_end"])
    row("  SIL, HIL wait without spinning", res["mission_sil_nospin"])
    row("  SIL, HIL over a Unix socket", res["mission_sil_unix"])
    if "mission_mil_estimate" in res:
        est = res["mission_mil_estimate"]
        row("seed mission MIL on the estimate", est)
        row("  truth-fed, the same pairs", est["truth_fed_pairs"])
        n = len(est["ratio_pairs"])
        lines.append(f"  estimate-fed / truth-fed MIL (same run, median of {n}"
                     f" pairs flown back to back): {est['ratio_to_truth_fed']:.2f}x (target >= "
                     f"0.6x; pairs {', '.join(f'{r:.2f}' for r in est['ratio_pairs'])})  "
                     f"{'ok' if est['meets_target'] else 'MISSED'}")
    row("  MIL interpreted (same sources)", res["mission_mil_python"])
    row("  SIL interpreted (no spin)", res["mission_sil_python"])
    row("controller, interpreted", res["controller_update"]["python_reference"])
    cu = res["controller_update"]

    def ratio(a: str, b: str) -> float:
        return res[a]["median"] / res[b]["median"]
    lines.append(f"this run: {cu['implementation']}; compiled / interpreted (same run): MIL "
                 f"{ratio('mission_mil', 'mission_mil_python'):.2f}x, SIL "
                 f"{ratio('mission_sil', 'mission_sil_python'):.2f}x (spinning alone "
                 f"{ratio('mission_sil', 'mission_sil_nospin'):.2f}x; Unix-socket HIL / UDP "
                 f"{ratio('mission_sil_unix', 'mission_sil'):.2f}x), controller "
                 f"{cu['python_reference']['median'] / cu['median']:.1f}x")
    c = res["codec"]
    lines.append(f"ratios (same run): ODOMETRY encode pymavlink/ours "
                 f"{c['ratio_odometry_encode_ours']:.1f}x, actuator decode pymavlink/ours "
                 f"{c['ratio_actuators_decode_ours']:.1f}x; SIL time / MIL time "
                 f"{res['sil_over_mil_time']:.2f}")
    lines.append(f"seed mission: {res['mission_mil']['sim_time_s']:.1f} s simulated, exit "
                 f"{res['mission_mil']['exit_reason']}; MIL {res['mission_mil']['us_per_tick']:.1f}"
                 f" us/tick, SIL {res['mission_sil']['us_per_tick']:.1f} us/tick (tick loop; "
                 "end to end adds the setup: FMU load, world rasterisation, SIL start)")
    b = res["mil_tick_breakdown"]
    lines.append(f"MIL tick breakdown, us per tick (each part timed alone in its own run; the "
                 f"tick untimed: {b['loop_us_per_tick']:.1f} us; each the least of "
                 f"{b['repeats']} rounds; a timed trivial call's "
                 f"{b['timer_overhead_us']:.2f} us taken out per call):")
    for name, us in b["parts_us_per_tick"].items():
        lines.append(f"  {name:<48s}{us:>8.2f}")
    lines.append("  (the master loop's figure is the untimed tick less the parts, so it carries "
                 "their few-percent timing error; `cosim bench --instructions` counts it)")
    be = res.get("mil_tick_breakdown_estimate")
    if be is not None:
        lines.append(f"MIL tick breakdown on the estimate (feed = hil), us per tick (untimed "
                     f"{be['loop_us_per_tick']:.1f} us):")
        for name, us in be["parts_us_per_tick"].items():
            lines.append(f"  {name:<48s}{us:>8.2f}")
    f = res["floor_us_per_tick"]
    lines.append(f"floor: the essentials of a tick measured alone ({b['setpoints_per_tick']:.2f} "
                 f"setpoints, {b['telemetry_per_tick']:.2f} telemetry messages, "
                 f"{b['frames_per_tick']:.3f} frames per tick), us per tick:")
    for name, us in f.items():
        if name != "max real-time factor":
            lines.append(f"  {name:<48s}{us:>8.2f}")
    lines.append(f"  => at best {f['max real-time factor']:.0f}x real time with no glue at all")
    lines += format_flood(res["flood"])
    lines += format_paper2(res["paper2"])
    if "numerics" in res:
        from cosim.bench.numerics import format_numerics

        lines += format_numerics(res["numerics"])
    if "peers" in res:
        from cosim.bench.peers import format_peers

        lines += format_peers(res["peers"])
    return "\n".join(lines)


def main(quick: bool = False, json_path: Path | None = None, flood_only: bool = False,
         instructions: bool = False, live_only: bool = False,
         numerics_only: bool = False, peers_only: bool = False) -> int:
    if peers_only:     # the lead over peer simulators (bench/peers.py)
        from cosim.bench.peers import bench_peers, format_peers

        res = {"machine": machine(), "peers": bench_peers(*((1, 20.0) if quick else (4,)))}
        print("\n".join(format_peers(res["peers"])))
        return _write(res, json_path or Path("runs") / "bench_peers.json")
    if numerics_only:  # what the portable numerics cost (bench_numerics.py)
        from cosim.bench.numerics import bench_numerics, format_numerics

        res = {"machine": machine(), "numerics": bench_numerics(1 if quick else 3)}
        print("\n".join(format_numerics(res["numerics"])))
        return _write(res, json_path or Path("runs") / "bench_numerics.json")
    if live_only:      # what the live view costs the loop (bench_live.py)
        from cosim.bench.live import bench_live, format_live

        res = {"machine": machine(), "live": bench_live(**(
            {"t_final_s": 5.0, "repeats": 1} if quick else {}))}
        print("\n".join(format_live(res["live"])))
        return _write(res, json_path or Path("runs") / "bench_live.json")
    if instructions:   # instructions per tick, now and before (bench_instr.py)
        from cosim.bench.instructions import ToolMissing, bench_instructions, format_instructions

        try:        # both feeds: truth-fed (the figure's history) and the default's
            res = {"machine": machine(), "instructions": bench_instructions(),
                   "instructions_estimate": bench_instructions(feed="hil")}
        except ToolMissing as exc:
            print(f"cosim bench: {exc}", file=sys.stderr)
            return 2
        print("\n".join(format_instructions(res["instructions"]) + [""]
                        + format_instructions(res["instructions_estimate"])))
        return _write(res, json_path or Path("runs") / "bench_instructions.json")
    if flood_only:     # the flood figure alone (issue 14 item 9)
        res = {"machine": machine(), "quick": quick,
               "flood": bench_flood(**(QUICK_FLOOD if quick else {}))}
        m = res["machine"]
        print(f"machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, {m['system']}")
        print("\n".join(format_flood(res["flood"])))
    else:
        res = run(quick)
        print(format_report(res))
    return _write(res, json_path or Path("runs") / ("bench_flood.json" if flood_only
                                                    else "bench.json"))


def _write(res: dict[str, Any], path: Path) -> int:
    """The figures as JSON at path (its folder made); exit status 0."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=2))
    print(f"figures written to {path}")
    return 0
