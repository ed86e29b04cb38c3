"""`cosim test PATH...`: fly scenario files, folders of them or suite files, check each case's
criteria, its baseline and (on request) the equivalence of two modes; report on the screen, as
JUnit XML and as a Markdown page with plots; `--update` writes the baselines."""

from __future__ import annotations

import fnmatch
import json
import sys
import time
from pathlib import Path

from cosim.errors import ScenarioError
from cosim.regress import report
from cosim.regress.cases import MODES, NUMERICS, collect
from cosim.regress.flight import SIDES
from cosim.regress.runner import jobs_for, run_cases, update


def add_test(add) -> None:
    t = add("test", help="regression-test scenarios against their baselines")
    t.add_argument("paths", nargs="+", metavar="PATH",
                   help="scenario files, folders of them, or suite files ([[case]] tables)")
    t.add_argument("-k", dest="select", action="append", default=[], metavar="PATTERN",
                   help="only the cases whose id matches (a glob, or a part of the id)")
    t.add_argument("--update", action="store_true",
                   help="write the baselines of the selected cases from this run (a case "
                        "that fails its own criteria is not written); says what changed")
    t.add_argument("--baselines", type=Path, metavar="DIR",
                   help="the baselines' folder (default: baselines/ beside each scenario or "
                        "suite file, or the suite's [suite] baselines)")
    t.add_argument("--equivalence", metavar="A,B",
                   help="fly each case both ways and compare: mil,sil; interpreted,compiled; "
                        "native,portable (bit for bit for the first two, within the tubes for "
                        "native,portable)")
    t.add_argument("--require-baselines", action="store_true",
                   help="a case without a baseline fails (CI: a baseline forgotten)")
    t.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field in every case")
    t.add_argument("--seed", type=int, default=None, help="the seed of every case")
    t.add_argument("--mode", choices=MODES, default=None, help="every case in this mode")
    t.add_argument("--numerics", choices=NUMERICS, default=None,
                   help="every case with these numerics (default: its baseline's)")
    t.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML")
    t.add_argument("--report", type=Path, metavar="DIR",
                   help="write DIR/index.md with the failed cases' plots")
    t.add_argument("--out", type=Path, default=Path("runs/test"),
                   help="the runs' folders, one per case and side (default runs/test)")
    t.add_argument("--timeout", type=float, default=None, metavar="S",
                   help="stop a flight after S seconds of wall time (an error)")
    t.add_argument("--executor", choices=("dask", "serial"), default="dask",
                   help="dask (default): a local cluster, one flight per core; serial: one "
                        "after the other")
    t.add_argument("--workers", type=int, default=None, help="local Dask workers")
    t.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing Dask cluster (its workers need the same files)")
    t.add_argument("--quiet", action="store_true", help="only the summary line and failures")


def equivalence_of(text: str | None) -> tuple[str, str] | None:
    if text is None:
        return None
    parts = tuple(p.strip() for p in text.split(","))
    pairs = ({"mil", "sil"}, {"interpreted", "compiled"}, {"native", "portable"})
    if len(parts) != 2 or set(parts) not in pairs:
        raise ScenarioError("--equivalence", text, "mil,sil or interpreted,compiled or "
                            "native,portable")
    return parts[0], parts[1]


def selected(cases, patterns: list[str]):
    if not patterns:
        return cases
    return [c for c in cases if any(fnmatch.fnmatchcase(c.id, p) or p in c.id
                                    for p in patterns)]


def test_command(args) -> int:
    eq = equivalence_of(args.equivalence)
    assert eq is None or all(s in SIDES for s in eq)
    if args.timeout is not None and not args.timeout > 0:
        raise ScenarioError("--timeout", args.timeout, "seconds > 0")
    if args.update and eq is not None:
        raise ScenarioError("--update", "--equivalence", "one of them (a baseline is one "
                            "flight)")
    cases = selected(collect(args.paths, baselines=args.baselines, sets=tuple(args.set),
                             seed=args.seed, mode=args.mode, numerics=args.numerics),
                     args.select)
    if not cases:
        raise ScenarioError("PATH", " ".join(map(str, args.paths)),
                            "scenario or suite files that hold a case" +
                            (" matching -k" if args.select else ""))
    jobs = jobs_for(cases, args.out, equivalence=eq, timeout_s=args.timeout)
    by_id = {j.run_id: j for j in jobs}
    verdicts: list[dict] = []
    t0 = time.perf_counter()
    interrupted = False
    try:
        for v in run_cases(jobs, executor=args.executor, workers=args.workers,
                           scheduler=args.scheduler):
            job = by_id[v["run_id"]]
            if v["status"] == "new" and args.require_baselines:
                v["status"] = "failed"
                v["failures"].append(f"no baseline ({job.case.baseline}); cosim test "
                                     "--update writes one")
            if args.update:
                v["update"] = update(job, v)
            verdicts.append(v)
            if not args.quiet:
                print(_line(v), flush=True)
    except KeyboardInterrupt:
        interrupted = True
    wall = time.perf_counter() - t0
    _write(args, verdicts, {f"{j.case.suite}/{j.case.id}": j.case for j in jobs}, wall)
    print(report.one_screen(verdicts, wall))
    if interrupted:
        print(f"cosim test: interrupted after {len(verdicts)} of {len(jobs)} cases",
              file=sys.stderr)
        return 130
    if args.update:
        return 0 if all(v["status"] != "error" for v in verdicts) else 1
    return 0 if all(v["status"] in ("passed", "new") for v in verdicts) else 1


def _line(v: dict) -> str:
    text = f"[{report.MARK[v['status']]}] {v['suite']}/{v['id']}"
    for u in v.get("update", []):
        text += f"\n    update: {u}"
    return text


def _write(args, verdicts: list[dict], cases: dict, wall: float) -> None:
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "verdicts.json").write_text(json.dumps(
        sorted(verdicts, key=lambda v: v["run_id"]), indent=1, default=str) + "\n")
    if args.junit is not None:
        report.junit(verdicts, args.junit, wall)
    if args.report is not None:
        page = report.markdown(verdicts, cases, args.report, wall)
        print(f"cosim test: report in {page}")
