"""A study in a folder: its jobs, its manifest, the run through the engine, and its report.

The folder holds `study.json` (the settings that define the study: scenario and its hash,
seed, distributions or grid, fixed `--set`s), `results.csv` (one row per run), `runs.log`,
`report.md` / `report.json` / plots, and `runs/NNNNNN/` with `--keep-runs`. Running the same
command again continues the study: settings that differ from `study.json` are an error (a new
study needs a new `--out`), except the number of runs of a Monte Carlo study, which may grow
(run i's draws depend on the seed and i only).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from pathlib import Path
from typing import Any

from cosim.errors import ScenarioError, output_error
from cosim.studies.deps import with_set
from cosim.studies.dists import Dist, run_draws
from cosim.studies.engine import StudyStats, run_study
from cosim.studies.jobs import Job, self_contained, start_sets
from cosim.studies.report import write_report
from cosim.studies.table import ResultsTable

MANIFEST = "study.json"
TABLE = "results.csv"
# manifest keys that may change between two runs of the same study
MAY_CHANGE = {"n", "command", "program"}


# A study has at most MAX_RUNS runs: its jobs are made (and a Monte Carlo study's draws checked)
# before the first run starts, ~1 KB each; 1e5 runs of a 1-minute mission are ~70 core-days.
MAX_RUNS = 100_000


def check_grid(grid: dict[str, list[Any]]) -> None:
    n = math.prod(len(v) for v in grid.values())
    if n > MAX_RUNS:
        raise ScenarioError("--set", " ".join(f"{k}=({len(v)} values)" for k, v in grid.items()),
                            f"a grid of at most {MAX_RUNS} runs (this one: {n} runs)")


def scenario_hash(raw: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(raw, sort_keys=True, default=str).encode()).hexdigest()


CACHE = "cache"     # what runs share (textures, taught keys: cosim/cache.py), in the study folder


def _keep(out: Path, keep: bool, i: int) -> str | None:
    return str(out / "runs" / f"{i:06d}") if keep else None


def montecarlo_jobs(sc, dists: list[Dist], n: int, seed: int, sets: dict[str, Any], out: Path,
                    *, mode: str = "mil", keep_runs: bool = False, mcap: bool = False
                    ) -> tuple[list[Job], dict[str, Any]]:
    """The jobs of an n-run study, every draw checked against its field's range first."""
    if not 1 <= n <= MAX_RUNS:
        raise ScenarioError("-n", n, f"an integer in 1..{MAX_RUNS} (the draws of every run are "
                            "made and checked before the first starts)")
    if not 0 <= seed <= 2**63 - 1:
        raise ScenarioError("--seed", seed, "an integer in [0, 2^63 - 1]")
    keys = [d.key for d in dists]
    sets = {**start_sets(sc, [*keys, *sets]), **sets}
    clash = set(keys) & set(sets)
    if clash:
        raise ScenarioError("--set", sorted(clash)[0], "a key that is not also varied")
    if "seed" in keys:
        raise ScenarioError("--vary seed", "seed", "another key: every run gets its own seed")
    base = with_set(sc, sets) if sets else sc
    draws = [run_draws(seed, i, dists) for i in range(n)]
    for d in dists:
        vals = [v[d.key] for _, v in draws]
        check = {min(vals), max(vals)} if d.kind != "choice" else set(map(repr, vals))
        for v in check:
            value = v if d.kind != "choice" else next(x for x in vals if repr(x) == v)
            try:
                with_set(base, {d.key: value})
            except ScenarioError as exc:
                run = next(i for i, (_, dv) in enumerate(draws) if dv[d.key] == value)
                raise ScenarioError(f"--vary {d.text}", value,
                                    f"draws inside the field's range (run {run}; {exc}); "
                                    "no clipping: use truncnormal(mu,sigma,lo,hi) or narrower "
                                    "bounds") from None
    raw = self_contained(sc)
    jobs = [Job(i, raw, sc.source, tuple(sets.items()), tuple(v.items()), seed=s, mode=mode,
                keep_dir=_keep(out, keep_runs, i), mcap=mcap, cache_dir=str(out / CACHE))
            for i, (s, v) in enumerate(draws)]
    manifest = {"kind": "montecarlo", "scenario": sc.source, "scenario_sha256": scenario_hash(raw),
                "seed": seed, "n": n, "vary": [d.text for d in dists], "sets": sets,
                "params": keys, "mode": mode}
    return jobs, manifest


