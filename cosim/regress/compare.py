"""The checks of one case: its criteria, its baseline (metrics within tolerances, the trajectory
inside tubes, or bit for bit), and the equivalence of two modes. The verdict is a plain dict (it
travels from a Dask worker, is written as JSON and read by the reports)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from cosim.regress.baseline import Baseline
from cosim.regress.cases import DEFAULT_SIGNALS, Case, Tol, Tolerances
from cosim.regress.flight import Flight

# equivalences that must hold bit for bit unless the suite says `exact = false`: the project's
# own contracts (docs/architecture: MIL and SIL fly the same bits; the compiled build is the
# interpreted source's)
EXACT_PAIRS = ({"mil", "sil"}, {"interpreted", "compiled"})


def band(ref: dict[str, np.ndarray], signal: str, tol: Tol, n: int
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t, baseline, lo, hi) over `n` samples: the tube at time t spans the baseline over
    [t - time_s, t + time_s], widened by max(abs, rel x |baseline|). A baseline that ends
    first holds its last value (a landed vehicle stays where it is)."""
    rate = _rate(ref)
    r = ref[signal]
    t = np.arange(n) / rate
    r = np.concatenate([r, np.full(n - len(r), r[-1])])[:n]
    m = int(math.floor(tol.time_s * rate + 1e-9))
    lo = np.full(n, np.inf)
    hi = np.full(n, -np.inf)
    for off in sorted({k / rate for k in range(-m, m + 1)} | {-tol.time_s, tol.time_s}):
        v = np.interp(t + off, t, r)
        w = tol.of(v)
        lo = np.minimum(lo, v - w)
        hi = np.maximum(hi, v + w)
    return t, r, lo, hi


def tube(ref: dict[str, np.ndarray], new: dict[str, np.ndarray], signal: str,
         tol: Tol) -> dict[str, Any]:
    """Is `new[signal]` inside the tube around `ref[signal]` (`band`)? A flight that ends
    first holds its last value too."""
    y = new[signal]
    n = max(len(ref[signal]), len(y))
    t, r, lo, hi = band(ref, signal, tol, n)
    y = np.concatenate([y, np.full(n - len(y), y[-1])])
    out = ~(np.isnan(y) & np.isnan(r)) & ~((y >= lo) & (y <= hi))
    res: dict[str, Any] = {"signal": signal, "unit": DEFAULT_SIGNALS.get(signal, ("",))[0],
                           "passed": not out.any(), "abs": tol.abs, "rel": tol.rel,
                           "time_s": tol.time_s, "first_exit_t": None}
    if out.any():
        i = int(np.argmax(out))
        excess = np.where(out, np.maximum(lo - y, y - hi), 0.0)
        res.update(first_exit_t=float(t[i]), value=float(y[i]), lo=float(lo[i]),
                   hi=float(hi[i]), worst=float(np.nan_to_num(excess, nan=np.inf).max()),
                   place=[_at(new, k, i) for k in ("n", "e", "alt")])
    return res


def _rate(traj: dict[str, np.ndarray]) -> float:
    t = traj["t"]
    return 1.0 / float(t[1] - t[0]) if len(t) > 1 else 1.0


def _at(traj: dict[str, np.ndarray], k: str, i: int) -> float:
    v = traj.get(k)
    return float(v[min(i, len(v) - 1)]) if v is not None and len(v) else math.nan


def tube_text(c: dict[str, Any]) -> str:
    n, e, alt = c["place"]
    return (f"{c['signal']} left its tube at t={c['first_exit_t']:.2f} s: {c['value']:.4f} "
            f"{c['unit']} outside [{c['lo']:.4f}, {c['hi']:.4f}] (tolerance {c['abs']:g}"
            f"{' + ' + format(c['rel'], 'g') + ' rel' if c['rel'] else ''}"
            f"{', +-' + format(c['time_s'], 'g') + ' s' if c['time_s'] else ''}) at n={n:.2f} "
            f"e={e:.2f} alt={alt:.2f} m; worst {c['worst']:.4g} {c['unit']} outside")


