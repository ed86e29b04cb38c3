"""A study's report from its results table: `report.md`, `report.json` and plots.

- success rate: runs that passed their scenario's criteria / all runs (a failed run counts as
  not passed), with the Wilson score 95 % interval (E. B. Wilson, "Probable inference, the law
  of succession, and statistical inference", JASA 22(158), 1927), which stays inside [0, 1] and
  is sound for small n and rates near 0 or 1, unlike the normal approximation;
- p5 / p50 / p95 of each numeric metric over the runs that have it (numpy's linear
  interpolation between order statistics);
- why runs did not pass: their exit reasons, and the criteria that failed (counted);
- the worst runs (failed first, then not passed, then the largest value of the study's main
  metric) with their seed, parameters, failed criteria and the `cosim run` command that
  replays one exactly; then the worst few by each of the main metrics (the smallest
  clearance, the largest errors and times);
- plots: a histogram of each main metric, and each main metric against each varied parameter.
"""

from __future__ import annotations

import json
import math
import shlex
from pathlib import Path
from typing import Any

import numpy as np

from cosim.studies.deps import parse_value, strict_json
from cosim.studies.jobs import HEAD, TAIL

Z95 = 1.959963984540054          # standard normal quantile of 0.975
# the first of these a study has is its main metric (ranks the worst runs)
MAIN_METRICS = ("path_error_rms_m", "landing_error_m", "position_error_max_m",
                "final_pose_error_m", "min_clearance_m", "mission_time_s", "path_error_max_m",
                "speed_mean_mps")
WORST_N = 5
WORST_PER_METRIC = 3
LOWER_IS_WORSE = ("min_clearance_m", "speed_mean_mps")


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    den = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z / den * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def toml_literal(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, list | tuple):
        return "[" + ",".join(toml_literal(x) for x in v) + "]"
    return json.dumps(str(v))


def replay_command(manifest: dict[str, Any], row: dict[str, str]) -> str:
    """The `cosim run` line that flies this run again, bit for bit."""
    args = [manifest.get("program") or "cosim", "run", manifest["scenario"]]
    if row["seed"] != "":
        args += ["--seed", row["seed"]]
    if manifest.get("mode", "mil") != "mil":
        args += ["--mode", manifest["mode"]]
    assigns = dict(manifest.get("sets", {}))
    for k in manifest["params"]:
        if k != "seed":
            assigns[k] = parse_value(row[k])
    for k, v in assigns.items():
        args += ["--set", f"{k}={toml_literal(v)}"]
    args += ["--out", f"runs/replay-{row['run_id']}"]
    return " ".join(shlex.quote(a) for a in args)


def _num(s: str) -> float | None:
    try:
        v = float(s)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def numeric_metrics(rows: list[dict[str, str]], params: list[str]) -> dict[str, list[float]]:
    fixed = {*HEAD, *params, *TAIL}
    cols = [c for c in (rows[0] if rows else {}) if c not in fixed]
    out = {}
    for c in cols:
        vals = [r[c] for r in rows if r[c] != ""]
        nums = [_num(v) for v in vals]
        if vals and all(x is not None for x in nums):
            out[c] = nums
    return out


def build_report(rows: list[dict[str, str]], manifest: dict[str, Any]) -> dict[str, Any]:
    params = list(manifest["params"])
    n = len(rows)
    k = sum(r["passed"] == "True" for r in rows)
    lo, hi = wilson(k, n)
    metrics = numeric_metrics(rows, params)
    stats = {m: {"n": len(v), "p5": float(np.percentile(v, 5)),
                 "p50": float(np.percentile(v, 50)), "p95": float(np.percentile(v, 95)),
                 "mean": float(np.mean(v))} for m, v in metrics.items()}
    main = next((m for m in MAIN_METRICS if m in metrics), None)

    def badness(r: dict[str, str]) -> tuple:
        v = _num(r.get(main, "")) if main else None
        return (r["status"] != "failed", r["passed"] == "True",
                -(v if v is not None else math.inf), int(r["run_id"]))

    worst = []
    for r in sorted(rows, key=badness)[:WORST_N]:
        worst.append({"run_id": int(r["run_id"]), "seed": r["seed"], "status": r["status"],
                      "exit_reason": r["exit_reason"], "passed": r["passed"] == "True",
                      "params": {p: r[p] for p in params},
                      "main_metric": r.get(main, "") if main else "",
                      "failed_criteria": r.get("failed_criteria", ""),
                      "error": r["error"], "replay": replay_command(manifest, r)})
    exits: dict[str, int] = {}
    failed_criteria: dict[str, int] = {}
    numerics: dict[str, int] = {}
    for r in rows:
        if r.get("numerics"):
            numerics[r["numerics"]] = numerics.get(r["numerics"], 0) + 1
    for r in rows:
        exits[r["exit_reason"] or "(raised)"] = exits.get(r["exit_reason"] or "(raised)", 0) + 1
        for c in r.get("failed_criteria", "").split():
            failed_criteria[c] = failed_criteria.get(c, 0) + 1
    by_metric = {}
    for m in [m for m in MAIN_METRICS if m in metrics][:4]:
        have = [r for r in rows if _num(r.get(m, "")) is not None]
        sign = 1.0 if m in LOWER_IS_WORSE else -1.0
        have.sort(key=lambda r, m=m, sign=sign: (sign * _num(r[m]), int(r["run_id"])))
        by_metric[m] = [{"run_id": int(r["run_id"]), "value": _num(r[m]),
                         "passed": r["passed"] == "True",
                         "replay": replay_command(manifest, r)}
                        for r in have[:WORST_PER_METRIC]]
    return {"study": manifest, "runs": n, "failed": sum(r["status"] == "failed" for r in rows),
            "success": {"passed": k, "runs": n, "rate": k / n if n else None,
                        "wilson95": [lo, hi]},
            "exit_reasons": exits, "failed_criteria": failed_criteria, "main_metric": main,
            "numerics": numerics,
            "portable": bool(n) and numerics.get("portable", 0) == n,
            "metrics": stats, "worst": worst, "worst_by_metric": by_metric}