def sweep_jobs(sc, grid: dict[str, list[Any]], out: Path, *, mode: str = "mil",
               keep_runs: bool = False, mcap: bool = False) -> tuple[list[Job], dict[str, Any]]:
    """The Cartesian product of the values; keys with one value are fixed --sets."""
    check_grid(grid)
    for key, values in grid.items():  # every value checked before any run starts
        for v in values:
            with_set(sc, {key: v})
    params = [k for k, v in grid.items() if len(v) > 1]
    sets = {k: v[0] for k, v in grid.items() if len(v) == 1}
    sets = {**start_sets(sc, [*grid]), **sets}
    raw = self_contained(sc)
    combos = itertools.product(*(grid[k] for k in params))
    jobs = [Job(i, raw, sc.source, tuple(sets.items()), tuple(zip(params, c, strict=True)),
                mode=mode, keep_dir=_keep(out, keep_runs, i), mcap=mcap,
                cache_dir=str(out / CACHE))
            for i, c in enumerate(combos)]
    manifest = {"kind": "sweep", "scenario": sc.source, "scenario_sha256": scenario_hash(raw),
                "grid": {k: grid[k] for k in params}, "sets": sets, "params": params,
                "mode": mode}
    return jobs, manifest


def open_study(out: Path, manifest: dict[str, Any]) -> ResultsTable:
    """Create the study folder, or check that it holds this same study; the table."""
    if out.exists() and not out.is_dir():
        raise ScenarioError("--out", str(out), "a folder (this path is a file)")
    out.mkdir(parents=True, exist_ok=True)
    mf = out / MANIFEST
    for p in (mf, out / TABLE):
        if p.exists() and not p.is_file():
            raise ScenarioError("--out", str(out), f"a study folder whose {p.name} is a file "
                                "(it is a folder: move it)")
    if mf.is_file():
        try:
            old = json.loads(mf.read_text())
        except (ValueError, OSError, RecursionError) as exc:
            raise ScenarioError("--out", str(out), f"a study folder with a readable "
                                f"{MANIFEST} ({type(exc).__name__}; a new --out, or remove "
                                "the broken file)") from None
        if not isinstance(old, dict):
            raise ScenarioError("--out", str(out), f"a study folder whose {MANIFEST} holds a "
                                "JSON object (a new --out, or remove the broken file)")
        for k in sorted(set(old) | set(manifest)):
            if k not in MAY_CHANGE and json.dumps(old.get(k), default=str) != json.dumps(
                    manifest.get(k), default=str):
                raise ScenarioError("--out", str(out), f"a new folder, or the same settings: it "
                                    f"holds a study whose {k} was {old.get(k)!r}, not "
                                    f"{manifest.get(k)!r}")
    try:
        mf.write_text(json.dumps(manifest, indent=2, default=str) + "\n")
    except OSError as exc:
        raise output_error(exc, mf) from None
    try:
        return ResultsTable(out / TABLE, list(manifest["params"]))
    except ValueError as exc:
        raise ScenarioError("--out", str(out), f"a folder of this study ({exc})") from None


def run_in_folder(jobs: list[Job], manifest: dict[str, Any], out: Path, **engine) -> tuple[
        StudyStats, list[dict[str, str]], dict[str, Any] | None]:
    """Run what is left, sort the table, write the report when every run has a row. The
    folder is locked for the study: a second study into it fails at once (ScenarioError)."""
    from cosim.outputs.folder import claim_run_folder

    if out.exists() and not out.is_dir():
        raise ScenarioError("--out", str(out), "a folder (this path is a file)")
    with claim_run_folder(out, "--out", what="study"):
        table = open_study(out, manifest)
        try:
            stats = run_study(jobs, table, log=out / "runs.log", **engine)
        finally:
            try:
                rows = table.finish()
            except OSError as exc:
                raise output_error(exc, table.path, "it holds the rows written before") \
                    from None
        ids = {j.run_id for j in jobs}
        rows = [r for r in rows if int(r["run_id"]) in ids]
        try:
            report = write_report(rows, manifest, out) if len(rows) == len(ids) else None
        except OSError as exc:
            raise output_error(exc, out / "report.md", f"every row is in {TABLE}") from None
    return stats, rows, report