def metric_checks(ref: dict[str, Any], new: dict[str, Any], tol: Tolerances
                  ) -> tuple[list[str], list[str]]:
    """(failures, notes): each metric of the baseline within its tolerance; metrics only one
    side has are notes (a new cosim may report more)."""
    fails, notes = [], []
    for k in sorted(set(ref) | set(new)):
        if k in tol.ignore_metrics:
            continue
        if k not in new:
            notes.append(f"metric {k}: in the baseline ({ref[k]}), not in this run")
            continue
        if k not in ref:
            notes.append(f"metric {k}: new in this run ({new[k]}), not in the baseline")
            continue
        a, b = _value(ref[k]), _value(new[k])
        t = tol.for_metric(k)
        if not _close(a, b, t):
            fails.append(f"metric {k}: {_show(b)}, baseline {_show(a)} (tolerance "
                         f"{t.abs:g}{' or ' + format(t.rel * 100, 'g') + ' %' if t.rel else ''})")
    return fails, notes


def _value(v: Any) -> Any:
    """A metric as compared: numbers (also 'nan' / 'inf' as JSON keeps them), lists of numbers
    (as flat_metrics writes them, JSON text), else as it is."""
    if isinstance(v, str):
        if v in ("nan", "inf", "-inf"):
            return float(v)
        if v.startswith("["):
            try:
                return [float(x) for x in json.loads(v)]
            except (ValueError, TypeError):
                return v
    return v


def _close(a: Any, b: Any, t: Tol) -> bool:
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool) \
            and not isinstance(b, bool):
        if math.isnan(a) or math.isnan(b):
            return math.isnan(a) and math.isnan(b)
        if math.isinf(a) or math.isinf(b):
            return a == b
        return abs(b - a) <= float(t.of(a))
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, t) for x, y in zip(a, b, strict=True))
    return a == b


def _show(v: Any) -> str:
    return f"{v:.6g}" if isinstance(v, float) else str(v)


