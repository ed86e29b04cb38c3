"""`cosim montecarlo` and the study options of `cosim sweep` (the parsers and handlers)."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from cosim.cli_checks import add_numerics, enter_numerics
from cosim.errors import ScenarioError

MONTECARLO_EXAMPLES = """examples:
  cosim montecarlo scenarios/mambo_seed_track.toml -n 200 --seed 1 \\
      --vary 'wind.n_mps=uniform(0,1.5)' \\
      --vary 'sensors.flow.flow_noise_rad_s=truncnormal(0.02,0.01,0,0.05)' \\
      --vary 'vehicle.start.yaw_deg=normal(0,15)'
  cosim montecarlo scenarios/scripted_square.toml -n 50 --vary 'wind.e_mps=choice(0,0.5,1)' \\
      --scheduler tcp://HOST:8786
distributions: uniform(a,b) normal(mu,sigma) truncnormal(mu,sigma,lo,hi) loguniform(a,b)
  choice(v1,v2,...); a draw outside the field's range is an error (no clipping).
The same command again continues an interrupted study (runs in results.csv are skipped).
exit status: 0 study done, 1 some runs failed (raised or a component error), 2 bad input,
130 after Ctrl-C, 143 after SIGTERM (the runs cut by it get no row: the same command flies
them again)."""


def add_study_options(p: argparse.ArgumentParser, *, default_executor: str) -> None:
    p.add_argument("--executor", choices=("dask", "serial"), default=default_executor,
                   help=f"where runs go (default {default_executor})")
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="an existing Dask scheduler (or env COSIM_DASK_SCHEDULER); "
                        "default: a local cluster, one worker per core")
    p.add_argument("--workers", type=int, default=None,
                   help="local workers (default: all cores)")
    p.add_argument("--keep-runs", action="store_true",
                   help="keep each run's folder in OUT/runs/NNNNNN (off: table only)")
    p.add_argument("--mcap", action="store_true",
                   help="with --keep-runs: each kept run folder also gets run.mcap")
    p.add_argument("--retry-failed", action="store_true", help="re-run the failed rows")
    p.add_argument("--limit", type=int, default=None, metavar="K",
                   help="run at most K more runs, then stop (a study in chunks)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    add_numerics(p)


def add_montecarlo(add) -> None:
    m = add("montecarlo", help="many runs with parameters drawn at random (seeded)")
    m.epilog = MONTECARLO_EXAMPLES
    m.add_argument("scenario")
    m.add_argument("-n", "--runs", type=int, required=True, help="number of runs")
    m.add_argument("--seed", type=int, default=0, help="the study seed (default 0)")
    m.add_argument("--vary", action="append", required=True, metavar="KEY=DIST(ARGS)")
    m.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a fixed override for every run")
    m.add_argument("--mode", choices=("mil", "sil"), default="mil")
    m.add_argument("--out", type=Path, help="study folder (default runs/mc-<scenario>)")
    add_study_options(m, default_executor="dask")


def _engine_kw(args) -> dict:
    if args.limit is not None and args.limit < 0:
        raise ScenarioError("--limit", args.limit, "an integer >= 0")
    if args.workers is not None and args.workers < 1:
        raise ScenarioError("--workers", args.workers, "an integer >= 1")
    if args.scheduler is not None and args.executor != "dask":
        raise ScenarioError("--scheduler", args.scheduler, "only with --executor dask")
    if args.scheduler is not None:
        from cosim.executors import scheduler_address

        scheduler_address(args.scheduler)          # a malformed address: refused now
    if args.scheduler is not None and args.workers is not None:
        raise ScenarioError("--workers", args.workers, "only without --scheduler (an existing "
                            "cluster has the workers it has)")
    return {"executor": args.executor, "scheduler": args.scheduler, "workers": args.workers,
            "limit": args.limit, "retry_failed": args.retry_failed,
            "progress": not args.quiet}


def montecarlo(args) -> int:
    from cosim.studies.deps import load_scenario, one_each
    from cosim.studies.dists import parse_varies
    from cosim.studies.study import montecarlo_jobs

    sc = load_scenario(args.scenario)
    dists = parse_varies(args.vary)
    sc = enter_numerics(args, sc)
    sets = one_each(args.set)
    out = args.out or Path("runs") / f"mc-{sc.name}"
    jobs, manifest = montecarlo_jobs(sc, dists, args.runs, args.seed, sets, out,
                                     mode=args.mode, keep_runs=args.keep_runs,
                                     mcap=_mcap(args))
    return _go(jobs, manifest, out, args, f"montecarlo: {len(jobs)} runs of {sc.name}")


def sweep(args) -> int:
    from cosim.studies.deps import load_scenario, parse_sets
    from cosim.studies.study import sweep_jobs

    sc = enter_numerics(args, load_scenario(args.scenario))
    out = args.out or Path("runs") / f"sweep-{sc.name}"
    jobs, manifest = sweep_jobs(sc, parse_sets(args.set, multi=True), out, mode=args.mode,
                                keep_runs=args.keep_runs, mcap=_mcap(args))
    return _go(jobs, manifest, out, args, f"sweep: {len(jobs)} runs of {sc.name}")


def _mcap(args) -> bool:
    if args.mcap and not args.keep_runs:
        from cosim.errors import ScenarioError

        raise ScenarioError("--mcap", True, "together with --keep-runs (an MCAP per kept run)")
    return bool(args.mcap)


def program() -> str:
    """This `cosim` as a user can type it again: `cosim` when that is the one on the PATH,
    else the path it was started by (`.venv/bin/cosim`); `cosim` when started otherwise."""
    import os
    import shutil

    a = sys.argv[0] if sys.argv else ""
    if os.path.basename(a) != "cosim":
        return "cosim"
    on_path = shutil.which("cosim")
    if on_path and os.path.realpath(on_path) == os.path.realpath(a):
        return "cosim"
    return a


def _go(jobs, manifest, out: Path, args, title: str) -> int:
    from cosim.studies.engine import StudyError, StudyInterrupted
    from cosim.studies.study import TABLE, run_in_folder

    kw = _engine_kw(args)
    manifest["program"] = program()
    manifest["command"] = " ".join(shlex.quote(a) for a in [program(), *sys.argv[1:]])
    where = args.scheduler or ("a local Dask cluster" if args.executor == "dask"
                               else f"the {args.executor} executor")
    print(f"{title} on {where}; results in {out / TABLE}", file=sys.stderr, flush=True)
    try:
        stats, rows, report = run_in_folder(jobs, manifest, out, **kw)
    except StudyInterrupted as exc:
        print(f"cosim: {exc}; the same command continues the study", file=sys.stderr)
        return 130
    except StudyError as exc:
        print(f"cosim: {exc}", file=sys.stderr)
        return 1
    print(f"{stats.ran} runs now ({stats.failed} failed), {stats.skipped} already done, "
          f"{stats.wall_s:.1f} s", file=sys.stderr)
    if report is None:
        print(f"{len(rows)} of {len(jobs)} runs in {out / TABLE}; the same command continues",
              file=sys.stderr)
        return 0
    s = report["success"]
    lo, hi = s["wilson95"]
    print(f"success {s['passed']}/{s['runs']} (Wilson 95 % {100 * lo:.1f}-{100 * hi:.1f} %); "
          f"report in {out / 'report.md'}")
    if report["failed"]:
        return 1
    if manifest["kind"] == "sweep" and len(manifest["params"]) == 1:
        from cosim.studies.sweep import plot_sweep

        print(f"sweep figure in {plot_sweep(rows, manifest['params'][0], out)}")
    if manifest["kind"] == "sweep" and s["passed"] < s["runs"]:
        return 1
    return 0
