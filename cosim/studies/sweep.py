"""A sweep's figure: `cosim sweep` runs the Cartesian product of its `--set` values through the
study engine (a study like `cosim montecarlo`: results.csv, report.md, resumable); with one
swept key it also draws `sweep.png`, three metrics against that key's values."""

from __future__ import annotations

from pathlib import Path
from typing import Any

FIGURE = "sweep.png"
PANELS = (("mission_time_s", "mission time (s)"), ("path_error_rms_m", "path error RMS (m)"),
          ("speed_mean_mps", "mean speed following (m/s)"))


def _number(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def plot_sweep(rows: list[dict[str, Any]], key: str, out: Path) -> Path:
    """`out/sweep.png`: each panel's metric (NaN where a run has none) against `key`, the rows
    in the order of the key's values."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = sorted(rows, key=lambda r: int(r["run_id"]))
    xs = [r[key] for r in rows]
    fig, axs = plt.subplots(1, len(PANELS), figsize=(12, 3.6))
    for ax, (metric, label) in zip(axs, PANELS, strict=True):
        ax.plot(xs, [_number(r.get(metric)) for r in rows], "o-")
        ax.set_xlabel(key)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out / FIGURE
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
