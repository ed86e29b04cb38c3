"""How to run a scenario (the options that are not part of the scenario itself)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cosim.sim.hooks import Hooks


@dataclass
class RunOptions:
    mode: str = "mil"                 # 'mil' | 'sil'
    realtime: bool = False
    speed: float = 1.0                # real-time factor target when realtime
    video: bool = False               # keep camera frames for a video
    png_every: int = 0                # save every Nth frame as PNG (0: none)
    progress: bool = False
    out_dir: Path | None = None       # where the SIL onboard log goes (None: a temp dir)
    hil_timeout_s: float = 2.0        # s wall clock without a HIL answer -> onboard failed
    # SIL lockstep: wait this long (us wall clock) for the other process's HIL datagram by
    # polling before sleeping in the kernel (a wake-up per datagram otherwise; the other
    # side's tick takes tens of us). None: 200 us with >= 2 CPUs and not real time, else 0.
    # Results do not depend on it (lockstep), only the wall time and CPU use do.
    hil_spin_us: float | None = None
    # SIL: the simulator (HIL) link between the two processes: "udp" (loopback, as any MAVLink
    # link) or "unix" (a Unix-domain datagram socket; measured no faster in the seed mission).
    # The api and gcs links stay UDP (as PX4 SITL's simulator link is TCP while its MAVLink
    # links are UDP).
    # Results do not depend on it.
    hil_transport: str = "udp"
    # MIL: the HIL exchange between the master and the vehicle in this process. "framed": a
    # datagram of MAVLink frames each way, as over a socket (SIL's); "typed": the records
    # those frames decode to, handed over without the frames (cosim/sim/onboard.py; tested to
    # give the same series, tlog and counters); "auto": typed unless fault hooks are on the
    # links (they act on datagrams). Results do not depend on it.
    hil_exchange: str = "auto"
    app_override: Any = None          # an app object to use instead of the scenario's
    # sitl: the onboard stack's API and GCS links are real UDP sockets for outside clients,
    # {'gcs': ((bind_host, port), (remote_host, port)), 'api': (...)}; MIL only
    external_links: dict[str, tuple[tuple[str, int], tuple[str, int]]] | None = None
    sitl: bool = False                # no mission or arena exits: only crash, time, Ctrl-C
    hooks: Hooks | None = None        # fault injection (cosim.sim.hooks); None: no faults
    mcap: bool = False                # also write the run as run.mcap (Foxglove schemas)
    images: str = "jpeg"              # camera frames in run.mcap: jpeg | png | raw
    live: Any = None                  # a cosim.outputs.live.LiveView serving the run live
    signing_key: bytes | None = None  # 32 bytes: the vehicle signs api/gcs, rejects unsigned
    # a camera whose frames are delayed (`[camera] latency_s`, `jitter_s`): True renders each
    # frame on a worker thread from its capture to its delivery (cosim/sensors/stream.py),
    # False at capture, in the loop; None: on the worker when the run may use more than one
    # core (cosim/cvthreads.py: a single run on a machine with free cores, not a study
    # worker). Results do not depend on it, only the wall time does.
    pipeline: bool | None = None