def write_report(rows: list[dict[str, str]], manifest: dict[str, Any], out: Path) -> dict:
    rep = build_report(rows, manifest)
    rep["plots"] = plot_study(rows, manifest, out, rep["main_metric"])
    (out / "report.json").write_text(strict_json(rep, indent=2) + "\n")   # NaN -> null
    (out / "report.md").write_text(markdown(rep))
    return rep


def markdown(rep: dict[str, Any]) -> str:
    st, s = rep["study"], rep["success"]
    lines = [f"# {st['kind']} study of {st['scenario']}", "",
             f"command: `{st['command']}`", "",
             f"{rep['runs']} runs, {rep['failed']} failed (raised or component error).", ""]
    if rep["runs"]:
        lo, hi = s["wilson95"]
        lines += [f"**success rate {s['passed']}/{s['runs']} = {100 * s['rate']:.1f} %** "
                  f"(Wilson 95 % interval {100 * lo:.1f} % to {100 * hi:.1f} %)", ""]
    lines += ["exit reasons: " + ", ".join(f"{k} {v}" for k, v in
                                           sorted(rep["exit_reasons"].items())), ""]
    nm = rep.get("numerics") or {}
    if rep.get("portable"):
        lines += ["numerics: portable in every run (the same bits on any x86-64 CPU)", ""]
    elif nm:
        lines += ["numerics: " + ", ".join(f"{k} in {v}" for k, v in sorted(nm.items())) +
                  " runs; native runs can differ on another kind of CPU (`--numerics "
                  "portable`)", ""]
    if rep.get("failed_criteria"):
        lines += ["failed criteria (runs): " + ", ".join(
            f"{k} {v}" for k, v in sorted(rep["failed_criteria"].items())), ""]
    lines += [
              "| metric | runs | p5 | p50 | p95 | mean |", "|---|---:|---:|---:|---:|---:|"]
    for m, v in rep["metrics"].items():
        lines.append(f"| {m} | {v['n']} | {v['p5']:.4g} | {v['p50']:.4g} | {v['p95']:.4g} | "
                     f"{v['mean']:.4g} |")
    lines += ["", f"## worst runs (by {rep['main_metric'] or 'status'})", ""]
    for w in rep["worst"]:
        ps = ", ".join(f"{k}={v}" for k, v in w["params"].items() if k != "seed")
        what = w["error"] or f"{w['exit_reason']}, {'passed' if w['passed'] else 'not passed'}"
        if w.get("failed_criteria"):
            what += f" ({w['failed_criteria']} failed)"
        lines += [f"- run {w['run_id']} (seed {w['seed']}; {ps}): {what}"
                  + (f"; {rep['main_metric']} = {w['main_metric']}" if w["main_metric"] else ""),
                  f"  `{w['replay']}`"]
    for m, ws in rep.get("worst_by_metric", {}).items():
        which = "smallest" if m in LOWER_IS_WORSE else "largest"
        lines += ["", f"## the {which} {m}", ""]
        for w in ws:
            lines += [f"- run {w['run_id']}: {w['value']:.4g}"
                      f" ({'passed' if w['passed'] else 'not passed'})", f"  `{w['replay']}`"]
    lines += ["", "## plots", ""] + [f"![{p}]({p})" for p in rep["plots"]]
    return "\n".join(lines) + "\n"


def plot_study(rows, manifest, out: Path, main: str | None) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    params = list(manifest["params"])
    metrics = numeric_metrics(rows, params)
    shown = [m for m in MAIN_METRICS if m in metrics][:4] or list(metrics)[:4]
    files = []
    if shown:
        fig, axs = plt.subplots(1, len(shown), figsize=(4 * len(shown), 3.2), squeeze=False)
        for ax, m in zip(axs[0], shown, strict=True):
            ax.hist(metrics[m], bins=min(30, max(5, len(metrics[m]) // 5)))
            ax.xaxis.set_major_locator(MaxNLocator(5))    # labels that do not run together
            ax.set_xlabel(m)
            ax.set_ylabel("runs")
            ax.grid(True, alpha=0.3)
        fig.tight_layout()
        fig.savefig(out / "report_hist.png", dpi=100)
        plt.close(fig)
        files.append("report_hist.png")
    num_params = [p for p in params if all(_num(r[p]) is not None for r in rows)]
    if shown and num_params and rows:
        fig, axs = plt.subplots(len(num_params), len(shown), squeeze=False,
                                figsize=(4 * len(shown), 3.0 * len(num_params)))
        for i, p in enumerate(num_params):
            for j, m in enumerate(shown):
                ax = axs[i][j]
                for ok, style in ((True, "o"), (False, "x")):
                    pts = [(float(r[p]), float(r[m])) for r in rows
                           if r[m] != "" and _num(r[m]) is not None
                           and (r["passed"] == "True") == ok]
                    if pts:
                        xs, ys = zip(*pts, strict=True)
                        ax.plot(xs, ys, style, ms=3, alpha=0.7,
                                label="passed" if ok else "not passed")
                ax.xaxis.set_major_locator(MaxNLocator(5))
                ax.set_xlabel(p)
                ax.set_ylabel(m)
                ax.grid(True, alpha=0.3)
        axs[0][0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "report_vs_params.png", dpi=100)
        plt.close(fig)
        files.append("report_vs_params.png")
    return files
