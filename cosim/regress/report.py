"""What `cosim test` reports: a one-screen summary, JUnit XML (what CI servers read) and a
Markdown page with, per failed case, the baseline and the new trajectory overlaid and each
signal that left its tube plotted with the tube."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from cosim.regress import baseline as baselines
from cosim.regress.cases import Case
from cosim.regress.compare import band
from cosim.regress.flight import read_run

MARK = {"passed": "PASS", "failed": "FAIL", "error": "ERROR", "new": "NEW"}


def counts(verdicts: list[dict[str, Any]]) -> dict[str, int]:
    out = {k: 0 for k in MARK}
    for v in verdicts:
        out[v["status"]] += 1
    return out


def one_screen(verdicts: list[dict[str, Any]], wall_s: float) -> str:
    """Each case that did not pass, with its failures (the first divergence first), and the
    counts."""
    lines = []
    for v in sorted(verdicts, key=lambda v: (v["suite"], v["id"])):
        if v["status"] == "passed":
            continue
        extra = ""
        if v["status"] == "new" and "update" not in v:
            extra = " (no baseline: cosim test --update writes one)"
        lines.append(f"  [{MARK[v['status']]}] {v['suite']}/{v['id']}{extra}  "
                     f"{v['wall_s']:.1f} s")
        lines += ["         " + line for line in case_text(v).splitlines()]
    c = counts(verdicts)
    run_s = sum(v["wall_s"] for v in verdicts)
    lines.append(f"cosim test: {c['passed']} passed, {c['failed']} failed, {c['error']} errors, "
                 f"{c['new']} new; {wall_s:.1f} s wall for {run_s:.1f} s of runs")
    return "\n".join(lines)


def case_text(v: dict[str, Any], most: int = 6) -> str:
    """A case's failures, a line each (the first divergence first), as `cosim test` and the
    pytest plugin show them."""
    lines = v["failures"][:most]
    if len(v["failures"]) > most:
        lines.append(f"... and {len(v['failures']) - most} more")
    return "\n".join(lines)


def junit(verdicts: list[dict[str, Any]], path: Path, wall_s: float) -> None:
    """JUnit XML as Jenkins, GitLab and GitHub's test reporters read it: one <testsuite> per
    suite, one <testcase> per case; a failed check is a <failure>, a run that gave no result
    an <error>."""
    c = counts(verdicts)
    root = ET.Element("testsuites", name="cosim test", tests=str(len(verdicts)),
                      failures=str(c["failed"]), errors=str(c["error"]),
                      time=f"{wall_s:.3f}")
    for suite in sorted({v["suite"] for v in verdicts}):
        vs = sorted((v for v in verdicts if v["suite"] == suite), key=lambda v: v["id"])
        sc = counts(vs)
        ts = ET.SubElement(root, "testsuite", name=suite, tests=str(len(vs)),
                           failures=str(sc["failed"]), errors=str(sc["error"]), skipped="0",
                           time=f"{sum(v['wall_s'] for v in vs):.3f}")
        for v in vs:
            tc = ET.SubElement(ts, "testcase", classname=suite, name=v["id"],
                               time=f"{v['wall_s']:.3f}", file=v["scenario"])
            if v["status"] in ("failed", "error"):
                tag = "failure" if v["status"] == "failed" else "error"
                el = ET.SubElement(tc, tag, message=_clean(v["failures"][0])[:500],
                                   type="baseline" if tag == "failure" else "run")
                el.text = _clean("\n".join(v["failures"]))
            out = [f"{k}: {d}" for k, d in v.get("runs", {}).items()] + v.get("notes", [])
            if v["status"] == "new":
                out.insert(0, "new: no baseline (cosim test --update writes one)")
            if out:
                ET.SubElement(tc, "system-out").text = _clean("\n".join(out))
    ET.indent(root)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def _clean(text: str) -> str:
    """XML 1.0 has no control characters but tab and newline."""
    return "".join(ch for ch in text if ch in "\t\n" or ord(ch) >= 32)


def markdown(verdicts: list[dict[str, Any]], cases: dict[str, Case], out: Path,
             wall_s: float) -> Path:
    """`out/index.md` and its plots (`out/<suite>-<case>-*.png`)."""
    out.mkdir(parents=True, exist_ok=True)
    c = counts(verdicts)
    lines = ["# cosim test", "",
             f"{c['passed']} passed, {c['failed']} failed, {c['error']} errors, {c['new']} new "
             f"({wall_s:.1f} s).", "", "| case | result | time (s) | first failure |",
             "|---|---|---|---|"]
    for v in sorted(verdicts, key=lambda v: (v["suite"], v["id"])):
        first = v["failures"][0].replace("|", "\\|") if v["failures"] else ""
        lines.append(f"| {v['suite']}/{v['id']} | {MARK[v['status']]} | {v['wall_s']:.1f} | "
                     f"{first} |")
    for v in sorted(verdicts, key=lambda v: (v["suite"], v["id"])):
        if v["status"] != "failed":
            continue
        lines += ["", f"## {v['suite']}/{v['id']}", "", f"Scenario `{v['scenario']}`; runs: "
                  + ", ".join(f"`{d}`" for d in v.get("runs", {}).values()), ""]
        lines += [f"- {f}" for f in v["failures"]] + [f"- note: {n}" for n in v["notes"]]
        for png in _plots(v, cases.get(f"{v['suite']}/{v['id']}"), out):
            lines += ["", f"![{png.stem}]({png.name})"]
    page = out / "index.md"
    page.write_text("\n".join(lines) + "\n")
    return page


def _plots(v: dict[str, Any], case: Case | None, out: Path) -> list[Path]:
    """The overlay of the two trajectories (seen from above) and each signal that left its
    tube, with the tube; against the baseline, or between the two sides of an equivalence."""
    runs = list(v.get("runs", {}).values())
    if case is None or not runs:
        return []
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sig = tuple(case.tolerance.signals)
    new = read_run(Path(runs[-1]), signals=sig, rate_hz=case.tolerance.rate_hz).trajectory
    if v.get("equivalence") is not None and len(runs) == 2:
        ref, ref_name = read_run(Path(runs[0]), signals=sig,
                                 rate_hz=case.tolerance.rate_hz).trajectory, "first side"
    else:
        b = baselines.read(case)
        if b is None or not new:
            return []
        ref, ref_name = b.trajectory, "baseline"
    if not ref or not new:
        return []
    stem = f"{v['suite']}-{v['id']}".replace("/", "_")
    pngs = []
    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(ref["e"], ref["n"], label=ref_name, lw=2, alpha=0.6)
    ax.plot(new["e"], new["n"], label="this run", lw=1)
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title(f"{v['id']}: seen from above")
    pngs.append(_save(fig, out / f"{stem}-overlay.png", plt))
    for c in v["tubes"]:
        if c["passed"]:
            continue
        s = c["signal"]
        n = max(len(ref[s]), len(new[s]))
        t, r, lo, hi = band(ref, s, case.tolerance.signals[s], n)
        y = new[s]
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.fill_between(t, lo, hi, color="tab:blue", alpha=0.2, label="tube")
        ax.plot(t, r, color="tab:blue", lw=1, label=ref_name)
        ax.plot(t[:len(y)], y, color="tab:red", lw=1, label="this run")
        if c["first_exit_t"] is not None and not math.isnan(c["first_exit_t"]):
            ax.axvline(c["first_exit_t"], color="k", ls=":", lw=1)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(f"{s} ({c['unit']})" if c["unit"] else s)
        ax.legend(loc="best")
        ax.set_title(f"{c.get('label', '')}{s} left its tube at t={c['first_exit_t']:.2f} s")
        pngs.append(_save(fig, out / f"{stem}-{s}.png", plt))
    return pngs


def _save(fig, path: Path, plt) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