def first_difference(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> str:
    """Where two trajectories first differ in any bit (their samples)."""
    n = min(len(a["t"]), len(b["t"]))
    for i in range(n):
        for k in a:
            if k != "t" and k in b and not _same(a[k][i], b[k][i]):
                return (f"first difference at t={a['t'][i]:.2f} s in {k}: "
                        f"{b[k][i]!r} against {a[k][i]!r}")
    if len(a["t"]) != len(b["t"]):
        return f"the flights last {len(a['t'])} and {len(b['t'])} samples"
    return "the sampled trajectories agree; the series differ between samples or in other columns"


def _same(x: float, y: float) -> bool:
    return x == y or (math.isnan(x) and math.isnan(y))


def exact_wanted(tol: Tolerances, base_numerics: str, run_numerics: str,
                 same_versions: bool) -> bool:
    """Must the flight be its baseline bit for bit? Only where the tolerances say
    `exact = true` and bits can be expected: both portable, with the same library versions.
    Otherwise (the default) the tubes and metric tolerances decide, and whether the flight is
    bit for bit is reported."""
    return tol.exact == "true" and base_numerics == run_numerics == "portable" and same_versions


def check(case: Case, flights: dict[str, Flight], base: Baseline | None,
          equivalence: tuple[str, str] | None = None) -> dict[str, Any]:
    """The verdict of one case. `flights`: its flights by side ('run' when it has one)."""
    v: dict[str, Any] = {"id": case.id, "suite": case.suite, "scenario": str(case.scenario),
                         "failures": [], "notes": [], "tubes": [], "exact": None,
                         "baseline": str(case.baseline) if base is not None else None,
                         "runs": {k: str(f.run_dir) for k, f in flights.items()},
                         "wall_s": sum(f.wall_s for f in flights.values())}
    errors = [f"{side}: {f.error}" for side, f in flights.items() if not f.ok]
    if errors:
        v.update(status="error", failures=errors)
        return v
    for side, f in flights.items():
        s = f.summary or {}
        label = "" if len(flights) == 1 else f"{side}: "
        for name, c in s.get("criteria", {}).items():
            if not c.get("passed", True):
                v["failures"].append(f"{label}criterion {name}: {_show(c.get('value'))} "
                                     f"(limit {_show(c.get('limit'))})")
        if not s.get("passed", False) and not s.get("criteria"):
            v["failures"].append(f"{label}did not pass: {s.get('exit_reason')}: "
                                 f"{s.get('message', '')}")
    first = next(iter(flights.values()))
    if base is not None:
        _against_baseline(v, case, first, base)
    if equivalence is not None:
        _equivalent(v, case, flights[equivalence[0]], flights[equivalence[1]], equivalence)
    v["status"] = "failed" if v["failures"] else ("new" if base is None and equivalence is None
                                                 else "passed")
    return v


def _against_baseline(v: dict[str, Any], case: Case, f: Flight, base: Baseline) -> None:
    tol = case.tolerance
    s = f.summary or {}
    if s.get("exit_reason") != base.meta.get("exit_reason"):
        v["failures"].append(f"exit {s.get('exit_reason')}, baseline "
                             f"{base.meta.get('exit_reason')}")
    same_versions = base.meta.get("versions") == f.versions
    exact = exact_wanted(tol, base.numerics, f.numerics, same_versions)
    identical = f.series_sha256 == base.meta.get("series_sha256")
    v["exact"] = "identical" if identical else "differs"
    if exact and not identical:
        v["failures"].append("not bit for bit its portable baseline (exact = true): "
                             + first_difference(base.trajectory, f.trajectory))
    elif tol.exact == "true" and not exact:
        why = (_version_diff(base.meta.get("versions", {}), f.versions) if not same_versions
               else f"numerics {base.numerics} / {f.numerics}")
        v["notes"].append(f"exact = true, but bits cannot be expected ({why}): compared "
                          "within tubes")
    if base.meta.get("rate_hz") != tol.rate_hz:
        v["failures"].append(f"the baseline is sampled at {base.meta.get('rate_hz')} Hz, the "
                             f"tolerance asks {tol.rate_hz:g} Hz: cosim test --update")
        return
    _tubes(v, base.trajectory, f.trajectory, tol, "")
    fails, notes = metric_checks(base.metrics, f.metrics, tol)
    v["failures"] += fails
    v["notes"] += notes


def _tubes(v: dict[str, Any], ref, new, tol: Tolerances, label: str) -> None:
    """Each signal in its tube; the failures the earliest first (the first divergence)."""
    checks = []
    for sig, t in tol.signals.items():
        if sig not in ref or sig not in new:
            v["notes"].append(f"{label}signal {sig}: not in both trajectories (a baseline "
                              "made before its tolerance named it: --update)")
            continue
        c = tube(ref, new, sig, t)
        c["label"] = label
        checks.append(c)
    v["tubes"] += checks
    v["failures"] += [label + tube_text(c) for c in sorted(
        (c for c in checks if not c["passed"]), key=lambda c: c["first_exit_t"])]


def _equivalent(v: dict[str, Any], case: Case, a: Flight, b: Flight,
                sides: tuple[str, str]) -> None:
    label = f"{sides[0]} vs {sides[1]}: "
    if a.series_sha256 == b.series_sha256:
        v["equivalence"] = "identical"
        return
    v["equivalence"] = "differs"
    exact = case.tolerance.exact == "true" or (case.tolerance.exact == "auto"
                                               and set(sides) in EXACT_PAIRS)
    if exact:
        v["failures"].append(label + "not bit for bit: " + first_difference(a.trajectory,
                                                                            b.trajectory))
    _tubes(v, a.trajectory, b.trajectory, case.tolerance, label)
    if not exact:
        fails, _ = metric_checks(a.metrics, b.metrics, case.tolerance)
        v["failures"] += [label + x for x in fails]


def _version_diff(a: dict[str, Any], b: dict[str, Any]) -> str:
    return ", ".join(f"{k} {a.get(k)} -> {b.get(k)}" for k in sorted(set(a) | set(b))
                     if a.get(k) != b.get(k))
